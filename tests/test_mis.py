"""Multiple importance sampling: light sampling against BSDF sampling, and
photon merging against path tracing.

Each technique's weight must be computed from the same pdfs on both sides of
the pair, or the weights of a path do not sum to one and the image is biased:
the light pdf of a BSDF-sampled hit is checked against the pdf the light
sampler used for the same point, the weights against their sum, and whole
renders against the path tracer without merging."""

import math

import numpy as np
import pytest

import clpt
from clpt.constants import LUMA
from clpt.pack import pack_scene
from clpt.photons import PhotonSettings


def _lights_scene():
    return clpt.Scene(shapes=[
        clpt.Quad.from_vertices([(-0.5, 1, -0.5), (0.5, 1, -0.5), (0.5, 1, 0.5), (-0.5, 1, 0.5)],
                                material="black", emission=(2, 2, 2), two_sided=True),
        clpt.Triangle(vertices=((1.5, -1, 0), (1.5, 0, 0), (1.5, -1, 1)), material="black", emission=(3, 1, 1),
                      two_sided=True),
        clpt.Sphere(center=(-1.2, 0.3, 0.2), radius=0.25, material="black", emission=(1, 4, 1)),
    ])


@pytest.mark.parametrize("lanes", [1, 8])
def test_light_pdf_of_a_hit_equals_the_samplers(probes, lanes):
    """For light samples from random points (some inside the sphere light),
    the pdf of the hit point as a BSDF-sampled ray sees it is the sampler's."""
    probe = probes(lanes)
    rng = np.random.default_rng(7)
    n = 4096
    x = rng.uniform(-1.0, 1.0, (n, 3)) * [1.0, 0.9, 1.0]
    x[:256] = [-1.2, 0.3, 0.2] + rng.uniform(-0.1, 0.1, (256, 3))  # inside the sphere light
    u = rng.random((3, n))
    ps, ph = probe.run("probe_light_pdf", [x[:, 0], x[:, 1], x[:, 2], u[0], u[1], u[2]], 2,
                       prefix=probe.scene_args(pack_scene(_lights_scene())))
    ok = (ps > 0) & (ph > 0)
    assert ok.sum() > 0.5 * n
    rel = np.abs(ph[ok] / ps[ok] - 1)
    # Grazing directions lose a little to the hit point's rounding; nearly all agree to float precision.
    assert np.quantile(rel, 0.99) < 1e-3 and np.median(rel) < 1e-5, (np.quantile(rel, 0.99), rel.max())


def test_power_heuristic_weights_sum_to_one():
    """The kernels' weights (bsdf.h mis_power, photon_grid.h merge weight)
    as numpy twins: for any pair of pdfs of one path they sum to 1."""
    rng = np.random.default_rng(3)
    a = 10.0 ** rng.uniform(-20, 20, 10000)
    b = 10.0 ** rng.uniform(-20, 20, 10000)

    def mis_power(p, q):  # weight of the technique with pdf p against one with pdf q
        r = q / p
        return 1.0 / (1.0 + r * r)
    s = mis_power(a, b) + mis_power(b, a)
    assert np.allclose(s, 1.0, rtol=1e-12)


def _caustic_scene(size=24):
    s = clpt.load_scene("cornell_box_small_bulb")
    return clpt.Scene(camera=clpt.Camera(**{**s.camera.__dict__, "width": size, "height": size}),
                      shapes=s.shapes, materials=s.materials, render=s.render)


def test_zero_photons_gives_the_path_tracers_image_exactly(device_spec):
    scene = _caustic_scene(16)
    pt = clpt.Renderer(scene, device=device_spec, photons=False).render(16, seed=4, max_depth=6)
    off = clpt.Renderer(scene, device=device_spec).render(16, seed=4, max_depth=6,
                                                          photons=PhotonSettings(count=0))
    assert np.array_equal(pt.image, off.image)
    assert np.array_equal(pt.lum_var, off.lum_var)


def test_merging_with_mis_converges_to_the_path_tracer(device_spec):
    """Merging at every vertex, weighted against path tracing, adds up to the
    unbiased image: block means agree with plain path tracing within noise
    once the radius is small (the merge's blur is the only bias)."""
    scene = _caustic_scene(24)
    pt = clpt.Renderer(scene, device=device_spec, photons=False).render(4096, seed=1, max_depth=8)
    pm = clpt.Renderer(scene, device=device_spec).render(
        1024, seed=2, max_depth=8, photons=PhotonSettings(radius=0.002, count=20000, spp_per_map=4, pilot=False))
    assert pm.stats.nonfinite == 0 and len(pm.stats.photon_maps) == 1024 // 4
    for img in (pt, pm):
        assert np.isfinite(img.image).all()
    # 4 x 4 blocks of 6 x 6 pixels: the difference of block means against their noise.
    def blocks(a):
        return a.reshape(4, 6, 4, 6, *a.shape[2:]).mean(axis=(1, 3))
    lum = LUMA
    d = blocks(pm.image @ lum) - blocks(pt.image @ lum)
    var = blocks(pm.lum_var / pm.sample_count) / 36 + blocks(pt.lum_var / pt.sample_count) / 36
    z = d / np.sqrt(var)
    # The merge's per-pixel variance misses its photon noise shared within an
    # iteration; a 6-sigma bound over 16 blocks still catches a weight error
    # (a missing or doubled caustic is tens of sigma).
    assert np.abs(z).max() < 6, z.round(1)


@pytest.mark.parametrize("mode", ["merge", "online", "offline"])
def test_rough_vertices_are_left_to_path_tracing(device_spec, mode):
    """Every diffuse wall of the small-bulb box made a rough conductor, the
    balls' glass and mirror kept (kernels/scene.h material_mergeable: a
    vertex with a microfacet lobe neither merges nor gathers, photons end
    there unstored, and a path whose first non-delta vertex is one is path
    tracing's alone): no photon is stored, and each photon mode renders the
    path tracer's image exactly. Merging at those vertices (the gathers know
    no microfacet lobe) would change it."""
    import dataclasses
    s = _caustic_scene(16)
    rough = {name: clpt.Material.rough_conductor("Cu", alpha=0.1 * (i + 1), distribution=("ggx", "beckmann")[i % 2])
             for i, name in enumerate(("white", "red", "green"))}
    shapes = [dataclasses.replace(x, material=rough[x.material]) if x.material in rough else x for x in s.shapes]
    assert sum(isinstance(x.material, clpt.Material) for x in shapes) >= 5
    scene = clpt.Scene(camera=s.camera, shapes=shapes, materials=s.materials, render=s.render)
    pt = clpt.Renderer(scene, device=device_spec, photons=False).render(32, seed=1, max_depth=8)
    pm = clpt.Renderer(scene, device=device_spec).render(
        32, seed=1, max_depth=8, photons=PhotonSettings(mode=mode, count=20000, spp_per_map=8, offline_spp=8,
                                                        progressive=mode != "offline", pilot=False))
    assert pm.stats.photon_maps and all(m["stored"] == 0 for m in pm.stats.photon_maps)
    assert pm.stats.nonfinite == 0 and (pt.image > 0).mean() > 0.9
    # The same paths and numbers; the photon build's float contractions may differ (Intel's compiler).
    rel = np.abs(pm.image.astype(np.float64) - pt.image) / np.maximum(pt.image, 1e-3)
    assert rel.max() < 1e-4, f"differs by {rel.max():.2g} (relative) at pixel {np.unravel_index(rel.argmax(), rel.shape)}"


def _photon_modes_render_the_path_tracer(device_spec, scene, mode):
    """No photon is stored, and photon mode `mode` renders the path tracer's image exactly."""
    pt = clpt.Renderer(scene, device=device_spec, photons=False).render(32, seed=1, max_depth=8)
    pm = clpt.Renderer(scene, device=device_spec).render(
        32, seed=1, max_depth=8, photons=PhotonSettings(mode=mode, count=20000, spp_per_map=8,
                                                        progressive=True, pilot=False))
    assert pm.stats.photon_maps and all(m["stored"] == 0 for m in pm.stats.photon_maps)
    assert pm.stats.nonfinite == 0 and (pt.image > 0).mean() > 0.9
    rel = np.abs(pm.image.astype(np.float64) - pt.image) / np.maximum(pt.image, 1e-3)
    assert rel.max() < 1e-4, f"differs by {rel.max():.2g} (relative) at pixel {np.unravel_index(rel.argmax(), rel.shape)}"


def _mis_matches_bsdf_sampling(device_spec, shapes, max_depth):
    """Light and BSDF sampling by MIS against BSDF sampling alone (nee=False),
    32x32 from inside a grey box lit by a square lamp and the given shapes,
    within their noise in 8x8-pixel blocks."""
    room = clpt.Box(center=(0, 0, 0), size=(2, 2, 2), inward=True, material=clpt.Material(kd=(0.5, 0.5, 0.5)))
    lamp = clpt.Quad(corner=(-0.3, 0.99, -0.3), edge_u=(0.6, 0, 0), edge_v=(0, 0, 0.6), material=clpt.Material(),
                     emission=(8, 8, 8))
    cam = clpt.Camera(origin=(0, -0.1, 0.95), target=(0, -0.5, 0), fov=70, width=32, height=32)
    scene = clpt.Scene(camera=cam, shapes=[room, lamp, *shapes])
    mis = clpt.Renderer(scene, device=device_spec, photons=False).render(512, seed=3, max_depth=max_depth)
    bs = clpt.Renderer(scene, device=device_spec, photons=False, nee=False).render(2048, seed=4, max_depth=max_depth)
    assert mis.stats.nonfinite == 0 and bs.stats.nonfinite == 0

    def blocks(r):
        lum = r.image @ np.array([0.2126, 0.7152, 0.0722])
        var = r.lum_var / r.sample_count
        return lum.reshape(4, 8, 4, 8).mean(axis=(1, 3)), var.reshape(4, 8, 4, 8).sum(axis=(1, 3)) / 64 ** 2

    (m1, v1), (m2, v2) = blocks(mis), blocks(bs)
    z = (m1 - m2) / np.sqrt(v1 + v2)
    assert np.abs(z).max() < 4.5, z.round(1)


@pytest.mark.parametrize("mode", ["merge", "online"])
def test_plastic_vertices_are_left_to_path_tracing(device_spec, mode):
    """The small-bulb box's diffuse walls made Mitsuba plastics (smooth and
    rough), the balls' glass and mirror kept: a plastic vertex neither
    merges nor gathers and photons end there unstored (kernels/scene.h
    material_mergeable), so each photon mode renders the path tracer's
    image exactly; the lights are still found by both techniques at those
    vertices, by MIS weights that sum to one (the image matches)."""
    import dataclasses
    s = _caustic_scene(16)
    plastic = {"white": clpt.Material.smooth_plastic((0.7, 0.7, 0.7)),
               "red": clpt.Material.rough_plastic((0.7, 0.1, 0.1), alpha=0.2, distribution="ggx"),
               "green": clpt.Material.rough_plastic((0.1, 0.7, 0.1), alpha=0.05, nonlinear=True)}
    shapes = [dataclasses.replace(x, material=plastic[x.material]) if x.material in plastic else x for x in s.shapes]
    assert sum(isinstance(x.material, clpt.Material) and x.material.plastic for x in shapes) >= 5
    _photon_modes_render_the_path_tracer(device_spec, clpt.Scene(camera=s.camera, shapes=shapes,
                                                                 materials=s.materials, render=s.render), mode)


def test_plastic_mis_is_unbiased(device_spec):
    """A rough and a smooth plastic under a small and a large light: light
    sampling and BSDF sampling combined by MIS (the plastic's bsdf_pdf in
    both weights) agree with BSDF sampling alone (nee=False) within their
    noise, block by block: the weights sum to one at plastic vertices."""
    bulb = clpt.Sphere(center=(0.6, 0.6, 0.3), radius=0.08, material=clpt.Material(), emission=(60, 60, 60))
    a = clpt.Sphere(center=(-0.45, -0.6, 0), radius=0.4,
                    material=clpt.Material.rough_plastic((0.7, 0.3, 0.1), alpha=0.1, distribution="ggx"))
    b = clpt.Sphere(center=(0.45, -0.6, 0), radius=0.4, material=clpt.Material.smooth_plastic((0.1, 0.3, 0.7)))
    _mis_matches_bsdf_sampling(device_spec, [bulb, a, b], max_depth=5)


@pytest.mark.parametrize("mode", ["merge", "online"])
def test_rough_dielectric_vertices_are_left_to_path_tracing(device_spec, mode):
    """The small-bulb box's diffuse walls and its glass ball made rough
    dielectrics, the mirror ball kept: a rough dielectric vertex neither
    merges nor gathers and photons end there unstored (kernels/scene.h
    material_mergeable), so each photon mode renders the path tracer's
    image exactly."""
    import dataclasses
    s = _caustic_scene(16)
    rough = {"white": clpt.Material.rough_dielectric(alpha=0.2, distribution="ggx"),
             "red": clpt.Material.rough_dielectric(alpha=0.05, specular_transmittance=(0.8, 0.2, 0.2)),
             "green": clpt.Material.rough_dielectric(alpha=0.5, int_ior=1.0, ext_ior=1.33)}
    shapes = [dataclasses.replace(x, material=rough[x.material]) if x.material in rough else x for x in s.shapes]
    shapes = [dataclasses.replace(x, material=clpt.Material.rough_dielectric(alpha=0.1))
              if isinstance(x, clpt.Sphere) and x.material == "glass" else x for x in shapes]
    assert sum(isinstance(x.material, clpt.Material) and x.material.rough_dielectric_lobe for x in shapes) >= 6
    _photon_modes_render_the_path_tracer(device_spec, clpt.Scene(camera=s.camera, shapes=shapes,
                                                                 materials=s.materials, render=s.render), mode)


def test_rough_dielectric_mis_is_unbiased(device_spec):
    """Rough glass balls (GGX and Beckmann) under a small and a large light:
    light sampling (also through the glass, from inside it and from the floor
    beneath) and BSDF sampling combined by MIS agree with BSDF sampling
    alone (nee=False) within their noise, block by block: the weights sum to
    one at rough dielectric vertices, over both hemispheres."""
    bulb = clpt.Sphere(center=(0.6, 0.6, 0.3), radius=0.12, material=clpt.Material(), emission=(30, 30, 30))
    a = clpt.Sphere(center=(-0.45, -0.6, 0), radius=0.4,
                    material=clpt.Material.rough_dielectric(alpha=0.2, distribution="ggx"))
    b = clpt.Sphere(center=(0.45, -0.6, 0), radius=0.4,
                    material=clpt.Material.rough_dielectric(alpha=0.4, specular_transmittance=(0.9, 0.6, 0.3)))
    _mis_matches_bsdf_sampling(device_spec, [bulb, a, b], max_depth=6)


@pytest.mark.parametrize("name", clpt.shipped_scenes())
def test_no_nonfinite_sample_on_shipped_scenes(device_spec, name):
    scene = clpt.load_scene(name)
    res = clpt.Renderer(scene, device=device_spec).render(4, width=24, height=24, seed=9)
    assert res.stats.nonfinite == 0 and np.isfinite(res.image).all()


@pytest.mark.parametrize("lanes", [1, 8])
def test_light_pick_follows_power(probes, lanes):
    """The O(1) alias-table pick (lights.h light_pick_index) chooses each
    light with probability proportional to its power, sides x pi x area x
    mean(Le): a chi-square test of which light 200,000 samples took (each
    light has its own Le.x, which the sample returns)."""
    from stats import ALPHA, chi2_test
    shapes, power = [], []
    rng = np.random.default_rng(11)
    for k in range(13):
        size = rng.uniform(0.05, 0.6)
        le = (1.0 + k, 0.5, 0.25 * (k % 3))
        two = bool(k % 2)
        z = -1.0 + 0.15 * k
        shapes.append(clpt.Quad(corner=(-size / 2, 1.0, z), edge_u=(size, 0, 0), edge_v=(0, 0, 0.1),
                                material="black", emission=le, two_sided=two))
        power.append((2 if two else 1) * math.pi * size * 0.1 * np.mean(le))
    shapes.append(clpt.Sphere(center=(0.0, -0.5, 0.0), radius=0.2, material="black", emission=(20.0, 1, 1)))
    power.append(math.pi * 4 * math.pi * 0.2 ** 2 * np.mean((20.0, 1, 1)))
    shapes.append(clpt.Triangle(vertices=((1, 0, 0), (1, 0.5, 0), (1, 0, 0.5)), material="black",
                                emission=(30.0, 0, 0)))
    power.append(math.pi * 0.125 * 10.0)
    packed = pack_scene(clpt.Scene(shapes=shapes))
    n = 200_000
    x = np.zeros((n, 3))
    u = np.random.default_rng(5).random((3, n))
    probe = probes(lanes)
    out = probe.run("probe_light_sample", [x[:, 0], x[:, 1], x[:, 2], u[0], u[1], u[2]], 7,
                    prefix=probe.scene_args(packed))
    le_x = np.round(out[4]).astype(int)
    ids = [1 + k for k in range(13)] + [20, 30]
    counts = np.array([(le_x == i).sum() for i in ids])
    assert counts.sum() == n
    expected = n * np.array(power) / np.sum(power)
    p, stat, dof = chi2_test(counts, expected)
    assert p > ALPHA, (p, stat, dof, counts, expected.round())
