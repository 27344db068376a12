"""Ray queries (kernels/scene.h) against a float64 numpy reference, and light
sampling (kernels/lights.h) against analytic irradiance."""

import math

import numpy as np
import pytest

import clpt
from clpt.pack import pack_scene

CAM = clpt.Camera(origin=(0, 0, 10), target=(0, 0, 0))


def scene_of(*shapes):
    return clpt.Scene(camera=CAM, shapes=list(shapes))


def np_planar(o, d, c, u, v, tri):
    n = np.cross(u, v)
    den = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((c - o) @ n) / den
        q = o + t[:, None] * d - c
        nn = n @ n
        a = (q @ np.cross(v, n)) / nn
        b = (q @ np.cross(n, u)) / nn
    inside = (a >= 0) & (b >= 0) & ((a + b <= 1) if tri else ((a <= 1) & (b <= 1)))
    margin = np.minimum.reduce([a, b, 1 - a - b if tri else np.minimum(1 - a, 1 - b)])
    return np.where(inside & (t > 0), t, np.inf), np.abs(margin), n / np.sqrt(nn)


def np_sphere(o, d, c, r):
    oc = o - c
    b = (oc * d).sum(1)
    disc = b * b - ((oc * oc).sum(1) - r * r)
    s = np.sqrt(np.maximum(disc, 0))
    t0, t1 = -b - s, -b + s
    t = np.where(t0 > 0, t0, t1)
    return np.where((disc >= 0) & (t > 0), t, np.inf), np.abs(disc) / r ** 2


def rays(seed, n, target_scale=1.5):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-3, 3, (n, 3))
    d = rng.uniform(-target_scale, target_scale, (n, 3)) - o
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def run_intersect(probe, scene, o, d):
    # Arbitrary segments, which may cross walls that no path's shadow ray can: nothing skipped.
    args = probe.scene_args(pack_scene(scene, shadowless=False))
    return probe.run("probe_intersect", [o[:, 0], o[:, 1], o[:, 2], d[:, 0], d[:, 1], d[:, 2]], 6, prefix=args)


@pytest.mark.parametrize("lanes", [1, 8])
@pytest.mark.parametrize("kind", ["quad", "triangle", "sphere"])
def test_intersection_matches_reference(probes, lanes, kind):
    c, u, v = np.array([-1.0, -0.5, 0.2]), np.array([2.0, 0.3, 0.1]), np.array([0.2, 1.5, -0.4])
    light = dict(emission=(1, 1, 1), material="white")
    if kind == "quad":
        shape = clpt.Quad(corner=tuple(c), edge_u=tuple(u), edge_v=tuple(v), **light)
    elif kind == "triangle":
        shape = clpt.Triangle(vertices=(tuple(c), tuple(c + u), tuple(c + v)), **light)
    else:
        shape = clpt.Sphere(center=(0.3, -0.2, 0.1), radius=1.2, **light)
    o, d = rays(11, 20000)
    t, nx, ny, nz, mat, occ = run_intersect(probes(lanes), scene_of(shape), o, d)
    if kind == "sphere":
        t_ref, margin = np_sphere(o, d, np.array(shape.center), shape.radius)
        n_ref = (o + np.where(np.isinf(t_ref), 0, t_ref)[:, None] * d - np.array(shape.center)) / shape.radius
    else:
        t_ref, margin, n1 = np_planar(o, d, c, u if kind == "quad" else u, v, kind == "triangle")
        n_ref = np.tile(n1, (len(o), 1))
    clear = margin > 1e-4  # leave out rays within rounding of an edge or a tangent
    hit = np.isfinite(t_ref)
    assert np.isfinite(t[~hit & clear]).sum() == 0 and np.isinf(t[hit & clear]).sum() == 0
    both = hit & np.isfinite(t)
    assert both.sum() > 2000
    assert np.allclose(t[both], t_ref[both], rtol=1e-4, atol=1e-5)
    n = np.stack([nx, ny, nz], 1)
    assert np.allclose(n[both], n_ref[both], atol=1e-4)
    assert (occ == np.isfinite(t)).all()


def test_rays_in_the_plane_and_grazing(probes):
    """Rays along a quad's plane never hit it and produce no NaN; rays grazing
    a sphere's silhouette hit or miss, finitely."""
    quad = clpt.Quad(corner=(-1, 0, -1), edge_u=(2, 0, 0), edge_v=(0, 0, 2), material="white", emission=(1, 1, 1))
    o = np.array([[-3.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-3.0, 0.0, 0.5], [0.5, 1e-30, 0.5]])
    d = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    t, *_, occ = run_intersect(probes(1), scene_of(quad), o, d)
    assert np.isinf(t).all() and (occ == 0).all()
    sph = clpt.Sphere(center=(0, 0, 0), radius=1.0, material="white", emission=(1, 1, 1))
    y = np.array([1.0 - 1e-7, 1.0, 1.0 + 1e-7, 0.0])
    o = np.stack([np.full(4, -5.0), y, np.zeros(4)], 1)
    d = np.tile([1.0, 0.0, 0.0], (4, 1))
    t, nx, ny, nz, mat, occ = run_intersect(probes(8), scene_of(sph), o, d)
    assert not np.isnan(t).any() and np.isfinite(t[3]) and t[3] == pytest.approx(4.0)
    assert np.isfinite(np.stack([nx, ny, nz])[:, np.isfinite(t)]).all()


def test_inside_sphere_hits_far_side(probes):
    sph = clpt.Sphere(center=(1, 2, 3), radius=2.0, material="white", emission=(1, 1, 1), two_sided=True)
    rng = np.random.default_rng(3)
    o = np.array([1, 2, 3]) + rng.uniform(-1, 1, (1000, 3))
    d = rng.normal(size=(1000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, nx, ny, nz, _, _ = run_intersect(probes(8), scene_of(sph), o, d)
    t_ref, _ = np_sphere(o, d, np.array([1, 2, 3]), 2.0)
    assert np.allclose(t, t_ref, rtol=1e-5)
    p = o + t[:, None] * d
    n = np.stack([nx, ny, nz], 1)
    assert np.allclose(n, (p - [1, 2, 3]) / 2.0, atol=1e-4)  # outward, even seen from inside


def test_closest_of_several_and_material_ids(probes):
    floor = clpt.Plane(point=(0, -1, 0), normal=(0, 1, 0), material="red")
    ball = clpt.Sphere(center=(0, 0, 0), radius=0.5, material="green")
    lamp = clpt.Quad(corner=(-0.5, 2, -0.5), edge_u=(0, 0, 1), edge_v=(1, 0, 0), material="white",
                     emission=(5, 5, 5))
    sc = scene_of(floor, ball, lamp)
    packed = pack_scene(sc)
    o = np.array([[0.0, 5.0, 0.0], [2.0, 5.0, 0.0], [0.0, 1.0, 0.0], [0.0, 3.0, 0.0]])
    d = np.array([[0.0, -1.0, 0.0]] * 3 + [[0.0, 1.0, 0.0]])
    t, nx, ny, nz, mat, occ = run_intersect(probes(8), sc, o, d)
    ids = {m: i for i, m in enumerate(packed.materials)}
    red, green, lamp_m = (ids[sc.surface(s)] for s in (floor, ball, lamp))
    assert t[:3] == pytest.approx([3.0, 6.0, 0.5], rel=1e-6)  # lamp is one-sided for light, not for hits
    assert np.isinf(t[3])
    assert list(mat[:3]) == [lamp_m, red, green]
    assert ny[:3] == pytest.approx([1.0, 1.0, 1.0])  # edge_u x edge_v = +y for the lamp


def lambert_irradiance(x, n, verts):
    """Irradiance at x (normal n) from a uniform emitter of radiance 1 spanning
    the polygon verts (Lambert's formula)."""
    r = [np.asarray(v, float) - x for v in verts]
    total = 0.0
    for i in range(len(r)):
        a, b = r[i], r[(i + 1) % len(r)]
        g = math.acos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))
        c = np.cross(a, b)
        total += g * (c / np.linalg.norm(c)) @ n
    return abs(total) / 2


def estimate_irradiance(probe, scene, x, n, count=200_000, seed=5, surface=None):
    """Mean and standard error of Le cos / pdf over light samples at x; if
    surface(points) is given, the sampled light points must lie on it."""
    rng = np.random.default_rng(seed)
    u = rng.random((3, count), dtype=np.float32)
    px, py, pz = (np.full(count, c) for c in x)
    wx, wy, wz, dist, le, pdf, valid = probe.run("probe_light_sample", [px, py, pz, u[0], u[1], u[2]], 7,
                                                 prefix=probe.scene_args(pack_scene(scene)))
    w = np.stack([wx, wy, wz], 1).astype(np.float64)
    if surface is not None:
        y = np.asarray(x) + w * dist[:, None]
        off = np.abs(surface(y[valid > 0])) / dist[valid > 0]
        assert off.max() < 1e-5, f"light sample points are off the light by {off.max():.3g} of the distance"
    cos = np.maximum(w @ n, 0)
    f = np.where(valid > 0, le * cos / np.where(valid > 0, pdf, 1), 0.0)
    return f.mean(), f.std() / math.sqrt(count), le, valid


@pytest.mark.parametrize("x", [(0.0, 0.0, 0.0), (0.7, 0.0, -0.3), (2.0, -0.5, 1.0)])
@pytest.mark.parametrize("kind", ["quad", "triangle"])
def test_planar_light_irradiance(probes, kind, x):
    verts = [(-0.5, 1.0, -0.4), (0.5, 1.0, -0.4), (0.5, 1.0, 0.6), (-0.5, 1.0, 0.6)]
    if kind == "quad":
        light = clpt.Quad.from_vertices(verts, material="black", emission=(1, 1, 1))
    else:
        verts = verts[:3]
        light = clpt.Triangle(vertices=tuple(verts), material="black", emission=(1, 1, 1))
    # Winding makes the light face down (-y), towards the points below it.
    n = np.array([0.0, 1.0, 0.0])
    e, sigma, _, _ = estimate_irradiance(probes(8), scene_of(light), np.array(x), n,
                                         surface=lambda y: y[:, 1] - 1.0)
    ref = lambert_irradiance(np.array(x), n, verts)
    assert abs(e - ref) < 5 * sigma + 1e-6, f"E = {e:.5f} +- {sigma:.5f}, analytic {ref:.5f}"


def test_one_sided_light_is_dark_behind(probes):
    light = clpt.Quad.from_vertices([(-0.5, 1, -0.5), (-0.5, 1, 0.5), (0.5, 1, 0.5), (0.5, 1, -0.5)],
                                    material="black", emission=(1, 1, 1))  # faces +y, away from x
    e, _, _, valid = estimate_irradiance(probes(8), scene_of(light), np.zeros(3), np.array([0, 1.0, 0]), 10000)
    assert e == 0 and valid.sum() == 0


@pytest.mark.parametrize("radius", [0.5, 1e-4])
def test_sphere_light_irradiance(probes, radius):
    light = clpt.Sphere(center=(0, 2.0, 0), radius=radius, material="black", emission=(1, 1, 1))
    n = np.array([0.0, 1.0, 0.0])
    on_sphere = lambda y: np.linalg.norm(y - [0, 2.0, 0], axis=1) - radius
    e, sigma, _, _ = estimate_irradiance(probes(8), scene_of(light), np.zeros(3), n, surface=on_sphere)
    ref = math.pi * (radius / 2.0) ** 2  # a sphere seen fully above the horizon
    assert abs(e - ref) < 5 * sigma + 1e-7 * ref, f"E = {e:.6g} +- {sigma:.3g}, analytic {ref:.6g}"


def test_inside_two_sided_sphere_light(probes):
    light = clpt.Sphere(center=(0, 0, 0), radius=3.0, material="black", emission=(1, 1, 1), two_sided=True)
    e, sigma, _, _ = estimate_irradiance(probes(8), scene_of(light), np.array([0.5, -1.0, 0.2]),
                                         np.array([0.0, 0.6, 0.8]),
                                         surface=lambda y: np.linalg.norm(y, axis=1) - 3.0)
    assert abs(e - math.pi) < 5 * sigma


def test_lights_picked_by_power(probes):
    a = clpt.Quad.from_vertices([(-3, 1, -0.5), (-2, 1, -0.5), (-2, 1, 0.5), (-3, 1, 0.5)], material="black",
                                emission=(1, 1, 1))
    b = clpt.Quad.from_vertices([(2, 1, -1), (4, 1, -1), (4, 1, 1), (2, 1, 1)], material="black",
                                emission=(3, 3, 3))  # 4x the area, 3x the radiance
    *_, le, _ = estimate_irradiance(probes(8), scene_of(a, b), np.zeros(3), np.array([0, 1.0, 0]), 100_000)
    frac = (le == 3).mean()
    p = 12 / 13
    assert abs(frac - p) < 5 * math.sqrt(p * (1 - p) / len(le))
