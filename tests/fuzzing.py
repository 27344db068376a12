"""Property-based fuzzing of scene files and `clpt render` options (hypothesis
strategies and the checks of one input), shared by tests/test_fuzz.py (a few
hundred inputs, in the suite) and tests/fuzz_long.py (as many as time allows,
counted by outcome).

An input passes when it is rendered to a finite, non-negative image, or is
refused with a one-line error (SceneError, ValueError, TypeError in the API;
exit status 1 or 2 with one `clpt: error:` line on the command line, or
argparse's usage error). Anything else, a traceback, another exception, a
non-finite pixel, is a failure.
"""

from __future__ import annotations

import copy
import json
import math
import tomllib
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

import clpt
from clpt.resources import scene_path

# --- values --------------------------------------------------------------------------

EXTREME_FLOATS = [0.0, -0.0, 5e-324, 1e-45, 1.2e-38, 1e-30, 1e-20, 1e-6, 0.5, 1.0, 2.0, 1e6, 1e20, 1e30,
                  3.4e38, 3.5e38, 1e39, 1e300, -1e300, -1.0, math.inf, -math.inf, math.nan]
EXTREME_INTS = [0, 1, -1, 2, 255, 2 ** 16, 2 ** 16 + 1, 2 ** 31 - 1, 2 ** 31, 2 ** 32, 2 ** 63 - 1, -2 ** 63,
                10 ** 30]

floats = st.one_of(st.sampled_from(EXTREME_FLOATS), st.floats(-10, 10), st.floats())
ints = st.one_of(st.sampled_from(EXTREME_INTS), st.integers(-5, 300))
scalars = st.one_of(floats, ints, st.booleans(), st.text(max_size=6))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.sampled_from(["a", "type", "kd", "radius"]),
                                                                       inner, max_size=3)), max_leaves=8)

# --- scene documents -----------------------------------------------------------------------

# Shapes of every kind, added to the Cornell box so each kind's keys get mutated.
EXTRA_SHAPES = [
    {"type": "sphere", "material": {"preset": "glass"}, "center": [0.3, -0.6, 0.2], "radius": 0.3},
    {"type": "triangle", "material": "green", "vertices": [[-0.5, -0.9, 0], [0, -0.9, 0.3], [0, -0.5, 0]]},
    {"type": "plane", "material": "white", "point": [0, -1.5, 0], "normal": [0, 1, 0]},
    {"type": "box", "material": {"kd": 0.5, "ks": 0.2, "shininess": 20}, "center": [-0.4, -0.7, -0.3],
     "size": [0.3, 0.6, 0.3], "rotation": [0, 20, 0]},
    {"type": "sphere", "material": "black", "emission": 5.0, "center": [0.5, 0.7, 0.5], "radius": 0.05},
]
GEOMETRY_KEYS = {"origin", "target", "center", "radius", "vertices", "corner", "edge_u", "edge_v", "point", "size"}


def base_scene() -> dict:
    return tomllib.loads(scene_path("cornell_box").read_text())


def toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def to_toml(doc: dict) -> str:
    """A document as TOML text (every table inline, so any structure goes)."""
    return "\n".join(f"{json.dumps(str(k))} = {toml_value(v)}" for k, v in doc.items()) + "\n"


def _scale_geometry(node, k):
    if isinstance(node, dict):
        return {key: (_scale_numbers(v, k) if key in GEOMETRY_KEYS else _scale_geometry(v, k))
                for key, v in node.items()}
    if isinstance(node, list):
        return [_scale_geometry(v, k) for v in node]
    return node


def _scale_numbers(node, k):
    if isinstance(node, list):
        return [_scale_numbers(v, k) for v in node]
    if isinstance(node, (int, float)) and not isinstance(node, bool):
        return node * k
    return node


def _paths(node, prefix=()):
    """Every (path, value) inside a document."""
    yield prefix, node
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


def _set(doc, path, value):
    node = doc
    for p in path[:-1]:
        node = node[p]
    if value is _DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value


_DELETE = object()


@st.composite
def scene_documents(draw):
    """The Cornell box with extra shapes, its geometry scaled by 10^k, then a
    few keys replaced, deleted or added."""
    doc = base_scene()
    doc["shapes"] = doc["shapes"] + copy.deepcopy(draw(st.lists(st.sampled_from(EXTRA_SHAPES), max_size=3)))
    if draw(st.booleans()):
        doc = _scale_geometry(doc, 10.0 ** draw(st.integers(-45, 45)))
    for _ in range(draw(st.integers(0, 3))):
        paths = [p for p, _ in _paths(doc) if p]
        action = draw(st.sampled_from(["replace", "replace", "delete", "add", "extreme", "extreme"]))
        if action == "extreme":  # a number made extreme, where a number belongs
            paths = [p for p, v in _paths(doc) if p and isinstance(v, (int, float)) and not isinstance(v, bool)]
            if paths:
                _set(doc, draw(st.sampled_from(paths)), draw(st.one_of(st.sampled_from(EXTREME_FLOATS),
                                                                         st.sampled_from(EXTREME_INTS))))
            continue
        path = draw(st.sampled_from(paths))
        try:
            if action == "replace":
                _set(doc, path, draw(values))
            elif action == "delete":
                _set(doc, path, _DELETE)
            else:
                node = doc
                for p in path[:-1]:
                    node = node[p]
                if isinstance(node, dict):
                    node[draw(st.sampled_from(["extra", "radius", "emission", "two_sided", "ior"]))] = draw(values)
        except (KeyError, IndexError, TypeError):
            pass
    return doc


@st.composite
def scene_texts(draw):
    """Scene file text: a mutated document, sometimes with bytes changed."""
    text = to_toml(draw(scene_documents()))
    if draw(st.integers(0, 19)) == 0:  # an array nested deeper than any parser's stack
        depth = draw(st.integers(100, 6000))
        return (text + "deep = " + "[" * depth + "]" * depth + "\n").encode()
    if draw(st.integers(0, 4)) == 0:
        data = bytearray(text.encode())
        for _ in range(draw(st.integers(1, 4))):
            i = draw(st.integers(0, len(data) - 1))
            data[i] = draw(st.integers(0, 255))
        return bytes(data)
    return text.encode()


# --- outcomes --------------------------------------------------------------------------------


class Failure(AssertionError):
    """An input that was neither rendered right nor refused with a clear error."""


def one_line(msg: str, what: str):
    if not msg or "\n" in msg.strip() or "Traceback" in msg:
        raise Failure(f"{what}: not a one-line error: {msg!r}")


def check_scene_file(path: Path, render: bool, device=None) -> str:
    """Load (and maybe render, 4x4 at 1 spp) a scene file; the outcome's name.
    Raises Failure for anything but a render or a clear refusal."""
    try:
        scene = clpt.load_scene(path)
    except clpt.SceneError as e:
        one_line(str(e), "load_scene")
        return "refused"
    except Exception as e:  # noqa: BLE001
        raise Failure(f"load_scene raised {type(e).__name__}: {e}") from e
    if not render:
        return "accepted"
    try:
        # One kernel for every scene (the generic build reads counts at run
        # time); paths cut at depth 8 so lossless scenes end.
        r = clpt.Renderer(scene, kernel="generic", device=device)
        res = r.render(1, width=4, height=4, max_depth=8, rr_depth=2, seed=1)
    except (clpt.SceneError, ValueError, TypeError) as e:
        one_line(str(e), "render")
        return "refused at render"
    except Exception as e:  # noqa: BLE001
        raise Failure(f"render raised {type(e).__name__}: {e}") from e
    img = res.image
    if not np.isfinite(img).all() or img.min() < 0:
        raise Failure(f"non-finite or negative image (min {np.nanmin(img)})")
    return "rendered" if res.stats.nonfinite == 0 else "rendered, non-finite samples dropped"


# --- command lines ---------------------------------------------------------------------------

NUMBER_WORDS = ["nan", "inf", "-inf", "-1", "0", "1e308", "abc", "", "1.5", "2147483648", "4294967296", "1e-300"]


def _num(valid):
    return st.one_of(valid.map(str), st.sampled_from(NUMBER_WORDS))


OUTPUTS = ["x.png", "x.exr", "x.jpg", "x.epx", "", "x", "/proc/x.exr", "sub/dir/x.png", ".", "x.tif", "x.hdr"]

# Options and the values to fuzz them with. Valid values are kept small so
# that every accepted render is short (a valid 2^31 spp render would run for
# days); --filter-width/--filter-iterations only take small values here.
CLI_OPTIONS = {
    "--spp": _num(st.integers(1, 4)),
    "--width": _num(st.one_of(st.integers(1, 12), st.sampled_from([65537, 60000]))),
    "--height": _num(st.one_of(st.integers(1, 12), st.sampled_from([65537, 60000]))),
    "--max-depth": _num(st.one_of(st.integers(0, 10), st.just(2 ** 31 - 1))),
    "--rr-depth": _num(st.integers(0, 10)),
    "--seed": _num(st.one_of(st.integers(0, 10), st.sampled_from([2 ** 31, 2 ** 32 - 1, 2 ** 32]))),
    "--exposure": _num(st.floats(-70, 70)),
    "--time-limit": _num(st.floats(0.05, 2.0)),
    "--photons": _num(st.integers(0, 20000)),
    "--radius": _num(st.floats(1e-6, 1.0)),
    "--cone-k": _num(st.floats(0.5, 3.0)),
    "--max-photons": _num(st.integers(0, 100)),
    "--photon-budget": _num(st.integers(0, 300)),
    "--alpha": _num(st.floats(0.0, 1.5)),
    "--spp-per-map": _num(st.integers(0, 4)),
    "--offline-spp": _num(st.integers(0, 4)),
    "--min-spp": _num(st.integers(0, 4)),
    "--noise-threshold": _num(st.floats(-1, 1)),
    "--adaptive-pass-spp": _num(st.integers(0, 4)),
    "--filter-width": st.integers(0, 3).map(str),
    "--filter-iterations": st.integers(1, 3).map(str),
    "--filter-interval": _num(st.integers(0, 3)),
    "--adaptive": st.sampled_from(["error", "paper", "bogus"]),
    "--photon-mode": st.sampled_from(["merge", "online", "offline"]),
    "--merge-vertices": _num(st.integers(0, 3)),
    "--merge-probability": _num(st.floats(0.0, 1.5)),
}
CLI_FLAGS = ["--filter", "--progressive", "--radius-absolute", "--no-nee", "--write-aux", "--no-depth-reduction",
             "--no-photon-pilot"]


@st.composite
def command_lines(draw):
    scene = draw(st.sampled_from(["cornell_box", "cornell_box_caustics", "no_such_scene"]))
    argv = ["render", scene, "-q"]
    for opt in draw(st.lists(st.sampled_from(sorted(CLI_OPTIONS)), max_size=5, unique=True)):
        argv += [opt, draw(CLI_OPTIONS[opt])]
    argv += draw(st.lists(st.sampled_from(CLI_FLAGS), max_size=2, unique=True))
    if "--spp" not in argv:
        argv += ["--spp", "1"]
    for side in ("--width", "--height"):
        if side not in argv:
            argv += [side, "6"]
    if "--photons" not in argv:
        argv += ["--photons", "5000"]
    return argv, draw(st.sampled_from(OUTPUTS))


def check_command(argv, output, tmp: Path, run_main, device=None) -> str:
    """Run `clpt render` in-process with -o tmp/output; the outcome's name.
    run_main(argv) returns (exit status, stderr)."""
    out = output if output.startswith("/") or output == "" else str(tmp / output)
    argv = [*argv, "-o", out] + (["--device", device] if device else [])
    status, err = run_main(argv)
    if "Traceback" in err:
        raise Failure(f"{argv}: a traceback:\n{err}")
    if status == "usage":
        return "usage error"
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("clpt: error:")]
    if status in (1, 2):
        if len(errors) != 1:
            raise Failure(f"{argv}: exit {status} without one error line: {err!r}")
        return f"refused (exit {status})"
    if status != 0:
        raise Failure(f"{argv}: exit status {status}: {err!r}")
    p = Path(out)
    if not p.is_file():
        raise Failure(f"{argv}: exit 0 but {p} was not written")
    try:
        img = clpt.load_image(p)
    except Exception as e:  # noqa: BLE001
        raise Failure(f"{argv}: exit 0 but the image cannot be read back: {e}") from e
    if not np.isfinite(img).all():
        raise Failure(f"{argv}: non-finite pixels in {p}")
    p.unlink()
    return "rendered, with a warning" if any("warning" in ln for ln in lines) else "rendered"
