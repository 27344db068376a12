"""The lab (clpt/tools/: benchmarks, studies, metrics, references) stays out
of the library: `import clpt` and `clpt render` load none of it, no library
module imports it or the CLI, and each subcommand has its own module in
clpt/cli/. The one reference helper renders, saves and reads back."""

import ast
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import clpt
from clpt.cli import COMMANDS, build_parser

CLPT = Path(clpt.__file__).resolve().parent

LOADED_TOOLS = "import sys; print(sorted(m for m in sys.modules if m == 'clpt.tools' or m.startswith('clpt.tools.')))"


def _run(code: str) -> str:
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ),
                       timeout=600)
    assert p.returncode == 0, p.stderr
    return p.stdout.strip().splitlines()[-1]


def test_import_clpt_and_its_parser_load_no_tools():
    assert _run(f"import clpt, clpt.cli; clpt.cli.build_parser(); {LOADED_TOOLS}") == "[]"


def test_render_command_loads_no_tools(tmp_path, device_spec):
    out = tmp_path / "r.png"
    argv = ["render", "cornell_box", "--spp", "1", "--width", "8", "--height", "8", "-q", "-o", str(out),
            "--device", device_spec]
    assert _run(f"from clpt.cli import main; assert main({argv!r}) == 0; {LOADED_TOOLS}") == "[]"
    assert out.exists()


def test_a_study_command_loads_its_tools(capsys, monkeypatch):
    """The other side of the two tests above: the tools are there, behind their subcommand."""
    from clpt.tools import bench

    seen = []
    monkeypatch.setattr(bench, "run_bench_builds", lambda a: seen.append(a.scene) or 0)
    from clpt.cli import main
    assert main(["bench-builds", "cornell_box"]) == 0 and seen == [["cornell_box"]]


def _imports(path: Path) -> set[str]:
    """The clpt modules a file imports anywhere in it (relative imports resolved)."""
    rel = path.relative_to(CLPT.parent).with_suffix("")
    package = list(rel.parts[:-1])  # a module's package; an __init__'s is its own folder
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)  # `from . import metrics`
    return {m for m in out if m == "clpt" or m.startswith("clpt.")}


def _lab(name: str) -> bool:
    return name.startswith(("clpt.tools", "clpt.cli"))


def test_the_library_never_imports_the_tools_or_the_cli():
    """Not even inside a function: the library is usable and importable without them."""
    files = [p for p in CLPT.rglob("*.py") if p.relative_to(CLPT).parts[0] not in ("tools", "cli", "__main__.py")]
    assert len(files) > 20
    wrong = {str(p.relative_to(CLPT)): sorted(m for m in _imports(p) if _lab(m)) for p in files}
    assert not {k: v for k, v in wrong.items() if v}


def test_the_tools_never_import_the_cli():
    """The CLI imports the tools (when a subcommand runs), never the other way round: no circle."""
    wrong = {str(p.relative_to(CLPT)): sorted(m for m in _imports(p) if m.startswith("clpt.cli"))
             for p in (CLPT / "tools").rglob("*.py")}
    assert not {k: v for k, v in wrong.items() if v}


def test_each_subcommand_runs_from_its_own_module():
    ap = build_parser()
    sub = next(a for a in ap._actions if a.__class__.__name__ == "_SubParsersAction")
    assert len(sub.choices) == len(COMMANDS)
    needs = {"compare": ["x"], "tradeoff": ["x"], "check": ["x"]}
    for name in sub.choices:
        func = ap.parse_args([name, *needs.get(name, [])]).func
        assert func.__module__ == "clpt.cli." + name.replace("-", "_"), name


def test_shared_options_are_the_same_option_everywhere():
    """--device is -d in every command that has it; --width and --height are integers."""
    ap = build_parser()
    sub = next(a for a in ap._actions if a.__class__.__name__ == "_SubParsersAction")
    for name, p in sub.choices.items():
        flags = {f: a for a in p._actions for f in a.option_strings}
        if "--device" in flags:
            assert flags["-d"] is flags["--device"], name
        for f in ("--width", "--height", "--ref-spp", "--max-depth"):
            if f in flags:
                assert flags[f].type is int, (name, f)


def test_relmse_luma_takes_the_references_noise_out():
    from clpt.tools.metrics import relmse, relmse_luma

    rng = np.random.default_rng(5)
    truth = np.full((64, 64, 3), 0.5)
    sigma = 0.05  # each reference pixel's luminance mean: truth + N(0, sigma^2)
    ref = truth + rng.normal(0.0, sigma, (64, 64, 1))
    img = truth + rng.normal(0.0, 0.02, (64, 64, 1))
    exact = relmse_luma(img, truth)
    assert relmse_luma(img, ref) > 5 * exact  # the reference's noise dominates
    corrected = relmse_luma(img, ref, np.full((64, 64), sigma ** 2))
    # Unbiased: per pixel, (e_i - e_r)^2 - sigma^2 has mean e_i's variance and
    # variance 2 (s_i^2 + s_r^2)^2 (Gaussian errors); over the 4096 pixels
    # the mean's standard error is that over 64, divided by r^2 + eps.
    se = np.sqrt(2.0) * (0.02 ** 2 + sigma ** 2) / 64 / (0.25 + 1e-2)
    assert abs(corrected - exact) < 4 * se
    assert relmse_luma(img, truth) == pytest.approx(relmse(img, truth), rel=1e-12)  # grey: luminance = channels


def test_relmse_rgb_denoised_takes_a_coloured_references_noise_out():
    """A reference whose noise is its colour times one random factor per
    pixel (each channel's variance the luminance's times (r_c / Y)^2): the
    RGB relMSE less that noise is the error against the truth, within its
    standard error; without the noise taken out it is several times more."""
    from clpt.constants import LUMA
    from clpt.tools.metrics import relmse, relmse_rgb_denoised

    rng = np.random.default_rng(8)
    truth = rng.uniform(0.02, 1.0, (64, 64, 3)) * rng.uniform(0.2, 1.0, (64, 64, 1))
    rel = 0.08  # the reference's relative noise: ref = truth (1 + N(0, rel^2))
    ref = truth * (1.0 + rng.normal(0.0, rel, (64, 64, 1)))
    img = truth * (1.0 + rng.normal(0.0, 0.02, (64, 64, 1)))
    exact = relmse(img, truth)
    assert relmse(img, ref) > 5 * exact
    lum_var = ((truth @ LUMA) * rel) ** 2  # the reference's luminance mean's variance
    corrected = relmse_rgb_denoised(img, ref, lum_var)
    # Per pixel and channel, (e_i - e_r)^2 - var_r has mean var_i and standard deviation
    # sqrt(2) (var_i + var_r) (Gaussian errors); the channels of a pixel move together.
    w = (truth * truth) / (truth * truth + 1e-2)
    per_pixel = (np.sqrt(2.0) * (0.02 ** 2 + rel ** 2) * w).mean(axis=-1)
    se = np.sqrt((per_pixel ** 2).sum()) / per_pixel.size
    assert abs(corrected - exact) < 4 * se


def test_reference_renders_saves_and_reads_back(tmp_path, device_spec):
    from clpt.image import read_metadata
    from clpt.scene import SettingsError
    from clpt.tools.reference import SEED, cached_path, reference_image

    path = cached_path(tmp_path / "refs", "scenes/cornell_box.toml", 12, 8, 16, max_depth=3)
    assert path == tmp_path / "refs" / "cornell_box_12x8_d3_16spp.exr"
    assert cached_path(tmp_path, "cornell_box", 12, 8, 16).name == "cornell_box_12x8_16spp.exr"
    ref = reference_image("cornell_box", 12, 8, 16, path, device_spec, max_depth=3)
    # Path tracing alone at the references' seed, the image as Renderer makes it.
    res = clpt.Renderer("cornell_box", device=device_spec, photons=False).render(16, width=12, height=8,
                                                                                  max_depth=3, seed=SEED)
    assert ref.shape == (8, 12, 3) and ref.dtype == np.float64
    assert np.array_equal(ref, res.image.astype(np.float64))
    noise = float((res.lum_var / np.maximum(res.sample_count, 1)).mean())
    assert ref.noise == pytest.approx(noise, rel=1e-12) and noise > 0
    meta = read_metadata(path)
    assert int(meta["clpt:reference_spp"]) == 16 and int(meta["clpt:max_depth"]) == 3
    again = reference_image("cornell_box", 12, 8, 16, path, device_spec, max_depth=3)  # read, not rendered
    assert np.array_equal(again, ref) and again.noise == pytest.approx(noise, rel=1e-6)
    # The noise per pixel, saved beside the image.
    per_pixel = res.lum_var / np.maximum(res.sample_count, 1)
    assert np.allclose(ref.noise_map, per_pixel, rtol=1e-12) and np.allclose(again.noise_map, per_pixel, rtol=1e-6)
    with pytest.raises(SettingsError, match=r"is 12x8, not 8x8$"):
        reference_image("cornell_box", 8, 8, 16, path, device_spec)


@pytest.mark.slow  # a dozen kernel builds (one per marked shape): about 40 s on 2 busy cores
def test_denoise_bench_regions_find_the_balls_the_caustic_and_the_lamps_reflections(device_spec):
    """bench-denoise's regions of cornell_box_caustics: each ball where it is
    (the mirror ball left of the glass ball, both in the lower half), no
    pixel in two of diffuse / glass / mirror, the caustic on the floor and
    the lamp's reflections on the balls; a reference measured against itself
    has no error and all its energy."""
    from clpt.tools.bench_denoise import region_errors, regions
    ref = clpt.render("cornell_box_caustics", spp=32, width=32, height=32, max_depth=16, seed=3,
                      device=device_spec, photons=False)
    m = regions("cornell_box_caustics", 32, 32, ref, device=device_spec, spp=8)
    assert {"diffuse", "glass ball", "mirror ball", "caustic", "brightest 1%"} <= set(m)
    glass, mirror = (np.argwhere(m[k]) for k in ("glass ball", "mirror ball"))
    assert mirror[:, 1].mean() < glass[:, 1].mean() and min(glass[:, 0].min(), mirror[:, 0].min()) >= 16
    assert not (m["diffuse"] & (m["glass ball"] | m["mirror ball"])).any() and not (m["glass ball"] & m["mirror ball"]).any()
    assert not (m["caustic"] & m["diffuse"]).any() and np.argwhere(m["caustic"])[:, 0].min() >= 16
    if "lamp reflections" in m:
        assert not (m["lamp reflections"] & ~(m["glass ball"] | m["mirror ball"])).any()
    for k, e in region_errors(ref, ref, m).items():
        assert e["relmse"] == 0 and e["energy"] == pytest.approx(1.0), k


def test_bench_photons_warns_when_the_references_noise_hides_the_error():
    from clpt.tools.bench import REFERENCE_NOISE_SHARE, reference_noise_warning

    def et(noise, errors):
        return {"reference_noise_luma": {"caustic": noise, "image": noise / 10},
                "runs": [{"method": m, "seconds": 60.0, "relmse_caustic": e, "relmse_caustic_luma": e - noise}
                         for m, e in errors.items()]}

    assert reference_noise_warning(et(1e-5, {"path tracing": 1e-3, "merging": 1e-4})) is None  # 10%
    warn = reference_noise_warning(et(4e-4, {"path tracing": 1.8e-3, "merging": 5e-4}))
    assert warn is not None and "80%" in warn and "merging at 60.0 s" in warn
    edge = 1e-3 * REFERENCE_NOISE_SHARE
    assert reference_noise_warning(et(edge, {"path tracing": 1e-3})) is None
    assert reference_noise_warning(et(edge * 1.01, {"path tracing": 1e-3})) is not None
    assert reference_noise_warning({"runs": []}) is None  # no noise map: nothing to say


def test_equal_cpu_time_runs_fill_their_budget(tmp_path, device_spec):
    """bench-photons --cpu-time: each method's render uses its CPU budget
    (within the 10% the bench allows before it renders again rescaled, plus
    a margin for a machine shared with other work), whatever its cost per
    sample does over a render; path tracing and merging on the caustics box."""
    from clpt.tools.bench import caustic_equal_time

    out = caustic_equal_time("cornell_box_caustics", device=device_spec, width=16, height=16, seconds=(0.5,),
                             reference=str(tmp_path / "ref.exr"), ref_spp=64, max_depth=8,
                             methods=("path", "default"), cpu=True)
    runs = {r["method"]: r for r in out["runs"]}
    assert len(runs) == 2 and runs["merging (default: MIS, progressive, pilot)"]["choice"] == "photon merging"
    for r in runs.values():
        assert 0.3 <= r["cpu_seconds"] <= 0.8, r
        assert r["spp"] > 1 and np.isfinite(r["relmse_image"]) and r["relmse_image"] > 0
    # A 64-spp reference's caustic is mostly its own noise: the bench says so.
    assert "more samples (--ref-spp)" in out["reference_noise_warning"]


class _FakeClock:
    """A process_time that advances only by what a fake render costs."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


@pytest.mark.parametrize("per, jitter", [(2e-6, 0.0), (2e-6, 3e-3), (0.0, 3e-3)])
def test_cpu_cost_per_spp_is_never_lost_in_a_renders_jitter(monkeypatch, per, jitter):
    """bench's equal-CPU-time calibration: on a small image, 32 more spp can
    cost less than the jitter of a render's fixed cost; the spp it asks for
    a budget must stay within that budget (it once asked for 5e8 spp of a
    16x16 image: a run of hours) and, where the cost per spp can be told
    apart, come near it."""
    from clpt.tools import bench

    clock = _FakeClock()
    monkeypatch.setattr(bench.time, "process_time", clock)
    rng = np.random.default_rng(3)
    fixed = 0.01

    def render(n):  # the fixed cost, up to `jitter` more, and per spp
        clock.t += fixed + jitter * rng.random() + per * n

    got_per, got_fixed = bench.cpu_cost_per_spp(render, 0.1, max_spp=1 << 16)
    budget = 0.5
    spp = int((budget - got_fixed) / got_per)
    assert fixed + per * spp <= budget * 1.1, (got_per, got_fixed, spp)
    if per > 0:
        assert got_per == pytest.approx(per, rel=0.1) and got_fixed == pytest.approx(fixed, abs=jitter + 1e-3)
