"""Environment lights (Mitsuba's envmap and constant) and directional lights.

- Analytic: a diffuse plane under a constant environment (kd L: it sees only
  sky), convex spheres of albedo a inside one (a L; a = 1: invisible), a
  directional light over a plane (kd / pi E cos).
- Sampling: chi-square of the envmap's directions (light_sample on the
  device, through the tables the renders use) against its cells'
  probabilities, on a map with a bright sun; the pdf it reports is the one
  the escape event (env_emission) gives the same direction, so the light
  sample's and the BSDF sample's MIS weights of a path sum to one; the
  escape pdf integrates to one over the sphere.
- MIS: a glossy sphere under a sharp map renders the same with MIS and with
  BSDF sampling alone.
- Loader: parameters, errors, Mitsuba's orientation (one bright pixel lights
  the side Mitsuba's formula says), to_world.
- Photons from a directional light: zero photons give the path tracer's
  image exactly; the caustic under a glass ball carries what a far point
  light's (another emission path through the kernels) carries; a glass ball
  under an environment alone gets photons from it (tests/test_env_photons.py).
- tests/data/env_spheres.xml against a stored Mitsuba 3 reference.
"""

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import clpt
from clpt.pack import alias_rows, env_cell_weights, pack_scene
from clpt.photons import PhotonSettings
from clpt.scene import DirectionalLight, EnvironmentLight, Material, PointLight, Quad, SceneError, Sphere

from stats import ALPHA, assert_matches_reference, chi2_test
from test_lights import _check_against, _floor_points, _plane_scene, _z_bound

sys.path.insert(0, str(Path(__file__).resolve().parent))
from envmaps import sun_map  # noqa: E402

DATA = Path(__file__).resolve().parent / "data"
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


# --- analytic -----------------------------------------------------------------------------------

def test_plane_under_a_constant_environment_is_kd_L(device_spec):
    """The plane sees only sky: irradiance pi L, radiance kd L, every pixel
    within noise (next event estimation and BSDF hits of the sky, weighted)."""
    size, kd, L = 16, 0.5, np.array([1.5, 1.0, 0.5])
    scene = _plane_scene(EnvironmentLight(radiance=tuple(L)), size, kd)
    res = clpt.Renderer(scene, device=device_spec, photons=False).render(spp=64, seed=3, max_depth=1)
    assert res.stats.nonfinite == 0
    _check_against(res, np.full((size, size, 1), kd), L, "constant environment")


@pytest.mark.parametrize("albedo", [0.5, 0.9, 1.0])
def test_furnace_sphere_in_a_constant_environment(device_spec, albedo):
    """A diffuse sphere of albedo a in a constant environment L: a convex
    surface sees only the environment, so every sphere pixel is a L (a = 1:
    the sphere vanishes) and the sky L exactly; with and without light
    sampling, deep paths and Russian roulette."""
    L = np.array([0.8, 1.0, 1.2])
    cam = clpt.Camera(origin=(0, 0, 3), target=(0, 0, 0), fov=30, width=16, height=16)
    scene = clpt.Scene(camera=cam, shapes=[Sphere(center=(0, 0, 0), radius=0.7, material=Material(kd=(albedo,) * 3)),
                                           EnvironmentLight(radiance=tuple(L))])
    for nee in (True, False):
        res = clpt.Renderer(scene, device=device_spec, photons=False, nee=nee).render(spp=128, seed=5, max_depth=16)
        img = res.image
        inner, sky = _sphere_pixels(cam, 0.7, 16, margin=0.08)
        assert sky.sum() > 16 and np.allclose(img[sky], L, rtol=1e-6)
        z = ((img @ LUMINANCE)[inner] - albedo * L @ LUMINANCE) / np.sqrt(
            np.maximum(res.lum_var[inner], 1e-12) / res.sample_count[inner])
        assert np.abs(z).max() < _z_bound(z.size), (nee, np.abs(z).max())
        assert abs(img[inner].mean(axis=0) / (albedo * L) - 1).max() < 0.01, (nee, img[inner].mean(axis=0))


def _sphere_pixels(cam, radius, size, margin):
    """Pixels wholly on a sphere at the origin, and wholly off it."""
    fr = clpt.pack.camera_frame(cam, size, size)
    ys, xs = np.mgrid[0:size, 0:size]
    inside = np.ones((size, size), dtype=bool)
    outside = np.ones((size, size), dtype=bool)
    for dx in (0, 1):
        for dy in (0, 1):
            d = fr.corner + (xs + dx)[..., None] * fr.dx + (ys + dy)[..., None] * fr.dy
            d = d / np.linalg.norm(d, axis=-1, keepdims=True)
            b = d @ fr.origin
            disc = b * b - (fr.origin @ fr.origin - radius ** 2)
            inside &= disc > margin
            outside &= disc < -margin
    return inside, outside


def test_directional_light_over_a_plane_is_E_cos(device_spec):
    """A diffuse plane under a directional light: L = kd / pi E cos, with an
    area light facing away (its shadow out of view) taking part of the pick."""
    size, kd, E = 16, 0.5, np.array([3.0, 2.0, 1.0])
    d = np.array([0.4, -0.3, -1.0])
    away = Quad(corner=(-6.5, -0.5, 3), edge_u=(1, 0, 0), edge_v=(0, 1, 0), material=Material(),
                emission=(50, 50, 50))
    scene = _plane_scene(DirectionalLight(direction=tuple(d), irradiance=tuple(E)), size, kd, extra=[away])
    res = clpt.Renderer(scene, device=device_spec, photons=False).render(spp=64, seed=3, max_depth=1)
    cos = -d[2] / np.linalg.norm(d)
    assert res.stats.nonfinite == 0
    _check_against(res, np.full((size, size, 1), kd / math.pi * cos), E, "directional light")


# --- sampling and MIS -----------------------------------------------------------------------------

ROT = ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0))  # a quarter turn about y


def _env_scene(img, to_world=ROT, scale=1.0):
    return clpt.Scene(shapes=[Sphere(center=(0, 0, 0), radius=0.01, material=Material(kd=(0.5,) * 3)),
                              EnvironmentLight(image=img, scale=scale, to_world=to_world)])


def _cells_of(w_world, img, to_world=ROT):
    """Sampling cell (x + W y) of world directions, in Mitsuba's (u, v) of the map."""
    h, wd = img.shape[:2]
    loc = w_world @ np.asarray(to_world)  # the inverse of a rotation: its transpose
    u = np.arctan2(loc[:, 0], -loc[:, 2]) / (2 * np.pi) - 0.5 / wd
    u -= np.floor(u)
    v = np.arccos(np.clip(loc[:, 1], -1, 1)) / np.pi
    gx = np.minimum((u * wd).astype(int), wd - 1)
    gy = np.minimum((v * (h - 1)).astype(int), h - 2)
    return gx + wd * gy, loc


@pytest.mark.parametrize("lanes", [1, 8])
def test_envmap_sampling_chi2_and_pdf(probes, lanes):
    """Directions from light_sample (an envmap with a sun, turned by
    to_world) fall in the map's sampling cells as the cells' weights say
    (chi-square), the pdf reported is the cell's probability over its solid
    angle per unit of (u, v), 1 / (2 pi^2 sin theta), and the escape event
    reports the same pdf and radiance for the same direction."""
    img = sun_map()
    h, w = img.shape[:2]
    packed = pack_scene(_env_scene(img))
    n = 200_000
    u = np.random.default_rng(11).random((3, n))
    x = np.zeros((n, 3))
    probe = probes(lanes)
    args = probe.scene_args(packed)
    wx, wy, wz, dist, le, pdf, valid = probe.run("probe_light_sample", [x[:, 0], x[:, 1], x[:, 2], u[0], u[1], u[2]],
                                                 7, prefix=args)
    assert valid.all()
    wv = np.stack([wx, wy, wz], axis=1).astype(np.float64)
    cells, loc = _cells_of(wv, img)
    weights = env_cell_weights(img).reshape(-1)
    prob = weights / weights.sum()
    counts = np.bincount(cells, minlength=prob.size)
    p, stat, dof = chi2_test(counts, n * prob)
    assert p > ALPHA, (p, stat, dof)
    # The pdf: cell probability * W (H - 1) / (2 pi^2 sin theta).
    sin_t = np.sqrt(np.maximum(loc[:, 0] ** 2 + loc[:, 2] ** 2, 1e-14))
    want = prob[cells] * w * (h - 1) / (2 * np.pi ** 2 * sin_t)
    interior = sin_t > 0.05
    assert np.allclose(pdf[interior], want[interior], rtol=2e-3)
    # The escape event's radiance and pdf for the same directions.
    # (A direction within float rounding of a cell's edge may land in the
    # neighbouring cell: a few in 10^4, where the pdf steps; beside the sun
    # the radiance changes by 400 a texel, so float's rounding of the
    # direction shows in it.)
    r, g, b, pe = probe.run("probe_env_emission", [wx, wy, wz], 4, prefix=args)
    same = np.isclose(pe, pdf, rtol=2e-3)
    assert same[interior].mean() > 0.999, same[interior].mean()
    assert np.allclose(r[interior], le[interior], rtol=2e-3, atol=1e-4 * img.max())
    interior &= same
    # MIS: for each light sample, its weight and the weight a BSDF sample of
    # the same direction gets (a cosine lobe around a random normal), sum to one.
    nrm = np.random.default_rng(12).normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    pb = np.maximum((wv * nrm).sum(1), 0) / np.pi
    ok = interior & (pb > 0)
    w_light = pdf[ok] ** 2 / (pdf[ok] ** 2 + pb[ok] ** 2)
    w_bsdf = pb[ok] ** 2 / (pb[ok] ** 2 + pe[ok] ** 2)
    assert np.abs(w_light + w_bsdf - 1).max() < 5e-3


def test_alias_rows_give_the_weights():
    """Each row's alias table (pack.alias_rows, the envmap's sampling
    tables) picks slot j with probability weight j over the row's sum:
    skewed rows, rows with zeros, one positive entry, an all-zero row
    (uniform) and a row of equal weights."""
    rng = np.random.default_rng(3)
    w = rng.random((6, 53)) ** 6
    w[1, ::2] = 0
    w[2] = 0
    w[2, 17] = 4.0
    w[3] = 0
    w[4] = 1
    w[5, :50] = 1e-9
    prob, alias = alias_rows(w)
    assert prob.shape == w.shape and ((prob >= 0) & (prob <= 1)).all() and ((alias >= 0) & (alias < 53)).all()
    for r in range(len(w)):
        got = prob[r].copy()
        np.add.at(got, alias[r], 1 - prob[r])
        want = w[r] / w[r].sum() if w[r].sum() > 0 else np.full(53, 1 / 53)
        assert np.abs(got / 53 - want).max() < 1e-12, r
        assert (got[w[r] == 0] == 0).all() or w[r].sum() == 0, r  # a zero weight is never given


def test_envmap_samples_are_uniform_within_their_cells(probes):
    """The fraction of a sample within its cell (what the alias choices
    leave of u1 and u2, rescaled) is uniform: 4 x 4 sub-cells of every cell
    get a sixteenth of its probability each (chi-square), the sun's cells
    (the most sampled, their slots kept or given away) included."""
    img = sun_map()
    h, w = img.shape[:2]
    packed = pack_scene(_env_scene(img))
    n = 300_000
    u = np.random.default_rng(17).random((3, n))
    x = np.zeros((n, 3))
    probe = probes(8)
    wx, wy, wz, *_, valid = probe.run("probe_light_sample", [x[:, 0], x[:, 1], x[:, 2], u[0], u[1], u[2]], 7,
                                      prefix=probe.scene_args(packed))
    assert valid.all()
    loc = np.stack([wx, wy, wz], axis=1).astype(np.float64) @ np.asarray(ROT)
    gu = np.arctan2(loc[:, 0], -loc[:, 2]) / (2 * np.pi) - 0.5 / w
    gx = (gu - np.floor(gu)) * w
    gy = np.arccos(np.clip(loc[:, 1], -1, 1)) / np.pi * (h - 1)
    cx, cy = np.minimum(gx.astype(int), w - 1), np.minimum(gy.astype(int), h - 2)
    sx = np.minimum(((gx - cx) * 4).astype(int), 3)
    sy = np.minimum(((gy - cy) * 4).astype(int), 3)
    bins = (cx + w * cy) * 16 + sx + 4 * sy
    weights = env_cell_weights(img).reshape(-1)
    expected = np.repeat(n * weights / weights.sum() / 16, 16)
    p, stat, dof = chi2_test(np.bincount(bins, minlength=expected.size), expected)
    assert dof > 100 and p > ALPHA, (p, stat, dof)


def test_escape_pdf_integrates_to_one(probes):
    """The pdf env_emission gives directions, integrated over the sphere by
    uniform directions, is one (within 4 sigma of the estimate)."""
    img = sun_map()
    packed = pack_scene(_env_scene(img))
    n = 400_000
    d = np.random.default_rng(13).normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    probe = probes(1)
    *_, pe = probe.run("probe_env_emission", [d[:, 0], d[:, 1], d[:, 2]], 4, prefix=probe.scene_args(packed))
    est = 4 * np.pi * pe.astype(np.float64)
    assert abs(est.mean() - 1) < 4 * est.std() / math.sqrt(n), (est.mean(), est.std() / math.sqrt(n))


def test_glossy_sphere_under_a_sharp_envmap_same_with_mis_and_bsdf_sampling(device_spec):
    """A rough gold sphere over a diffuse floor under the sun map: the image
    with MIS (light and BSDF sampling) and with BSDF sampling alone agree
    block by block within both renders' noise, and in mean within 1%."""
    img = sun_map()
    cam = clpt.Camera(origin=(0, 0.6, 3), target=(0, 0.1, 0), fov=40, width=32, height=32)
    metal = Material.rough_conductor("Au", alpha=0.2)
    scene = clpt.Scene(camera=cam, shapes=[
        Sphere(center=(0, 0.1, 0), radius=0.6, material=metal),
        Quad(corner=(-3, -0.5, 3), edge_u=(6, 0, 0), edge_v=(0, 0, -6), material=Material(kd=(0.5,) * 3)),
        EnvironmentLight(image=img, scale=0.5, to_world=ROT)])
    mis = clpt.Renderer(scene, device=device_spec, photons=False).render(spp=256, seed=7, max_depth=3)
    bsdf = clpt.Renderer(scene, device=device_spec, photons=False, nee=False).render(spp=1024, seed=8, max_depth=3)
    b = 8

    def blocks(x):
        return x.reshape(32 // b, b, 32 // b, b).sum(axis=(1, 3)) / b ** 2

    var = lambda r: blocks(r.lum_var / r.sample_count) / b ** 2  # noqa: E731
    z = (blocks(mis.image @ LUMINANCE) - blocks(bsdf.image @ LUMINANCE)) / np.sqrt(var(mis) + var(bsdf))
    assert np.abs(z).max() < _z_bound(z.size), np.abs(z).max()
    assert abs(mis.image.mean() / bsdf.image.mean() - 1) < 0.01
    # MIS is the better estimator here (the sun is small): less noise per sample.
    assert (mis.lum_var.mean() < bsdf.lum_var.mean())


# --- the XML loader and the scene API ----------------------------------------------------------------

@pytest.mark.parametrize("kernel", ["specialized", "generic"])
def test_prefetching_a_large_map_leaves_the_image_unchanged(device_spec, dctx, monkeypatch, kernel):
    """A map of 2^18 texels, which CPU builds prefetch (lights.h
    env_sample_prefetch, env_eval_prefetch): the same image, bit for bit,
    with CLPT_PREFETCH=0 (no prefetch compiled in), in a specialized build
    and a generic one, and the option is in the CPU build's."""
    from clpt.program import device_options
    from envmaps import sky_map

    img = sky_map(1024, 256)
    cam = clpt.Camera(origin=(0, 0.6, 3), target=(0, 0.1, 0), fov=40, width=12, height=10)
    scene = clpt.Scene(camera=cam, shapes=[
        Sphere(center=(0, 0.1, 0), radius=0.6, material=Material.rough_conductor("Au", alpha=0.2)),
        Quad(corner=(-3, -0.5, 3), edge_u=(6, 0, 0), edge_v=(0, 0, -6), material=Material(kd=(0.5,) * 3)),
        EnvironmentLight(image=img, to_world=ROT)])
    images = []
    for flag in ("1", "0"):
        monkeypatch.setenv("CLPT_PREFETCH", flag)
        r = clpt.Renderer(scene, device=device_spec, photons=False, kernel=kernel)
        images.append(r.render(spp=8, seed=3, max_depth=4).image)
    assert np.isfinite(images[0]).all() and images[0].mean() > 0
    assert np.array_equal(images[0], images[1])
    monkeypatch.setenv("CLPT_PREFETCH", "1")
    if dctx.is_pocl or dctx.platform.lower().startswith("intel"):
        assert device_options(dctx) == ["-DCLPT_PREFETCH=1"]
    monkeypatch.setenv("CLPT_PREFETCH", "0")
    assert device_options(dctx) == []


def test_prefetch_is_built_only_for_clang_cpu_runtimes(monkeypatch):
    """CLPT_PREFETCH goes to PoCL's and Intel's CPU devices, not to Oclgrind
    (which reports every device type, CPU included, and cannot run the
    intrinsic; it gets the sampler's table for bit reversal instead) nor to
    GPUs; CLPT_PREFETCH=0 turns it off."""
    import types

    import pyopencl as cl

    from clpt.program import device_options

    def fake(platform, kind, pocl=False):
        return types.SimpleNamespace(platform=platform, is_pocl=pocl, is_cpu=bool(kind & cl.device_type.CPU),
                                     device=types.SimpleNamespace(type=kind))
    on = ["-DCLPT_PREFETCH=1"]
    monkeypatch.delenv("CLPT_PREFETCH", raising=False)
    assert device_options(fake("Portable Computing Language", cl.device_type.CPU, pocl=True)) == on
    assert device_options(fake("Intel(R) OpenCL", cl.device_type.CPU)) == on
    assert device_options(fake("Oclgrind", cl.device_type.ALL)) == ["-DCLPT_BITREVERSE_TABLE=1"]
    assert device_options(fake("Intel(R) OpenCL Graphics", cl.device_type.GPU)) == []
    assert device_options(fake("NVIDIA CUDA", cl.device_type.GPU)) == []
    assert device_options(fake("Portable Computing Language", cl.device_type.GPU, pocl=True)) == []
    monkeypatch.setenv("CLPT_PREFETCH", "0")
    assert device_options(fake("Intel(R) OpenCL", cl.device_type.CPU)) == []


def _xml(tmp_path, emitters, shapes='<shape type="rectangle"><bsdf type="diffuse"/></shape>'):
    p = tmp_path / "s.xml"
    p.write_text(f'<scene version="3.0.0">{emitters}{shapes}</scene>')
    return p


def test_loader_envmap_constant_directional_parameters(tmp_path):
    img = sun_map()
    clpt.save_image(tmp_path / "sun.exr", img)
    s = clpt.load_scene(_xml(tmp_path, '<emitter type="envmap"><string name="filename" value="sun.exr"/>'
                                       '<float name="scale" value="2.5"/><transform name="to_world">'
                                       '<rotate y="1" angle="90"/></transform></emitter>'
                                       '<emitter type="directional"><vector name="direction" x="0" y="-2" z="0"/>'
                                       '<rgb name="irradiance" value="1, 2, 3"/></emitter>'))
    env = next(x for x in s.shapes if isinstance(x, EnvironmentLight))
    assert env.scale == 2.5 and np.array_equal(env.image, img)
    assert np.allclose(env.rotation(), [[0, 0, 1], [0, 1, 0], [-1, 0, 0]], atol=1e-6)
    dl = next(x for x in s.shapes if isinstance(x, DirectionalLight))
    assert np.allclose(dl.direction, (0, -1, 0)) and dl.irradiance == (1.0, 2.0, 3.0)
    s = clpt.load_scene(_xml(tmp_path, '<emitter type="constant"><rgb name="radiance" value="0.5, 1, 2"/></emitter>'
                                       '<emitter type="directional"><transform name="to_world">'
                                       '<lookat origin="0,0,0" target="1,0,0"/></transform></emitter>'))
    env = next(x for x in s.shapes if isinstance(x, EnvironmentLight))
    assert env.image is None and env.radiance == (0.5, 1.0, 2.0)
    dl = next(x for x in s.shapes if isinstance(x, DirectionalLight))
    assert np.allclose(dl.direction, (1, 0, 0))


@pytest.mark.parametrize("emitters, message", [
    ('<emitter type="constant"/><emitter type="constant"/>', "only one environment emitter"),
    ('<emitter type="envmap"><string name="filename" value="nothere.exr"/></emitter>', "file not found"),
    ('<emitter type="envmap"><string name="filename" value="tiny.exr"/></emitter>', "at least 2x3"),
    ('<emitter type="envmap"><string name="filename" value="sun.exr"/><float name="scale" value="-1"/></emitter>',
     "scale must be > 0"),
    ('<emitter type="directional"><vector name="direction" x="0" y="0" z="0"/></emitter>', "direction is zero"),
    ('<emitter type="envmap"><string name="filename" value="sun.exr"/><transform name="to_world">'
     '<scale x="2" y="1" z="1"/></transform></emitter>', "must be a rotation"),
])
def test_loader_refuses_bad_infinite_lights_in_one_line(tmp_path, emitters, message):
    clpt.save_image(tmp_path / "sun.exr", sun_map())
    clpt.save_image(tmp_path / "tiny.exr", np.ones((2, 2, 3), dtype=np.float32))
    with pytest.raises(SceneError, match=message) as e:
        clpt.load_scene(_xml(tmp_path, emitters))
    assert "\n" not in str(e.value)


def test_scene_api_refuses_a_second_environment_and_bad_maps():
    two = clpt.Scene(shapes=[Sphere(), EnvironmentLight(), EnvironmentLight(radiance=(2, 2, 2))])
    with pytest.raises(SceneError, match="at most one environment"):
        two.check()
    with pytest.raises(SceneError, match="finite and not negative"):
        clpt.Scene(shapes=[Sphere(), EnvironmentLight(image=-np.ones((4, 8, 3)))]).check()
    with pytest.raises(SceneError, match="direction: must not be zero"):
        clpt.Scene(shapes=[Sphere(), DirectionalLight(direction=(0, 0, 0))]).check()


def test_infinite_light_kinds_compile_only_where_present():
    plain = clpt.scene_features(pack_scene(clpt.Scene(shapes=[Sphere(emission=(1, 1, 1))])))
    assert not plain.env_light and not plain.directional_lights
    assert "-DCLPT_HAS_ENV_LIGHT=0" in plain.options()
    env = clpt.scene_features(pack_scene(clpt.Scene(shapes=[Sphere(), EnvironmentLight()])))
    dl = clpt.scene_features(pack_scene(clpt.Scene(shapes=[Sphere(), DirectionalLight()])))
    assert env.env_light and not env.directional_lights and dl.directional_lights and not dl.env_light


def test_envmap_orientation_is_mitsubas(tmp_path, device_spec):
    """A map black but for one pixel, which Mitsuba's convention puts at
    +x ((x + 1/2) / W = 1/4, y / (H - 1) = 1/2): of two quads tilted up
    towards +x and -x only the first is lit; turned by to_world (a quarter
    turn about y: +x goes to -z), of two tilted towards -z and +z only the
    first."""
    img = np.zeros((5, 6, 3), dtype=np.float32)
    img[2, 1] = 100.0
    clpt.save_image(tmp_path / "dot.exr", img)

    def lit(rot, normals):
        rotate = f'<transform name="to_world"><rotate y="1" angle="{rot}"/></transform>' if rot else ""
        shapes = "".join(
            f'<shape type="rectangle"><transform name="to_world"><lookat origin="{3 * n[0]},0,{3 * n[2]}" '
            f'target="{4 * n[0]},1,{4 * n[2]}" up="0,1,0"/></transform><bsdf type="diffuse"/></shape>'
            for n in normals)
        xml = _xml(tmp_path, f'<emitter type="envmap"><string name="filename" value="dot.exr"/>{rotate}</emitter>'
                             '<sensor type="perspective"><float name="fov" value="60"/><transform name="to_world">'
                             '<lookat origin="0,10,0.01" target="0,0,0" up="0,1,0"/></transform><film type="hdrfilm">'
                             '<integer name="width" value="16"/><integer name="height" value="16"/></film></sensor>',
                   shapes)
        scene = clpt.load_scene(xml)
        res = clpt.Renderer(scene, device=device_spec, photons=False).render(spp=16, seed=1, max_depth=1)
        assert res.stats.nonfinite == 0
        return [_quad_mean(res.image, scene.camera, (3.0 * n[0], 0.0, 3.0 * n[2])) for n in normals]

    # (The pixel's bilinear spread reaches the far side's horizon faintly.)
    a = lit(0, [(1, 0, 0), (-1, 0, 0)])
    assert a[0] > 0 and a[1] < 0.01 * a[0], a
    b = lit(90, [(0, 0, -1), (0, 0, 1)])
    assert b[0] > 0 and b[1] < 0.01 * b[0], b


def _quad_mean(img, cam, center):
    """The image's mean luminance over the 3x3 pixels around a point's projection (its quad's centre)."""
    fr = clpt.pack.camera_frame(cam, img.shape[1], img.shape[0])
    m = np.stack([fr.corner, fr.dx, fr.dy], axis=1)  # d = t (corner + px dx + py dy)
    t0, a, b = np.linalg.solve(m, np.asarray(center) - fr.origin)
    px, py = int(a / t0), int(b / t0)
    assert 1 <= px < img.shape[1] - 1 and 1 <= py < img.shape[0] - 1
    return float((img[py - 1:py + 2, px - 1:px + 2] @ LUMINANCE).mean())


# --- photons from a directional light ---------------------------------------------------------------

def _glass_ball(light, size=24):
    cam = clpt.Camera(origin=(0, 3, 0.001), target=(0, 0, 0), fov=40, width=size, height=size)
    return clpt.Scene(camera=cam, shapes=[
        Quad(corner=(-1, 0, -1), edge_u=(0, 0, 2), edge_v=(2, 0, 0), material=Material(kd=(0.5,) * 3)),
        Sphere(center=(0, 0.6, 0), radius=0.3, material=Material.preset("glass")), light])


D_SUN = np.array([0.3, -1.0, 0.2]) / np.linalg.norm([0.3, -1.0, 0.2])
E_SUN = np.array([2.0, 1.5, 1.0])


def test_zero_photons_gives_the_path_tracers_image_exactly_with_a_directional_light(device_spec):
    scene = _glass_ball(DirectionalLight(direction=tuple(D_SUN), irradiance=tuple(E_SUN)), size=12)
    pt = clpt.Renderer(scene, device=device_spec, photons=False).render(spp=8, seed=4, max_depth=6)
    none = clpt.Renderer(scene, device=device_spec).render(
        spp=8, seed=4, max_depth=6, photons=PhotonSettings(count=0, pilot=False))
    assert np.array_equal(pt.image, none.image)


def test_directional_light_caustic_matches_a_far_point_lights(device_spec):
    """The caustic a glass ball casts from a directional light (photons from
    its disk, aimed at the ball's shadow disk) carries what the same caustic
    from a point light far along the direction carries (photons aimed by
    solid angle: another emission path), its intensity giving the same
    irradiance at the ball: the sum over the caustic region within 3% (the
    point light's rays diverge by 0.8% across the ball, and both are noisy)."""
    far = 40.0
    pos = np.array([0, 0.6, 0]) - D_SUN * far
    ph = PhotonSettings(count=40000, spp_per_map=8, pilot=False)
    a = clpt.Renderer(_glass_ball(DirectionalLight(direction=tuple(D_SUN), irradiance=tuple(E_SUN))),
                      device=device_spec).render(spp=64, seed=2, max_depth=6, photons=ph)
    b = clpt.Renderer(_glass_ball(PointLight(position=tuple(pos), intensity=tuple(E_SUN * far * far))),
                      device=device_spec).render(spp=64, seed=2, max_depth=6, photons=ph)
    assert a.stats.nonfinite == 0 and b.stats.nonfinite == 0
    # The caustic region: the pixels seen through the ball (the floor under it).
    region = np.zeros((24, 24), dtype=bool)
    region[8:16, 8:16] = True
    sa, sb = (a.image @ LUMINANCE)[region].sum(), (b.image @ LUMINANCE)[region].sum()
    assert sa > 0.05 * region.sum() and abs(sa / sb - 1) < 0.03, (sa, sb)


# --- against Mitsuba 3 -------------------------------------------------------------------------------

def test_env_spheres_render_as_in_mitsuba(device_spec):
    """tests/data/env_spheres.xml (a diffuse and a rough gold sphere on a
    plane under a small HDR sky with a sun, turned by to_world): the image
    mean within 0.5% of Mitsuba 3's, no 16x16 block beyond 4 sigma."""
    ref = json.loads((DATA / "env_spheres_mitsuba.json").read_text())
    scene = clpt.load_scene(DATA / "env_spheres.xml", params={"res": ref["width"]})
    res = clpt.Renderer(scene, device=device_spec, photons=False).render(spp=256, seed=1)
    assert_matches_reference(res, ref)


def test_environment_lit_glass_photons_count_in_the_pilot(device_spec):
    """An environment emits photons (tests/test_env_photons.py): the pilot's
    map of a glass ball under one alone stores photons whose power is a
    share of the environment's, and the render follows the pilot's choice."""
    scene = _glass_ball(EnvironmentLight(image=sun_map(), scale=0.5, to_world=ROT), size=12)
    default = clpt.Renderer(scene, device=device_spec).render(spp=8, seed=4, max_depth=6)
    pilot = default.stats.photon_pilot
    assert pilot is not None and 0 < pilot["caustic_share"] < 1
    assert pilot["choice"] in ("photon merging", "path tracing")
