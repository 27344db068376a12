"""Property-based fuzzing of every file clpt reads (TOML and Mitsuba XML
scenes, OBJ, PLY and Mitsuba serialized meshes, checkpoints: READERS at the end) and of `clpt
render` options: hypothesis strategies and the checks of one input, shared by
tests/test_fuzz*.py (a few hundred inputs each, in the suite) and
tests/fuzz_long.py (as many as asked, counted by reader and outcome).

An input passes when it is rendered to a finite, non-negative image, or is
refused with a one-line error (SceneError, ValueError, TypeError in the API;
exit status 1 or 2 with one `clpt: error:` line on the command line, or
argparse's usage error). Anything else, a traceback, another exception, a
non-finite pixel, is a failure.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import math
import random
import re
import shutil
import tempfile
import tomllib
import warnings
from pathlib import Path
from typing import Callable

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

import clpt
from clpt.resources import scene_dir, scene_path
from clpt.texture import Texture

def bounded(n):
    """Settings for a test of n inputs, the same ones every run
    (derandomized), without a time limit per input."""
    return settings(max_examples=n, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck),
                    database=None)


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


def check_scene_file(path: Path, render: bool, device=None, need_place=False) -> str:
    """Load (and maybe render, 4x4 at 1 spp) a scene file; the outcome's name.
    Raises Failure for anything but a render or a clear refusal (one line
    naming the file, and with need_place the place in it: see refusal)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scene = clpt.load_scene(path)
    except clpt.SceneError as e:
        return refusal(e, path, need_place)
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


def _num(valid, words=NUMBER_WORDS):
    return st.one_of(valid.map(str), st.sampled_from(words))


OUTPUTS = ["x.png", "x.exr", "x.jpg", "x.epx", "", "x", "/proc/x.exr", "/proc/nope/x.exr", "/dev/null/x.png",
           "sub/dir/x.png", ".", "x.tif", "x.hdr"]

# Options and the values to fuzz them with. Valid values are kept small so
# that every accepted render is short (a valid 2^31 spp render would run for
# days); --filter-width/--filter-iterations only take small values here.
CLI_OPTIONS = {
    # Not 2^31 samples, which is valid: a render of days, not a fault.
    "--spp": _num(st.integers(1, 4), [w for w in NUMBER_WORDS if w != "2147483648"]),
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


# === Every file clpt reads ==================================================================
#
# Each reader (XML scenes, OBJ, PLY and serialized meshes, checkpoints) has a strategy of
# inputs (mutations of real files, and for XML scenes also scenes generated
# from a grammar of the supported elements) and a check of one input, in
# READERS below. The contract every check enforces: an input loads, and then
# holds only finite data (and, when asked, renders a finite 4x4 image at
# 1 spp), or it is refused with a one-line error (SceneError) that names the
# file, the place (a line, an element, a byte offset or a member) and the
# reason. Anything else, a traceback, another exception, a non-finite value,
# is a Failure; fuzz_long.py adds a time limit per input, so a hang is one too.
#
# A new reader (textures) slots in as one more Reader: seed files to mutate (or
# a generator) and a check.

TESTS = Path(__file__).resolve().parent
DATA = TESTS / "data"
MESHES = scene_dir() / "meshes"  # the shipped meshes, from the installed package as from the source tree

# Text that parsers trip on, spliced into files in place of numbers, values and bytes.
TOKENS = ["", " ", "0", "-0", "1", "-1", "3", "nan", "NaN", "inf", "-inf", "1e309", "-1e309", "1e-320", "3.4e38",
          "2147483647", "2147483648", "4294967296", "-2147483649", "99999999999999999999", "1e30", "0x10", "1,2",
          "1, 2, 3, 4", "a", "$x", "1e", ".", "+", "--1", "é", "\t", "\n", "//", "/", "#", "\\"]


def _at(draw, data, end=False):
    return draw(st.integers(0, len(data) if end else max(len(data) - 1, 0)))


def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


def m_flip(draw, d):
    if d:
        d[_at(draw, d)] ^= 1 << draw(st.integers(0, 7))
    return d


def m_byte(draw, d):
    if d:
        d[_at(draw, d)] = draw(st.integers(0, 255))
    return d


def m_delete(draw, d):
    i = _at(draw, d)
    del d[i:i + draw(st.integers(1, 64))]
    return d


def m_duplicate(draw, d):
    i = _at(draw, d)
    span = d[i:i + draw(st.integers(1, 64))]
    j = _at(draw, d, end=True)
    d[j:j] = span
    return d


def m_truncate(draw, d):
    return d[:_at(draw, d, end=True)]


def m_insert(draw, d):
    j = _at(draw, d, end=True)
    d[j:j] = draw(st.sampled_from(TOKENS)).encode()
    return d


NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def m_number(draw, d):
    """A number in the file (a count, a coordinate, an index) replaced by a token."""
    spans = [m.span() for m in NUMBER.finditer(bytes(d[:1 << 16]))]
    if spans:
        a, b = draw(st.sampled_from(spans))
        d[a:b] = draw(st.sampled_from(TOKENS)).encode()
    return d


def m_line(draw, d):
    """A line deleted, duplicated or swapped with another."""
    lines = _lines(bytes(d))
    i, j = draw(st.integers(0, len(lines) - 1)), draw(st.integers(0, len(lines) - 1))
    op = draw(st.sampled_from(["delete", "duplicate", "swap"]))
    if op == "delete":
        del lines[i]
    elif op == "duplicate":
        lines.insert(j, lines[i])
    else:
        lines[i], lines[j] = lines[j], lines[i]
    return bytearray(b"\n".join(lines))


ATTRIBUTE = re.compile(rb'(\w+)="([^"]*)"')
TAG = re.compile(rb"<(/?)([A-Za-z_]\w*)")
XML_VALUES = TOKENS + ["0, 0, 0", "1, 1, 1", "0, 0", "-1, -1, -1", "1e30, 1e30, 1e30", "0:1, 1000:1", "500:nan",
                       "bk7", "none", "true", "maybe", "$spp", "$res", "cbox/nope.obj", "cbox/light.obj",
                       "cbox/materials.xml", "white", "3.0.0", "0.6.0", "9.0.0"]


def m_attribute(draw, d):
    """An attribute's value replaced, or the attribute deleted or renamed."""
    spans = list(ATTRIBUTE.finditer(bytes(d)))
    if not spans:
        return d
    m = draw(st.sampled_from(spans))
    op = draw(st.sampled_from(["value", "value", "value", "delete", "rename"]))
    if op == "value":
        d[m.start(2):m.end(2)] = draw(st.sampled_from(XML_VALUES)).encode()
    elif op == "delete":
        del d[m.start():m.end()]
    else:
        d[m.start(1):m.end(1)] = draw(st.sampled_from(["name", "value", "id", "type", "x", "angle", "filename",
                                                       "origin", "bogus"])).encode()
    return d


def m_tag(draw, d):
    """A tag's name swapped for another (often a known one)."""
    spans = list(TAG.finditer(bytes(d)))
    if spans:
        m = draw(st.sampled_from(spans))
        from clpt.mitsuba import KNOWN_TAGS
        d[m.start(2):m.end(2)] = draw(st.sampled_from(sorted(KNOWN_TAGS) + ["bogus"])).encode()
    return d


BYTE_MUTATIONS = [m_flip, m_byte, m_delete, m_duplicate, m_truncate, m_insert]
TEXT_MUTATIONS = BYTE_MUTATIONS + [m_number, m_number, m_number, m_line, m_line]
XML_MUTATIONS = TEXT_MUTATIONS + [m_attribute, m_attribute, m_attribute, m_tag]


@st.composite
def mutations_of(draw, seeds: list[bytes], ops, most=4):
    """A seed file with 1 to `most` mutations drawn from ops."""
    d = bytearray(draw(st.sampled_from(seeds)))
    for _ in range(draw(st.integers(1, most))):
        d = draw(st.sampled_from(ops))(draw, d)
    return bytes(d)


# --- outcomes -------------------------------------------------------------------------------

# A place in the message: a line (file:12: or line 12), a byte offset, an XML
# element (<shape ...>), a scene key path (shapes[1].file), a checkpoint member,
# a mesh's vertex, normal, face or triangle by number, a serialized file's shape.
PLACE = re.compile(r"(:\d+:|\bline \d+|\bbyte \d+|<\w+|\w+\[\d+\]|\bmember '|\bheader\b|\belement\b|"
                   r"\b(vertex|normal|face|triangle|shape|shape_index) \d+)")


def refusal(e: Exception, path: Path, need_place=True) -> str:
    """Check a refusal's message (one line, naming the file, and a place unless
    the reason is about the whole file); returns the outcome's name."""
    msg = str(e)
    one_line(msg, type(e).__name__)
    if path.name not in msg:
        raise Failure(f"the error does not name the file {path.name}: {msg!r}")
    if need_place and not PLACE.search(msg) and not WHOLE_FILE.search(msg):
        raise Failure(f"the error names no place (line, element, byte offset or member): {msg!r}")
    return "refused"


# Reasons that are about the whole file, so have no place.
WHOLE_FILE = re.compile(r"(no such|empty|too large|has no triangles|has no faces|not a regular file|is a folder|"
                        r"not a clpt "
                        r"checkpoint|not UTF-8|cannot read the|no non-degenerate|not used by the scene|"
                        r"written by clpt|another scene|does not match its own hash|after import)")


def finite_image(img, what):
    img = np.asarray(img)
    if not np.isfinite(img).all() or img.min() < 0:
        raise Failure(f"{what}: non-finite or negative image (min {np.nanmin(img)})")


# --- Mitsuba XML scenes ---------------------------------------------------------------------

def xml_seeds() -> list[bytes]:
    """The test XML scenes, and the BSDFs they include (as a scene of its own);
    cbox_bunny.xml with a shipped PLY in place of its $bunny (not in the repo)."""
    seeds = [(DATA / n).read_bytes() for n in ("cbox_mesh.xml", "cbox_shapes.xml", "cbox/materials.xml",
                                               "cbox_textured.xml")]
    seeds.append((DATA / "cbox_bunny.xml").read_bytes().replace(b'value="$bunny"', b'value="cbox/bunny.ply"'))
    return seeds


class _Values:
    """Values for a generated scene from a seeded random.Random (hypothesis
    draws the seed; its own draws favour boundaries, which would make nearly
    every value wild): sensible, or with probability `wild` per value one of
    the tokens parsers trip on."""

    def __init__(self, seed, wild):
        self.rng, self.wild = random.Random(seed), wild

    def is_wild(self):
        return self.rng.random() < self.wild

    def num(self, lo=-3.0, hi=3.0):
        if self.is_wild():
            return self.rng.choice(TOKENS)
        return repr(round(self.rng.uniform(lo, hi), 4))

    def vec(self, lo=-3.0, hi=3.0):
        n = self.rng.choice([1, 2, 4]) if self.is_wild() else 3
        return ", ".join(self.num(lo, hi) for _ in range(n))

    def pick(self, good: list, bad: list = ()):
        """One of good, or (when wild) one of bad."""
        return self.rng.choice(bad if bad and self.is_wild() else good)

    def int(self, lo, hi):
        return self.rng.randint(lo, hi)


def _color(v: _Values, name, emitter=False):
    hi = 20.0 if emitter else 1.0
    kind = v.pick(["rgb", "rgb", "float", "spectrum", "spectrum_pairs", "checkerboard", "bitmap"])
    if kind == "rgb":
        return f'<rgb name="{name}" value="{v.vec(0, hi)}"/>'
    if kind == "float":
        return f'<float name="{name}" value="{v.num(0, hi)}"/>'
    if kind == "spectrum":
        return f'<spectrum name="{name}" value="{v.num(0, hi)}"/>'
    if kind == "spectrum_pairs":
        wavelengths = sorted(v.rng.sample(range(360, 831, 10), v.int(1, 4)))
        pairs = ", ".join(f"{w if not v.is_wild() else v.num()}:{v.num(0, hi)}" for w in wavelengths)
        return f'<spectrum name="{name}" value="{pairs}"/>'
    if kind == "bitmap":
        props = [f'<string name="filename" value="{v.pick(["textures/pattern.png"], ["nope.png", ""])}"/>']
        if v.pick([True, False]):
            props.append(f'<string name="filter_type" value="{v.pick(["bilinear", "nearest"], ["cubic", ""])}"/>')
        if v.pick([True, False]):
            props.append(f'<string name="wrap_mode" value="{v.pick(["repeat", "mirror", "clamp"], ["wrap"])}"/>')
        if v.pick([True, False]):
            props.append(f'<boolean name="raw" value="{v.pick(["true", "false"], ["2"])}"/>')
        if v.pick([True, False]):
            props.append(_transform(v, "to_uv"))
        return f'<texture type="bitmap" name="{name}">{"".join(props)}</texture>'
    uv = _transform(v, "to_uv") if v.pick([True, False]) else ""
    return (f'<texture type="checkerboard" name="{name}">{_color(v, "color0", emitter)}'
            f'{_color(v, "color1", emitter)}{uv}</texture>')


def _bsdf(v: _Values, depth=0, ident=None):
    t = v.pick(["diffuse", "diffuse", "conductor", "roughconductor", "dielectric", "thindielectric",
                "roughdielectric", "plastic", "roughplastic"]
               + (["twosided", "blendbsdf", "mask"] if depth < 2 else []),
               ["bogus", "hair"])
    body = []
    if t == "diffuse":
        body.append(_color(v, "reflectance"))
    elif t in ("conductor", "roughconductor"):
        if v.pick([True, False]):
            body.append(_color(v, "specular_reflectance"))
        body.append(v.pick(['<string name="material" value="Au"/>', '<string name="material" value="none"/>',
                            f'<rgb name="eta" value="{v.vec(0, 3)}"/>', ""]))
    elif t in ("dielectric", "thindielectric", "roughdielectric", "plastic", "roughplastic"):
        body.append(v.pick([f'<float name="int_ior" value="{v.num(1, 2.5)}"/>',
                            '<string name="int_ior" value="water"/>', ""]))
        if t.endswith("plastic"):
            body.append(_color(v, "diffuse_reflectance"))
    if t.startswith("rough"):
        body.append(v.pick([f'<float name="alpha" value="{v.num(0, 1)}"/>',
                            f'<float name="alpha_u" value="{v.num(0, 1)}"/><float name="alpha_v" value="{v.num(0, 1)}"/>',
                            ""]))
        body.append(v.pick(['<string name="distribution" value="ggx"/>',
                            '<string name="distribution" value="beckmann"/>', ""], ['<string name="distribution" '
                                                                                   'value="phong"/>']))
        body.append(v.pick(['<boolean name="sample_visible" value="false"/>', ""]))
    if t in ("dielectric", "roughdielectric"):
        body.append(v.pick([_color(v, "specular_transmittance"), _color(v, "specular_reflectance"),
                            '<string name="ext_ior" value="water"/>', ""]))
    if t in ("twosided", "mask"):
        body.append(_bsdf(v, depth + 1))
    if t == "blendbsdf":
        body += [f'<float name="weight" value="{v.num(0, 1)}"/>', _bsdf(v, depth + 1), _bsdf(v, depth + 1)]
    i = f' id="{ident}"' if ident else ""
    return f'<bsdf type="{t}"{i}>{"".join(body)}</bsdf>'


def _transform(v: _Values, name="to_world"):
    ops = []
    for _ in range(v.int(0, 3)):
        op = v.pick(["translate", "scale", "rotate", "matrix", "lookat"])
        if op == "translate":
            ops.append(f'<translate value="{v.vec()}"/>')
        elif op == "scale":
            ops.append(f'<scale value="{v.vec(0.01, 2)}"/>')
        elif op == "rotate":
            ops.append(f'<rotate value="{v.vec(-1, 1)}" angle="{v.num(-180, 180)}"/>')
        elif op == "matrix":
            vals = " ".join(v.num(-2, 2) for _ in range(12)) + " 0 0 0 1"
            ops.append(f'<matrix value="{vals}"/>')
        else:
            ops.append(f'<lookat origin="{v.vec()}" target="{v.vec()}" up="0, 1, 0"/>')
    return f'<transform name="{name}">{"".join(ops)}</transform>'


def _shape(v: _Values, bsdf_ids, light=False):
    t = v.pick(["rectangle", "rectangle", "cube", "sphere", "disk", "cylinder", "obj", "ply", "serialized"],
               ["bogus", "bsplinecurve", "instance"])
    body = [_transform(v)]
    if t == "sphere":
        body.append(f'<point name="center" value="{v.vec()}"/><float name="radius" value="{v.num(0.01, 2)}"/>')
    elif t == "cylinder":
        body.append(f'<point name="p0" value="{v.vec()}"/><point name="p1" value="{v.vec()}"/>'
                    f'<float name="radius" value="{v.num(0.01, 1)}"/>')
    elif t == "obj":
        body.append(f'<string name="filename" value="cbox/{v.pick(["small_box", "light"], ["nope"])}.obj"/>')
    elif t == "ply":
        body.append('<string name="filename" value="cbox/bunny.ply"/>')
    elif t == "serialized":
        body.append(f'<string name="filename" value="cbox/shapes.serialized"/>'
                    f'<integer name="shape_index" value="{v.pick(["0", "1", "2"], ["3", "-1", "x"])}"/>')
    if t in ("obj", "ply", "serialized") and v.pick([True, False]):
        body.append(f'<boolean name="face_normals" value="{v.pick(["true", "false"])}"/>')
    if v.pick([True, False]):
        body.append(f'<boolean name="flip_normals" value="{v.pick(["true", "false"], ["2", "yes"])}"/>')
    if bsdf_ids and v.pick([True, False]):
        body.append(f'<ref id="{v.pick(bsdf_ids, ["undefined"])}"/>')
    elif v.pick([True, False]):
        body.append(_bsdf(v))
    if light or v.int(0, 2) == 0:
        body.append(f'<emitter type="{v.pick(["area"], ["point", "bogus"])}">'
                    f'{_color(v, "radiance", emitter=True)}</emitter>')
    return f'<shape type="{t}">{"".join(body)}</shape>'


def _delta_emitter(v: _Values):
    """A point or spot light (Mitsuba's `point`, `spot`)."""
    t = v.pick(["point", "spot"], ["bogus"])
    body = [_color(v, "intensity", emitter=True)]
    if t == "point":
        body.append(v.pick([f'<point name="position" value="{v.vec()}"/>', _transform(v)]))
    else:
        body.append(f'<transform name="to_world"><lookat origin="{v.vec()}" target="{v.vec()}" up="0, 1, 0"/>'
                    '</transform>')
        body.append(v.pick([f'<float name="cutoff_angle" value="{v.num(1, 89)}"/>', ""], ['<float name='
                                                                                         '"cutoff_angle" value="-5"/>']))
        body.append(v.pick([f'<float name="beam_width" value="{v.num(0.5, 30)}"/>', ""]))
    return f'<emitter type="{t}">{"".join(body)}</emitter>'


def _top_emitter(v: _Values):
    """An emitter at the scene's top level: an environment (envmap, constant) or a directional light."""
    t = v.pick(["envmap", "constant", "directional"], ["bogus", "sunsky"])
    if t == "envmap":
        body = (f'<string name="filename" value="cbox/{v.pick(["sky.exr"], ["nope.exr", "light.obj"])}"/>'
                f'<float name="scale" value="{v.pick([v.num(0.1, 4)], ["0", "-1", "x"])}"/>' + _transform(v))
    elif t == "directional":
        body = (f'<vector name="direction" value="{v.pick([v.vec(-1, 1)], ["0, 0, 0", "x"])}"/>'
                + _color(v, "irradiance", emitter=True))
    else:
        body = _color(v, "radiance", emitter=True)
    return f'<emitter type="{t}">{body}</emitter>'


@st.composite
def xml_scenes(draw):
    """A Mitsuba scene generated from the grammar of the elements clpt reads:
    an integrator, a sensor with film and sampler, BSDFs by id (nested in
    twosided, blendbsdf and mask), shapes of every supported type with
    transforms, BSDFs, refs and area emitters, point and spot lights, and
    top-level environment and directional emitters. In one scene of two
    every value is sensible; in the others a few are extreme or malformed."""
    v = _Values(draw(st.integers(0, 2 ** 32 - 1)), draw(st.sampled_from([0.0, 0.0, 0.02, 0.1])))
    parts = [f'<scene version="{v.pick(["3.0.0", "3.0.0", "2.0.0", "0.6.0"], ["x", "9.0.0", ""])}">']
    spp = v.pick(["1", "2", "4"], ["0", "-1", "x", "1e3"])
    if v.pick([True, False]):
        parts.append(f'<default name="spp" value="{spp}"/>')
        spp = "$spp"
    if v.pick([True, False]):
        parts.append(f'<integrator type="{v.pick(["path", "path", "direct", "volpath"], ["bdpt", ""])}">'
                     f'<integer name="max_depth" value="{v.pick(["-1", "1", "4", "8"], ["0", "-2", "x"])}"/>'
                     "</integrator>")
    if v.int(0, 4):
        fov = (f'<float name="fov" value="{v.num(1, 120)}"/>' if v.int(0, 4)
               else f'<string name="focal_length" value="{v.pick(["50mm", "20"], ["0mm", "x"])}"/>')
        sides = [v.pick([str(v.int(1, 16))], ["0", "65537", "x", "1e3"]) for _ in range(2)]
        parts.append(f'<sensor type="{v.pick(["perspective", "perspective", "thinlens"], ["radiance"])}">'
                     f'{fov}<string name="fov_axis" value="{v.pick(["x", "y", "smaller"], ["z"])}"/>'
                     f'<transform name="to_world"><lookat origin="{v.vec(-5, 5)}" target="0, 0, 0" '
                     f'up="{v.pick(["0, 1, 0", "0, 1, 0", "1, 1, 1"], ["0, 0, 0", "0, 1"])}"/></transform>'
                     f'<sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>'
                     f'<film type="hdrfilm"><integer name="width" value="{sides[0]}"/>'
                     f'<integer name="height" value="{sides[1]}"/></film></sensor>')
    ids = [f"m{i}" for i in range(v.int(0, 3))]
    parts += [_bsdf(v, ident=i) for i in ids]
    parts += [_shape(v, ids, light=i == 0) for i in range(v.int(1, 5))]
    parts += [_delta_emitter(v) for _ in range(v.int(0, 2))]
    parts += [_top_emitter(v) for _ in range(v.pick([0, 0, 1], [2]))]
    parts.append("</scene>")
    return "\n".join(parts).encode()


def xml_inputs():
    """Mutated test scenes and generated ones, half and half."""
    return st.one_of(mutations_of(xml_seeds(), XML_MUTATIONS), xml_scenes())


def xml_workspace() -> Path:
    """A folder holding what the XML scenes refer to (tests/data/cbox and
    textures, a shipped PLY as cbox/bunny.ply, a serialized seed as
    cbox/shapes.serialized and an environment map as cbox/sky.exr); inputs
    are written beside it."""
    d = Path(tempfile.mkdtemp(prefix="clpt-fuzz-xml-"))
    shutil.copytree(DATA / "cbox", d / "cbox")
    shutil.copytree(DATA / "textures", d / "textures")
    shutil.copy(MESHES / "ring.ply", d / "cbox" / "bunny.ply")
    shutil.copy(DATA / "serialized" / "shapes_v4.serialized", d / "cbox" / "shapes.serialized")
    shutil.copy(DATA / "env_sky.exr", d / "cbox" / "sky.exr")
    return d


# --- OBJ and PLY meshes -------------------------------------------------------------------------

def _ply_text(vertices, faces, extra_vertex=(), extra_elements=""):
    head = ["ply", "format ascii 1.0", "comment a fuzzing seed", f"element vertex {len(vertices)}",
            "property float x", "property float y", "property float z",
            *[f"property {t} {n}" for t, n in extra_vertex], extra_elements,
            f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    body = [" ".join(repr(float(c)) for c in row) + "".join(" 1" for _ in extra_vertex) for row in vertices]
    body += [f"{len(f)} " + " ".join(map(str, f)) for f in faces]
    return ("\n".join(h for h in head if h) + "\n" + "\n".join(body) + "\n").encode()


def mesh_seeds() -> dict[str, list[bytes]]:
    """Real files to mutate, by format: the test scenes' OBJ files, a shipped
    binary PLY, and small files of each kind the readers take (OBJ with
    normals, texture coordinates, quads and negative indices; ASCII PLY with
    mixed polygons, extra properties and elements; little- and big-endian
    binary PLY with and without normals)."""
    from meshgen import uv_sphere, write_obj, write_ply

    v, t, n = uv_sphere(n_theta=4, n_phi=6)
    tmp = Path(tempfile.mkdtemp(prefix="clpt-fuzz-seeds-"))
    write_obj(tmp / "s.obj", v, t, n)
    write_ply(tmp / "s.ply", v, t, n, binary=True)
    write_ply(tmp / "p.ply", v, t, None, binary=True)
    write_ply(tmp / "a.ply", v, t, n, binary=False)
    seeds = {"obj": [(tmp / "s.obj").read_bytes()], "ply": [(tmp / f).read_bytes() for f in ("s.ply", "p.ply",
                                                                                             "a.ply")]}
    shutil.rmtree(tmp)
    seeds["obj"] += [(DATA / "cbox" / f).read_bytes() for f in ("small_box.obj", "light.obj")]
    seeds["obj"].append(b"# quads, texture coordinates, negative indices\no quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\n"
                        b"v 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\nusemtl white\ns off\n"
                        b"f 1/1/1 2/2/1 3/3/1 4/1/1\nf -4/-3 -2/-2 -1/-1\nl 1 2\n")
    square = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (3, 0, 0), (3, 1, 0)]
    seeds["ply"].append(_ply_text(square, [(0, 1, 2, 3), (4, 5, 6), (0, 2, 3)], extra_vertex=[("uchar", "red")],
                                  extra_elements="element material 0\nproperty float shine"))
    seeds["ply"].append(_ply_text(square, [(0, 1, 2, 3), (4, 5, 6)], extra_vertex=[("float", "u"), ("float", "v")]))
    seeds["ply"].append(_ply_text(square, [(0, 1, 2), (4, 5, 6)], extra_vertex=[("float", "texture_s"),
                                                                                ("float", "texture_t")]))
    big_endian = (MESHES / "ring.ply").read_bytes()
    head, body = big_endian.split(b"end_header\n", 1)
    verts = np.frombuffer(body, "<f4", 768 * 6)
    faces = np.frombuffer(body[768 * 24:], dtype=[("n", "u1"), ("i", "<i4", (3,))])
    be_faces = np.zeros(len(faces), dtype=[("n", "u1"), ("i", ">i4", (3,))])
    be_faces["n"], be_faces["i"] = faces["n"], faces["i"]
    seeds["ply"].append(head.replace(b"binary_little_endian", b"binary_big_endian") + b"end_header\n"
                        + verts.astype(">f4").tobytes() + be_faces.tobytes())
    seeds["ply"].append((MESHES / "ring.ply").read_bytes())
    return seeds


def mesh_inputs(fmt):
    return mutations_of(mesh_seeds()[fmt], TEXT_MUTATIONS)


def check_mesh_file(path: Path, render: bool, device=None, shape_index=0) -> str:
    """Read a mesh file; what loads must hold finite positions and unit normals
    and index its own vertices, and (render) render finite, 4x4 at 1 spp, as
    an emitter seen by a camera framing it."""
    from clpt.meshio import MeshError, read_mesh_uv

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            v, t, n, uv = read_mesh_uv(path, shape_index=shape_index)
    except MeshError as e:
        return refusal(e, path)
    except Exception as e:  # noqa: BLE001
        raise Failure(f"read_mesh raised {type(e).__name__}: {e}") from e
    if not (np.isfinite(v).all() and len(t) and t.min() >= 0 and t.max() < len(v)):
        raise Failure(f"{path.name}: loaded with non-finite vertices or indices out of range")
    if n is not None and not (np.abs(np.linalg.norm(n, axis=1) - 1) < 1e-9).all():
        raise Failure(f"{path.name}: loaded with normals that are not unit vectors")
    if uv is not None and not (uv.shape == (len(v), 2) and np.isfinite(uv).all()):
        raise Failure(f"{path.name}: loaded with texture coordinates not finite or not one per vertex")
    if not render:
        return "accepted"
    lo, hi = v.min(axis=0), v.max(axis=0)
    c, r = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) or 1.0
    cam = clpt.Camera(origin=tuple(c + (0.3 * r, 0.2 * r, 2 * r)), target=tuple(c), width=4, height=4)

    def render_it():  # a SceneError: a mesh the renderer cannot frame (e.g. spanning 1e-300 to 1e300)
        # Texture coordinates, where read, look up a checkerboard (the kernels' UV path).
        mat = "white" if uv is None else clpt.Material(kd=(0.8, 0.8, 0.8), textures=(
            ("reflectance", Texture("checkerboard", color0=(0.8, 0.8, 0.8), color1=(0.1, 0.2, 0.3))),))
        scene = clpt.Scene(camera=cam, shapes=[clpt.Mesh(vertices=v, triangles=t, normals=n, uvs=uv, material=mat,
                                                         emission=(1.0, 1.0, 1.0), two_sided=True)]).check()
        return clpt.Renderer(scene, kernel="generic", device=device).render(1, max_depth=3, rr_depth=2, seed=1)
    return rendered("render", render_it, path)


def rendered(what: str, render, path: Path) -> str:
    """render() (its warnings ignored) must give a finite, non-negative image
    or raise a one-line SceneError; the outcome's name."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = render()
    except clpt.SceneError as e:
        one_line(str(e), what)
        return f"refused at {what}"
    except Exception as e:  # noqa: BLE001
        raise Failure(f"{what} raised {type(e).__name__}: {e}") from e
    finite_image(res.image, path.name)
    return "rendered" if what == "render" else f"{what}d"


# --- Mitsuba serialized meshes ---------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def serialized_shapes() -> tuple:
    """Seed files as (their shapes' bytes: header and zlib stream each,
    version): the stored seeds (tests/data/serialized, every flag the reader
    takes), the blob of cbox/blob.obj in float32 without normals, and a
    float64 sphere with normals, alone."""
    from meshgen import serialized_seeds, serialized_shape, uv_sphere
    from clpt.meshio import read_mesh

    out = [([serialized_shape(version=version, **shape) for shape in shapes], version)
           for shapes, version in serialized_seeds().values()]
    v, t, _ = read_mesh(DATA / "cbox" / "blob.obj")
    sv, st_, sn = uv_sphere(n_theta=4, n_phi=6)
    out.append(([serialized_shape(v, t, name="blob"), serialized_shape(sv, st_, sn, double=True)], 4))
    out.append(([serialized_shape(sv, st_, sn, version=3)], 3))
    return tuple((tuple(shapes), version) for shapes, version in out)


def assemble_serialized(shapes: list[bytes], version: int, offsets=None, count=None) -> bytes:
    """A .serialized file of the shapes' bytes, with their dictionary of
    offsets (or the given, wrong, offsets and count)."""
    at, real = 0, []
    for b in shapes:
        real.append(at)
        at += len(b)
    offsets = real if offsets is None else offsets
    width = "<u8" if version == 4 else "<u4"
    table = np.array([o % (1 << (64 if version == 4 else 32)) for o in offsets], dtype=width).tobytes()
    return b"".join(shapes) + table + np.array([len(shapes) if count is None else count % (1 << 32)], "<u4").tobytes()


def serialized_seeds_bytes() -> list[bytes]:
    return [assemble_serialized(shapes, version) for shapes, version in serialized_shapes()]


@st.composite
def serialized_edits(draw):
    """A seed rewritten with one shape's decompressed stream damaged and
    compressed again (so the checks past zlib are reached: bytes changed,
    cut, repeated; the flags, the name or the counts replaced, often by
    extreme values), or its header or the dictionary of offsets changed."""
    import struct
    import zlib

    shapes, version = draw(st.sampled_from(serialized_shapes()))
    shapes = list(shapes)
    what = draw(st.sampled_from(["stream", "stream", "counts", "counts", "flags", "name", "header", "offsets"]))
    i = draw(st.integers(0, len(shapes) - 1))
    head, body = shapes[i][:4], bytearray(zlib.decompress(shapes[i][4:]))
    counts_at = body.index(b"\0", 4) + 1 if version == 4 else 4
    if what == "stream":
        for _ in range(draw(st.integers(1, 3))):
            body = draw(st.sampled_from([m_flip, m_byte, m_delete, m_duplicate, m_truncate]))(draw, body)
    elif what == "counts":
        k = draw(st.integers(0, 1))
        value = draw(st.one_of(st.sampled_from(EXTREME_INTS + [2 ** 64 - 1, 2 ** 40, 2 ** 32 + 1]),
                               st.integers(0, 64)))
        body[counts_at + 8 * k:counts_at + 8 * k + 8] = struct.pack("<Q", value % (1 << 64))
    elif what == "flags":
        flags = draw(st.one_of(st.integers(0, 2 ** 32 - 1), st.sampled_from([0, 0x1, 0x2, 0x8, 0x10, 0x2000, 0x3001,
                                                                               0x1003, 0x200b])))
        body[0:4] = struct.pack("<I", flags)
    elif what == "name" and version == 4:
        body[4:counts_at] = draw(st.sampled_from([b"", b"\0", b"x" * 300 + b"\0", "é".encode() + b"\0",
                                                  b"\xff\xfe\0", b"no end"]))
    elif what == "header":
        head = struct.pack("<HH", draw(st.sampled_from([0x041C, 0x041C, 0x1C04, 0])),
                           draw(st.sampled_from([3, 4, 4, 0, 5, 0xFFFF])))
    if what == "offsets":
        offsets = [draw(st.one_of(st.integers(0, 600), st.sampled_from(EXTREME_INTS + [2 ** 64 - 1])))
                   for _ in range(len(shapes))]
        count = draw(st.one_of(st.none(), st.sampled_from([0, 1, 2, 3, 99, 2 ** 31, 2 ** 32 - 1])))
        return assemble_serialized(shapes, version, offsets, count)
    shapes[i] = head + zlib.compress(bytes(body), draw(st.sampled_from([0, 1, 6, 9])))
    return assemble_serialized(shapes, version)


def serialized_inputs():
    """Byte-level damage of the seed files (mostly caught by zlib), edits
    that keep the streams valid zlib (serialized_edits), twice as often,
    and now and then random bytes."""
    seeds = serialized_seeds_bytes()
    return st.one_of(mutations_of(seeds, BYTE_MUTATIONS), serialized_edits(), serialized_edits(),
                     st.binary(max_size=200))


def check_serialized_file(path: Path, render: bool, device=None) -> str:
    """check_mesh_file for each of shape_index 0, 1 and 2 (the seeds hold
    one to three shapes, so the last are often out of range); the outcome of
    the first, with the others' refusals checked too."""
    outcomes = [check_mesh_file(path, render and k == 0, device, shape_index=k) for k in range(3)]
    return outcomes[0]


# --- checkpoints ----------------------------------------------------------------------------------

def checkpoint_seeds() -> list[bytes]:
    """Checkpoints written by clpt's writer for tiny (4x4) jobs of each kind:
    plain, offline caustics (caustic planes), adaptive with a round's pixels
    to redo, a mesh (the job's arrays), feature buffers and the filter. The
    sums are random but of the right layout; every job uses the generic
    kernel, so resuming one builds nothing new."""
    from clpt.engine.accum import Accumulator
    from clpt.engine.checkpoint import write_checkpoint
    from clpt.engine.job import DeviceOptions, RenderJob
    from meshgen import uv_sphere

    v, t, n = uv_sphere(center=(0.3, -0.6, 0.2), radius=0.3, n_theta=4, n_phi=6)
    box = clpt.load_scene("cornell_box")
    with_mesh = copy.copy(box)
    with_mesh.shapes = box.shapes + [clpt.Mesh(vertices=v, triangles=t, normals=n, material="white", name="ball")]
    generic = DeviceOptions(kernel="generic")
    jobs = [
        (RenderJob(box, 8, 1, 8, 2, 4, 4, generic), {}, 4),
        (RenderJob(clpt.load_scene("cornell_box_caustics"), 8, 2, 8, 2, 4, 4, DeviceOptions(kernel="generic"),
                   photons=clpt.PhotonSettings(count=2000, mode="offline", offline_spp=2)), {"caustic": True}, 2),
        (RenderJob(box, 8, 3, 8, 2, 4, 4, generic, adaptive=clpt.AdaptiveSettings(min_spp=2, pass_spp=2)), {}, 2),
        (RenderJob(with_mesh, 4, 4, 8, 2, 4, 4, generic), {}, 2),
        (RenderJob(box, 4, 5, 8, 2, 4, 4, DeviceOptions(kernel="generic", aux=True), filter=clpt.FilterSettings()),
         {"aux": True}, 1),
    ]
    rng = np.random.default_rng(26)
    tmp = Path(tempfile.mkdtemp(prefix="clpt-fuzz-ckpt-"))
    seeds = []
    for i, (job, layout, done) in enumerate(jobs):
        sums = Accumulator(job.n_pix, **layout)
        for k, plane in sums.planes.items():
            plane[...] = rng.uniform(0, 2, plane.shape)
        for p in ("", "c_") if "c_sum" in sums.planes else ("",):
            sums.planes[p + "sum"][:, 3] = done
        adaptive = job.adaptive is not None
        redo = [{"kind": "pixels", "s0": 0, "n": 0, "iteration": 0, "round": 0, "pixels": [1, 5],
                 "jobs": [[2, 8, 2, 0], [2, 8, 2, 0]]}] if adaptive else []
        state = {"next": done, "prepass_done": True, "rounds": int(adaptive), "adaptive_over": False, "redo": redo}
        write_checkpoint(tmp / f"{i}.ckpt", job, sums, state, elapsed=1.5)
        seeds.append((tmp / f"{i}.ckpt").read_bytes())
    shutil.rmtree(tmp)
    return seeds


def _members(data: bytes) -> dict:
    import io
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _archive(members: dict) -> bytes:
    import io
    buf = io.BytesIO()
    np.savez(buf, **members)
    return buf.getvalue()


def _json_member(a) -> object:
    return json.loads(bytes(a).decode())


def _as_member(doc) -> np.ndarray:
    return np.frombuffer(json.dumps(doc).encode(), dtype=np.uint8)


@st.composite
def checkpoint_edits(draw, seeds):
    """A seed rewritten as a valid archive with a member changed: a value in
    the meta or job JSON replaced, deleted or made extreme (then, half the
    time, meta's job hash recomputed for the changed job, so the checks past
    the hash are reached), a plane or mesh array damaged (non-finite or
    negative values, another shape or type), a member dropped or added."""
    from clpt.engine.checkpoint import CheckpointError, _decode, _job_types

    m = _members(draw(st.sampled_from(seeds)))
    what = draw(st.sampled_from(["meta", "meta", "job", "job", "job", "array", "array", "drop", "add"]))
    if what in ("meta", "job"):
        doc = _json_member(m[what])
        paths = [p for p, _ in _paths(doc) if p]
        path = draw(st.sampled_from(paths))
        action = draw(st.sampled_from(["replace", "replace", "extreme", "delete"]))
        try:
            _set(doc, path, _DELETE if action == "delete" else draw(values) if action == "replace"
                 else draw(st.sampled_from(EXTREME_FLOATS + EXTREME_INTS)))
        except (KeyError, IndexError, TypeError):
            pass
        m[what] = _as_member(doc)
        if what == "job" and draw(st.booleans()):
            meta = _json_member(m["meta"])
            arrays = [m[f"job_array_{i}"] for i in range(sum(k.startswith("job_array_") for k in m))]
            try:
                meta["job_key"] = _decode(doc, arrays, _job_types(), lambda r: (_ for _ in ()).throw(
                    CheckpointError(r))).key
                m["meta"] = _as_member(meta)
            except Exception:  # noqa: BLE001 - a job that does not decode: the reader must refuse it anyway
                pass
    elif what == "array":
        name = draw(st.sampled_from(sorted(k for k in m if k.startswith(("plane_", "job_array_")))))
        a = m[name].copy()
        op = draw(st.sampled_from(["nan", "inf", "negative", "shape", "dtype", "huge"]))
        flat = a.reshape(-1)
        i = draw(st.integers(0, max(flat.size - 1, 0)))
        if op in ("nan", "inf", "negative") and flat.size:
            if a.dtype.kind == "f":
                flat[i] = {"nan": np.nan, "inf": np.inf, "negative": -1e3}[op]
            else:
                flat[i] = {"nan": -1, "inf": np.iinfo(a.dtype).max, "negative": -7}[op]
        elif op == "shape":
            a = a.reshape(-1)[:max(flat.size - draw(st.integers(1, 3)), 0)] if flat.size else a
        elif op == "dtype":
            a = a.astype(draw(st.sampled_from([np.float32, np.int8, np.uint64, np.complex64, np.bool_])))
        else:
            a = np.repeat(a, 2, axis=0)
        m[name] = a
    elif what == "drop":
        del m[draw(st.sampled_from(sorted(m)))]
    else:
        m[draw(st.sampled_from(["plane_bogus", "plane_aux", "job_array_99", "plane_c_sum"]))] = np.zeros((16, 4))
    return _archive(m)


def checkpoint_inputs():
    """Byte-level damage (mostly caught by the zip format and its CRCs), and
    edits that keep the archive valid, so the checks of its content are reached;
    now and then an empty file or random bytes."""
    seeds = checkpoint_seeds()
    return st.one_of(mutations_of(seeds, BYTE_MUTATIONS), checkpoint_edits(seeds), checkpoint_edits(seeds),
                     st.sampled_from([b""]), st.binary(max_size=200))


def check_checkpoint_file(path: Path, render: bool, device=None) -> str:
    """Read a checkpoint; what loads holds finite sums of the job's shape and
    (render) resumes to a finite image in at most a few seconds."""
    from clpt.engine.checkpoint import Checkpoint, CheckpointError

    try:
        ck = Checkpoint(path)
    except CheckpointError as e:
        return refusal(e, path)
    except Exception as e:  # noqa: BLE001
        raise Failure(f"Checkpoint raised {type(e).__name__}: {e}") from e
    for k, v in ck.sums.planes.items():
        if not np.isfinite(v).all():
            raise Failure(f"{path.name}: loaded with non-finite sums in plane {k}")
    if not render:
        return "accepted"
    return rendered("resume", lambda: clpt.Renderer(ck.job.scene, device=device, **ck.job.options.renderer_kwargs())
                    .resume(ck, time_limit=3.0, out_checkpoint=path.with_suffix(".out.ckpt")), path)


# --- the readers, for the fuzzers ---------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Reader:
    """One kind of file clpt reads: a strategy of its inputs (bytes), the name
    an input is written under (in a fresh folder, or in workspace() when it
    refers to other files), and its check: check(path, render, device) returns
    the outcome's name or raises Failure.

    Textures are not read yet; they will be one more entry: seed files to
    mutate (e.g. small EXR and PNG files) and a check that loads the file
    through its reader and renders what loads."""

    name: str
    inputs: Callable[[], object]
    filename: str
    check: Callable[..., str]
    workspace: Callable[[], Path] = lambda: Path(tempfile.mkdtemp(prefix="clpt-fuzz-"))


READERS = {
    "toml": Reader("toml", scene_texts, "scene.toml", check_scene_file),
    "xml": Reader("xml", xml_inputs, "fuzz.xml",
                  lambda p, render, device=None: check_scene_file(p, render, device, need_place=True),
                  workspace=xml_workspace),
    "obj": Reader("obj", lambda: mesh_inputs("obj"), "fuzz.obj", check_mesh_file),
    "ply": Reader("ply", lambda: mesh_inputs("ply"), "fuzz.ply", check_mesh_file),
    "serialized": Reader("serialized", serialized_inputs, "fuzz.serialized", check_serialized_file),
    "checkpoint": Reader("checkpoint", checkpoint_inputs, "fuzz.ckpt", check_checkpoint_file),
}
