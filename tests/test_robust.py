"""Bad input and extreme scenes never give a silently wrong image nor lose a
render: offsets that follow the hit point and not the scene's extent, scales
far from 1, float-range checks naming the key, everything about a render
checked before its first sample, a fallback when saving fails, honest
metadata, warnings for options that do nothing, clear API errors, and scene
files read with limits."""

import os
import sys
from dataclasses import replace

import numpy as np
import pytest

import clpt
from clpt import preflight
from clpt.cli import main
from clpt.image import read_metadata
from clpt.photons import PhotonSettings

from test_extremes import assert_finite, assert_same_render, transform

W = 16


@pytest.fixture(scope="module")
def cbox_scene():
    return clpt.load_scene("cornell_box")


@pytest.fixture(scope="module")
def cbox_ref(cbox_scene, device_spec):
    return clpt.Renderer(cbox_scene, device=device_spec).render(256, width=W, height=W, seed=1)


# --- offsets and scale ------------------------------------------------------------------


def test_ground_sphere_does_not_change_the_box(device_spec, cbox_scene, cbox_ref):
    """A sphere of radius 1e6 just under the box (a common ground idiom) makes
    the scene's extent 2e6: the box must still render as the box (means, 4x4
    blocks and pixels within noise). With offsets relative to the extent
    (about 7 units here) every shadow ray left the box and the walls went
    black."""
    ground = clpt.Sphere(center=(0, -1000001.5, 0), radius=1e6, material="white", name="ground")
    r = clpt.Renderer(replace(cbox_scene, shapes=[*cbox_scene.shapes, ground]), device=device_spec)
    res = r.render(256, width=W, height=W, seed=1)
    assert_finite(res)
    assert_same_render(res, cbox_ref, "box with a ground sphere")


@pytest.mark.parametrize("s", [1e-37, 1e-30, 1e-20, 1e20, 1e30, 1e37])
def test_box_at_extreme_scales_renders_like_the_box(device_spec, cbox_scene, cbox_ref, s):
    """The box scaled by 1e-37 to 1e37 (its extent near float's limits: the
    camera at 3.9e37 is within a factor 10 of FLT_MAX) renders like the
    unscaled box: lengths are packed at a power-of-two scale that brings the
    extent near 1, where the kernels' squared distances fit in float."""
    r = clpt.Renderer(transform(cbox_scene, s), device=device_spec)
    assert r.packed.length_scale != 1.0
    res = r.render(256, width=W, height=W, seed=1)
    assert_finite(res)
    assert_same_render(res, cbox_ref, f"box x {s:g}")


def test_scale_is_exact_power_of_two(cbox_scene):
    from clpt.pack import length_scale, pack_scene

    assert length_scale(cbox_scene.extent()) == 1.0  # ordinary scenes are packed as they are
    big = pack_scene(transform(cbox_scene, 2.0 ** 40))
    assert big.length_scale == 2.0 ** -43
    assert np.array_equal(big.records, pack_scene(transform(cbox_scene, 2.0 ** -3)).records)


# --- float range in the checker -------------------------------------------------------------


def _with(cbox_scene, *shapes):
    return replace(cbox_scene, shapes=[*cbox_scene.shapes, *shapes])


@pytest.mark.parametrize("shape,key", [
    (clpt.Sphere(center=(1e39, 0, 0), radius=0.1, name="far"), "center"),
    (clpt.Sphere(center=(0, 0, 0), radius=1e300, name="far"), "radius"),
    (clpt.Sphere(center=(0, 0, 0), radius=1e-25, name="far"), "radius"),
    (clpt.Sphere(radius=0.1, material=clpt.Material(ks=(0.5,) * 3, shininess=1e39), name="far"), "shininess"),
    (clpt.Sphere(radius=0.1, material=clpt.Material(kt=(1,) * 3, ior=1e39), name="far"), "ior"),
    (clpt.Quad(corner=(0, 0, 0), edge_u=(1e-22, 0, 0), edge_v=(0, 1, 0), name="far"), "edge_u"),
    (clpt.Sphere(two_sided="no", name="far"), "two_sided"),
    (clpt.Quad(corner=(1e5, 0, 0), edge_u=(1e-3, 0, 0), edge_v=(0, 1e-3, 0), name="far"), "edge_u"),
    (clpt.Triangle(vertices=((1e5, 0, 0), (1e5, 1e-3, 0), (1e5, 0, 1e-3)), name="far"), "vertices"),
], ids=["center-1e39", "radius-1e300", "radius-tiny", "shininess-1e39", "ior-1e39", "edge-tiny", "two-sided-str",
        "quad-far-tiny", "triangle-far-tiny"])
def test_unrepresentable_values_are_refused_naming_the_key(cbox_scene, shape, key):
    with pytest.raises(clpt.SceneError, match=rf"shapes\[\d+\] 'far'(\.material)?\.{key}:"):
        _with(cbox_scene, shape).check()


def test_scenes_float_cannot_place_are_refused(cbox_scene):
    """A box whose corners pass float's range though its centre and size do
    not, and a tiny scene so far from the origin that, packed at an extent
    near 1, its positions would leave float's range."""
    big = clpt.Box(center=(3e38, 0, 0), size=(1e38, 1e38, 1e38), name="big")
    with pytest.raises(clpt.SceneError, match="shapes: the scene reaches .* beyond float's range"):
        _with(cbox_scene, big).check()
    speck = clpt.Scene(camera=clpt.Camera(origin=(1e10, 0, 1e-25), target=(1e10, 0, 0)),
                       shapes=[clpt.Sphere(center=(1e10, 0, 0), radius=1e-26, emission=(1, 1, 1))])
    with pytest.raises(clpt.SceneError, match="float cannot place it; move it near the origin"):
        speck.check()


def test_toml_integers_beyond_range_are_refused(tmp_path):
    text = clpt.resources.scene_path("cornell_box").read_text()
    p = tmp_path / "s.toml"
    for key, old, new in (("max_depth", "max_depth = 8", "max_depth = 4611686018427387904"),
                          ("spp", "spp = 64", f"spp = {2 ** 40}"), ("seed", "spp = 64", "spp = 64\nseed = -1")):
        p.write_text(text.replace(old, new))
        with pytest.raises(clpt.SceneError, match=f"render.{key}: must be"):
            clpt.load_scene(p)
    p.write_text(text.replace("fov = 39.3077", "fov = " + "9" * 400))
    with pytest.raises(clpt.SceneError, match="camera.fov: must be within float's range"):
        clpt.load_scene(p)


# --- scene files -------------------------------------------------------------------------------


def test_scene_files_only_regular_and_bounded(tmp_path):
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    with pytest.raises(clpt.SceneError, match="not a regular file"):
        clpt.load_scene(fifo)  # would block forever in open() or read()
    with pytest.raises(clpt.SceneError, match="not a regular file"):
        clpt.load_scene("/dev/zero")  # would be read without end
    big = tmp_path / "big.toml"
    with open(big, "wb") as f:
        f.truncate(clpt.scene.MAX_SCENE_BYTES + 1)
    with pytest.raises(clpt.SceneError, match="too large"):
        clpt.load_scene(big)
    deep = tmp_path / "deep.toml"
    deep.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(clpt.SceneError, match="nested too deeply") as e:
        clpt.load_scene(deep)
    assert "\n" not in str(e.value)
    with pytest.raises(clpt.SceneError, match="is a folder"):
        clpt.load_scene(tmp_path)


# --- the Python API --------------------------------------------------------------------------


@pytest.mark.parametrize("call,exc,match", [
    (lambda: clpt.Material(kd="red"), TypeError, "Material.kd must be 3 numbers"),
    (lambda: clpt.Material(ior="glass"), TypeError, "Material.ior must be a number"),
    (lambda: clpt.Quad.from_vertices([(0, 0, 0), (1, 0, 0), (1, 2, 0), (0, 1, 0)]), clpt.SceneError,
     "not a parallelogram"),
    (lambda: clpt.Quad.from_vertices([(0, 0), (1, 0), (1, 1), (0, 1)]), clpt.SceneError, "4 vertices of 3"),
    (lambda: clpt.Renderer("cornell_box", lanes=3), ValueError, "lanes must be one of"),
    (lambda: clpt.Renderer("cornell_box", kernel="fast"), ValueError, "kernel must be"),
    (lambda: PhotonSettings(radius="a").check(), clpt.SceneError, "radius must be a number"),
    (lambda: PhotonSettings(budget=1.5).check(), clpt.SceneError, "budget must be an integer"),
    (lambda: PhotonSettings(count=True).check(), clpt.SceneError, "count must be an integer"),
    (lambda: PhotonSettings(progressive="yes").check(), clpt.SceneError, "progressive must be True, False or None"),
    (lambda: clpt.AdaptiveSettings(min_spp="a").check(), clpt.SceneError, "min_spp must be an integer"),
    (lambda: clpt.AdaptiveSettings(threshold=float("nan")).check(), clpt.SceneError, "threshold must be a number"),
])
def test_api_mistakes_raise_clear_errors(call, exc, match):
    with pytest.raises(exc, match=match) as e:
        call()
    assert "\n" not in str(e.value)


# --- the command line: checked before the first sample -----------------------------------------


@pytest.fixture
def no_render(monkeypatch):
    """Fail the test if a Renderer is made (the mistake must be found first)."""
    def refuse(*a, **k):
        raise AssertionError("a Renderer was made before the options were checked")
    monkeypatch.setattr(sys.modules["clpt.render"], "Renderer", refuse)


@pytest.mark.parametrize("args,message", [
    (["-o", "out.epx"], ".epx is not an image format"),
    (["-o", "/proc/x.exr"], "cannot write in /proc"),
    (["-o", ""], "the output path is empty"),
    (["-o", "noext"], "no file extension"),
    (["--exposure", "nan"], "--exposure: must be a finite number"),
    (["--exposure", "1e308"], "--exposure: must be <= 64"),
    (["--time-limit", "nan"], "--time-limit: must be a finite number"),
    (["--time-limit", "0"], "--time-limit: must be > 0"),
    (["--time-limit", "-1"], "--time-limit: must be > 0"),
    (["--filter-interval", "-1"], "--filter-interval: must be an integer from 0"),
    (["--max-depth", "3000000000"], "--max-depth: must be an integer from 0 to 2147483647"),
    (["--seed", "4294967296"], "--seed: must be an integer from 0"),
    (["--save-sample-map", "/proc/map.png"], "--save-sample-map /proc/map.png: cannot write"),
    (["--width", "65536", "--height", "2", "-o", "x.jpg"], ".jpg images are at most 65500 pixels a side"),
    (["--width", "65537"], "--width: must be an integer from 1 to 65536"),
])
def test_render_mistakes_refused_before_rendering(tmp_path, capsys, no_render, args, message):
    if "-o" not in args:
        args = [*args, "-o", str(tmp_path / "x.png")]
    elif args[args.index("-o") + 1] == "x.jpg":
        args[args.index("-o") + 1] = str(tmp_path / "x.jpg")
    assert main(["render", "--spp", "1", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("clpt: error:") and "\n" not in err and message in err, err


def test_unwritable_output_refused_before_rendering(tmp_path, capsys, no_render):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if os.access(locked, os.W_OK):
            pytest.skip("running as a user who may write anywhere (root)")
        assert main(["render", "--spp", "1", "-o", str(locked / "x.exr")]) == 2
        assert "permission denied" in capsys.readouterr().err
    finally:
        locked.chmod(0o700)


def test_memory_is_checked_and_refusal_says_what_fits():
    need = preflight.host_bytes_needed(8192, 8192)
    assert 11e9 < need < 14e9  # measured: 12.4 GB peak RSS
    with pytest.raises(clpt.SceneError, match=r"needs about 12\.\d GiB .* at most about (\d+)x\1 fits"):
        preflight.check_memory(8192, 8192, aux=False, adaptive=False, photons=0, available=8 << 30)
    preflight.check_memory(512, 512, aux=True, adaptive=True, photons=10 ** 6, available=8 << 30)


def test_save_failure_writes_a_fallback_exr(tmp_path, capsys, monkeypatch, device_spec):
    """If the image cannot be written after all (here: the writer fails), the
    render is kept as an EXR beside the output and the message names it."""
    import clpt.image

    real = clpt.image.save_image

    def failing(path, *a, **k):
        if str(path).endswith(".png"):
            raise clpt.image.ImageError(f"{path}: disk full")
        return real(path, *a, **k)

    monkeypatch.setattr(clpt.image, "save_image", failing)
    out = tmp_path / "x.png"
    dev = ["--device", device_spec] if device_spec else []
    assert main(["render", "--spp", "2", "--width", "8", "--height", "8", "-o", str(out), *dev]) == 1
    err = capsys.readouterr().err
    fb = tmp_path / "x.clpt-unsaved.exr"
    assert f"the render was written to {fb}" in err and "disk full" in err
    img = clpt.load_image(fb)
    assert img.shape == (8, 8, 3) and np.isfinite(img).all() and img.mean() > 0
    assert read_metadata(fb)["clpt:spp"] == 2


def test_options_that_do_not_apply_warn(tmp_path, capsys, device_spec):
    dev = ["--device", device_spec] if device_spec else []
    base = ["render", "--spp", "1", "--width", "4", "--height", "4", "-o", str(tmp_path / "x.png"), *dev]
    assert main([*base, "--photons", "10", "--filter-width", "3", "--min-spp", "2"]) == 0
    warnings = [ln for ln in capsys.readouterr().err.splitlines() if "warning" in ln]
    assert len(warnings) == 3
    assert "--photons ignored: the scene has no mirror or glass" in warnings[0]
    assert "--filter-width ignored without --filter" in warnings[1]
    assert "--min-spp ignored without --adaptive" in warnings[2]


# --- metadata -------------------------------------------------------------------------------------


def test_metadata_is_honest(tmp_path, capsys, device_spec):
    dev = ["--device", device_spec] if device_spec else []
    exr = tmp_path / "a.exr"
    assert main(["render", "cornell_box", "--spp", "8", "--width", "8", "--height", "8", "--adaptive", "error",
                 "--min-spp", "2", "--seed", "2147483648", "--time-limit", "60", "--exposure", "1.5",
                 "-o", str(exr), *dev]) == 0
    m = read_metadata(exr)
    assert m["clpt:spp"] == pytest.approx(8.0, abs=0.01)  # the average, not the busiest pixel
    assert m["clpt:spp_min"] <= 8 <= m["clpt:spp_max"]
    assert m["clpt:interrupted"] == 0 and m["clpt:time_limited"] == 0
    assert m["clpt:seed"] == "2147483648"  # beyond int32: text
    assert m["clpt:version"] == clpt.__version__ and m["clpt:exposure"] == 1.5
    assert m["clpt:scene"] == "cornell_box" and len(m["clpt:scene_sha256"]) == 64
    assert m["clpt:adaptive"].startswith("error, min spp 2")
    png = tmp_path / "a.png"
    assert main(["render", "cornell_box_caustics", "--spp", "1", "--width", "8", "--height", "8", "--photons",
                 "1000", "--no-photon-pilot", "-o", str(png), *dev]) == 0
    m = read_metadata(png)
    assert m["clpt:spp"] == "1.0" and "1000 photons" in m["clpt:photons"] and "spp_max=1" in m["ImageDescription"]


@pytest.mark.parametrize("limit", [float("nan"), 0.0, -1.0, float("inf"), "1"])
def test_api_time_limit_is_checked(cbox_scene, device_spec, limit):
    r = clpt.Renderer(cbox_scene, device=device_spec)
    with pytest.raises(clpt.SceneError, match="time_limit must be a finite number of seconds"):
        r.render(1, width=4, height=4, time_limit=limit)


def test_time_limit_reached_is_not_an_interruption(cbox_scene, device_spec):
    r = clpt.Renderer(cbox_scene, device=device_spec)
    res = r.render(1 << 20, width=8, height=8, seed=1, time_limit=0.5)
    assert res.time_limited and not res.interrupted
    meta = res.metadata()
    assert meta["clpt:time_limited"] == 1 and meta["clpt:interrupted"] == 0
