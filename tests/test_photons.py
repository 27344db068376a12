"""Caustic photon mapping: the grid and gather against brute force, the
cone-filter normalization, edge cases of the build, the photon pass, and the
split of light paths between the photon map and the path tracer."""

import math

import numpy as np
import pyopencl as cl
import pytest

import clpt
from clpt.engine.passes import PhotonPass
from clpt.photons import PhotonSettings

from stats import assert_mean_within


@pytest.fixture(scope="module")
def pmap(probes):
    probe = probes(8)
    return probe, PhotonPass(probe.dctx, probe.program, probe.real)


def gather(probe, pm, queries, kd=(0.5, 0.5, 0.5), ks=(0, 0, 0), shininess=0.0, cone_k=1.1, max_photons=0,
           budget=0xFFFFFFFF, u=None):
    """photon_gather_one at each query (x, n, d: n x 9 array; u: the subsampling offsets)."""
    q = np.zeros((len(queries), 10))
    q[:, :9] = queries
    q[:, 9] = 0.5 if u is None else u
    q = np.ascontiguousarray(q, dtype=probe.real)
    ctx, queue = probe.dctx.context, probe.dctx.queue
    qb = cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=q)
    out = np.zeros((len(q), 3), dtype=probe.real)
    ob = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    k = cl.Kernel(probe.program, "probe_gather")
    r4 = cl.cltypes.make_float4
    k(queue, (len(q),), None, *pm.sorted, pm.bucket_start, np.uint32(pm.mask),
      np.uint32(max_photons or 0xFFFFFFFF), np.uint32(budget), probe.real(pm.radius), probe.real(pm.inv_cell),
      probe.real(cone_k), r4(*kd, 0), r4(*ks, shininess),
      qb, ob)
    cl.enqueue_copy(queue, out, ob)
    queue.finish()
    return out


def brute_force(pos, dirs, power, queries, radius, kd=0.5, cone_k=1.1):
    out = np.zeros((len(queries), 3))
    for i, q in enumerate(queries):
        x, n = q[:3], q[3:6]
        d = np.linalg.norm(pos - x, axis=1)
        ok = (d < radius) & (dirs @ n < 0)
        w = 1 - d[ok] / (cone_k * radius)
        out[i] = kd / math.pi * (w[:, None] * power[ok]).sum(0)
    return out / ((1 - 2 / (3 * cone_k)) * math.pi * radius ** 2)


def plane_queries(rng, n, lo=-1, hi=1):
    q = np.zeros((n, 9))
    q[:, 0] = rng.uniform(lo, hi, n)
    q[:, 2] = rng.uniform(lo, hi, n)
    q[:, 4] = 1.0   # normal +y
    q[:, 7] = -1.0  # looking down
    return q


@pytest.mark.parametrize("layout", ["clustered", "one_cell", "far_away", "one_photon", "empty"])
def test_gather_equals_brute_force(pmap, layout):
    probe, pm = pmap
    rng = np.random.default_rng(1)
    r = 0.05
    n = {"one_photon": 1, "empty": 0}.get(layout, 20000)
    pos = np.zeros((n, 3))
    if layout == "clustered":  # a dense caustic blob on a sparse floor
        pos[:, [0, 2]] = np.where(rng.random((n, 1)) < 0.6, rng.normal(0, 0.08, (n, 2)), rng.uniform(-1, 1, (n, 2)))
    elif layout == "one_cell":  # every photon in one cell
        pos[:, [0, 2]] = rng.uniform(0.001, 0.049, (n, 2))
    elif layout == "far_away":  # a far cluster, and some photons beyond any sane scene
        pos[:, [0, 2]] = rng.uniform(-1, 1, (n, 2))
        pos[: n // 2] += 1e4
        pos[:100] = rng.uniform(-1, 1, (100, 3)) * 3e38
    elif layout == "one_photon":
        pos[0] = (0.01, 0.0, -0.02)
    dirs = np.tile([0.0, -1.0, 0.0], (n, 1))
    dirs[::7] = [0.0, 1.0, 0.0]  # some arrive from below: they must be left out
    power = rng.uniform(0.5, 1.5, (n, 3))
    pm.load(pos, dirs, power, r)
    q = plane_queries(rng, 300, -0.2, 0.2) if layout != "far_away" else np.vstack(
        [plane_queries(rng, 150), plane_queries(rng, 150) + np.r_[1e4, 0, 1e4, np.zeros(6)]])
    got = gather(probe, pm, q)
    ref = brute_force(pos, dirs, power, q, r)
    assert np.allclose(got, ref, rtol=1e-4, atol=1e-6 * max(1.0, ref.max()))
    if layout == "clustered":
        assert (ref > 0).mean() > 0.9


def test_grid_is_sorted_with_consistent_bucket_starts(pmap):
    probe, pm = pmap
    rng = np.random.default_rng(2)
    n = 50000
    pm.load(rng.normal(0, 0.3, (n, 3)), np.tile([0, -1.0, 0], (n, 1)), np.ones((n, 3)), 0.02)
    keys = np.empty(n, np.uint32)
    cl.enqueue_copy(probe.dctx.queue, keys, pm.sorted_keys)
    starts = np.empty(pm.mask + 2, np.uint32)
    cl.enqueue_copy(probe.dctx.queue, starts, pm.bucket_start)
    probe.dctx.queue.finish()
    assert (np.diff(keys.astype(np.int64)) >= 0).all() and keys.max() <= pm.mask
    ref = np.searchsorted(keys, np.arange(pm.mask + 2), side="left")
    assert np.array_equal(starts, ref)


@pytest.mark.parametrize("cone_k", [1.0, 1.1, 2.0, 50.0])
def test_uniform_photon_field_gives_its_irradiance(pmap, cone_k):
    """Photons of total flux Phi spread uniformly over area A give irradiance
    E = Phi / A; the cone filter's normalization 1 - 2/(3k) must preserve it."""
    probe, pm = pmap
    rng = np.random.default_rng(3)
    n, side, r, kd = 400_000, 2.0, 0.04, 0.6
    pos = np.zeros((n, 3))
    pos[:, [0, 2]] = rng.uniform(-1, 1, (n, 2))
    phi = 8.0
    pm.load(pos, np.tile([0.3, -0.9, 0.1], (n, 1)), np.full((n, 3), phi / n), r)
    q = plane_queries(rng, 2000, -0.9, 0.9)
    got = gather(probe, pm, q, kd=(kd,) * 3, cone_k=cone_k)[:, 1]
    expected = kd / math.pi * phi / side ** 2
    # Each estimate sums ~ n pi r^2 / A photons: a Poisson count, weighted.
    assert_mean_within(got.mean(), expected, got.std() / math.sqrt(len(got)), 5.0, what=f"k = {cone_k}")


def test_max_photons_caps_the_gather(pmap):
    probe, pm = pmap
    n = 1000
    pos = np.zeros((n, 3))
    pos[:, 0] = np.linspace(-0.01, 0.01, n)
    pm.load(pos, np.tile([0, -1.0, 0], (n, 1)), np.ones((n, 3)), 0.05)
    q = plane_queries(np.random.default_rng(0), 1, 0, 0)
    full = gather(probe, pm, q, cone_k=1e9)[0, 0]
    capped = gather(probe, pm, q, cone_k=1e9, max_photons=10)[0, 0]
    assert capped == pytest.approx(full * 10 / n, rel=1e-5)


def test_ten_million_photons_build(pmap):
    probe, pm = pmap
    n = 10_000_000
    rng = np.random.default_rng(4)
    pos = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
    info = pm.load(pos, np.tile(np.float32([0, -1, 0]), (n, 1)), np.ones((n, 3), np.float32), 0.01)
    keys = np.empty(n, np.uint32)
    cl.enqueue_copy(probe.dctx.queue, keys, pm.sorted_keys)
    probe.dctx.queue.finish()
    assert info["stored"] == n and (np.diff(keys[:: 9973].astype(np.int64)) >= 0).all()
    pm.load(pos[:1], np.zeros((1, 3)), np.ones((1, 3)), 0.01)  # give the memory back


def test_budget_subsampling_is_unbiased(pmap):
    """Over all offsets, the subsampled gathers average to the full one exactly:
    every photon is visited for 1 offset in s and weighted by s."""
    probe, pm = pmap
    rng = np.random.default_rng(5)
    n = 20000
    pos = np.zeros((n, 3))
    pos[:, [0, 2]] = rng.normal(0, 0.03, (n, 2))
    pm.load(pos, np.tile([0, -1.0, 0], (n, 1)), rng.uniform(0.5, 1.5, (n, 3)), 0.05)
    q = plane_queries(rng, 5, -0.03, 0.03)
    full = gather(probe, pm, q)
    m = 840  # lcm(1..8): every stride up to 8 sees each of its offsets equally often
    budget = 2500  # strides up to 8 for the 20000 photons of the densest row
    u = np.tile((np.arange(m) + 0.5) / m, len(q))
    sub = gather(probe, pm, np.repeat(q, m, axis=0), budget=budget, u=u).reshape(len(q), m, 3).mean(axis=1)
    assert np.allclose(sub, full, rtol=1e-4)  # float sums of ~10^4 terms in other orders
    one = gather(probe, pm, q, budget=budget, u=0.3)
    assert not np.allclose(one, full, rtol=1e-2)  # a single gather does subsample


# --- the photon pass and the renderer ---------------------------------------------------


def caustic_scene(res=24):
    """A glass ball focusing a small light onto a floor, seen from the side."""
    floor = clpt.Quad(corner=(-2, 0, -2), edge_u=(0, 0, 4), edge_v=(4, 0, 0), material="white")
    ball = clpt.Sphere(center=(0, 0.45, 0), radius=0.3, material="glass")
    lamp = clpt.Quad(corner=(-0.15, 2.0, -0.15), edge_u=(0.3, 0, 0), edge_v=(0, 0, 0.3), material="black",
                     emission=(40, 40, 40))
    cam = clpt.Camera(origin=(0, 1.5, 2.0), target=(0, 0, 0), fov=30, width=res, height=res)
    return clpt.Scene(camera=cam, shapes=[floor, ball, lamp])


@pytest.fixture(scope="module")
def pt_reference(device_spec):
    """The caustic scene by path tracing alone, at high spp."""
    return clpt.Renderer(caustic_scene(), device=device_spec, photons=False).render(16384, seed=1)


def test_no_caustic_casters_no_photon_pass(device_spec):
    r = clpt.Renderer("cornell_box", device=device_spec)
    assert not r.features.photons and r.states[0].pmap is None
    res = r.render(2, width=8, height=8)
    assert set(res.stats.launches) == {"trace_paths"} and not res.stats.photon_maps
    off = clpt.Renderer("cornell_box_caustics", device=device_spec, photons=False)
    assert not off.features.photons and off.states[0].pmap is None
    on = clpt.Renderer("cornell_box_caustics", device=device_spec)
    res = on.render(2, width=8, height=8)
    assert on.features.photons and res.stats.launches["trace_photons"] == 1
    assert res.stats.launches["radix_scatter"] >= 2 and res.stats.photon_maps[0]["stored"] > 0


def window_error(img, ref):
    d = img[..., 0].astype(np.float64) - ref.image[..., 0]
    return (d ** 2).mean(), d.sum()


def test_photon_image_converges_to_path_tracing(device_spec, pt_reference):
    """The photon map owns exactly the caustic paths the path tracer leaves to
    it: the image converges to the path-traced one, and the bias (the blur of
    the radius) shrinks with the radius."""
    r = clpt.Renderer(caustic_scene(), device=device_spec)
    ref_var = pt_reference.lum_var / pt_reference.sample_count
    mse = {}
    for rad in (0.04, 0.02, 0.01, 0.005):
        res = r.render(256, seed=2, photons=PhotonSettings(radius=rad, count=400_000))
        var = res.lum_var / res.sample_count
        mse[rad], total = window_error(res.image, pt_reference)
        if rad == 0.005:  # the image's total (where blurring cannot hide bias) agrees within noise
            sigma = math.sqrt((var + ref_var).sum())
            assert abs(total) < 5 * sigma, f"image sum differs by {total:.3f} (sigma {sigma:.3f})"
    assert mse[0.04] > 2 * mse[0.02] > 2 * 2 * mse[0.01] > 0, mse
    assert mse[0.005] < mse[0.01]


def test_online_and_offline_agree(device_spec):
    r = clpt.Renderer(caustic_scene(), device=device_spec)
    on = r.render(256, seed=3, photons=PhotonSettings(mode="online", radius=0.01))
    off = r.render(256, seed=3, photons=PhotonSettings(mode="offline", radius=0.01, offline_spp=64))
    var = on.lum_var / on.sample_count + off.lum_var / off.sample_count
    # The same photon map: what differs is the sampling of the pixels only.
    assert abs(on.image[..., 0].sum() - off.image[..., 0].sum()) < 5 * math.sqrt(var.sum())
    assert on.stats.launches["trace_paths"] >= 2 and "trace_photons" in off.stats.launches


def stored_flux(renderer, seed, settings):
    """Per-slot flux of one photon map (0 where no photon was stored)."""
    st = renderer.states[0]
    st.build_photons(seed, settings, 0.01, 1)
    n = settings.count
    pw = np.empty((n, 4), np.float32)
    cl.enqueue_copy(st.dctx.queue, pw, st.pmap.raw[2])
    st.dctx.queue.finish()
    return pw[:, :3].astype(np.float64)


def test_aiming_modes_deliver_the_same_caustic_flux(device_spec):
    """Aiming photons by solid angle or in equal shares changes where photons
    go, not the flux they carry in expectation: the emission pdf is accounted."""
    scene = clpt.load_scene("fig09_mirror_and_green_glass")
    r = clpt.Renderer(scene, device=device_spec)
    sums = {}
    for aim in ("solid_angle", "equal"):
        s = PhotonSettings(count=400_000, aim=aim)
        f = stored_flux(r, 11, s)
        n = len(f)
        sums[aim] = (f.sum(0), f.std(0) * math.sqrt(n))  # a sum of n i.i.d. slots
    (a, sa), (b, sb) = sums["solid_angle"], sums["equal"]
    for c in range(3):
        assert_mean_within(a[c], b[c], math.hypot(sa[c], sb[c]), 5.0, what=f"stored flux, channel {c}")
    # A caster behind the light's emitting side gets no photons when aiming by
    # solid angle; equal shares waste half of them there.
    behind = caustic_scene()
    behind.shapes.append(clpt.Sphere(center=(0, 3.0, 0), radius=0.3, material="mirror"))
    rb = clpt.Renderer(behind, device=device_spec)
    n_solid = (stored_flux(rb, 12, PhotonSettings(count=100_000)) > 0).any(1).sum()
    n_equal = (stored_flux(rb, 12, PhotonSettings(count=100_000, aim="equal")) > 0).any(1).sum()
    assert n_solid > 1.8 * n_equal


@pytest.mark.parametrize("mode", ["online", "offline"])
def test_photon_renders_are_reproducible(device_spec, mode):
    r = clpt.Renderer(caustic_scene(12), device=device_spec)
    s = PhotonSettings(mode=mode, count=50_000)
    a = r.render(8, seed=5, photons=s, pass_seconds=1e9).image
    b = r.render(8, seed=5, photons=s, pass_seconds=1e-9).image
    assert np.array_equal(a, b)
    assert not np.array_equal(a, r.render(8, seed=6, photons=s).image)


def test_progressive_radius_schedule():
    s = PhotonSettings(progressive=True, alpha=0.7, radius=0.1, radius_absolute=True)
    r = [s.radius_for(1.0, i) for i in range(5)]
    for i in range(4):  # r_{i+1}^2 = r_i^2 (i + alpha) / (i + 1)
        assert r[i + 1] ** 2 == pytest.approx(r[i] ** 2 * (i + 0.7) / (i + 1), rel=1e-12)
    assert PhotonSettings(radius=0.1).radius_for(2.0, 7) == pytest.approx(0.2)


def test_progressive_photon_mapping_converges_past_the_fixed_blur(device_spec, pt_reference):
    """Same photons in all: one map with a fixed radius keeps its blur; fresh
    maps with a shrinking radius get closer to the path-traced image."""
    r = clpt.Renderer(caustic_scene(), device=device_spec)
    fixed = r.render(256, seed=4, photons=PhotonSettings(radius=0.04, count=12_800 * 32))
    prog = r.render(256, seed=4, photons=PhotonSettings(radius=0.04, count=12_800, progressive=True,
                                                        spp_per_map=8, alpha=0.5))
    assert len(prog.stats.photon_maps) == 32
    radii = [m["radius"] for m in prog.stats.photon_maps]
    assert radii == sorted(radii, reverse=True) and radii[-1] < 0.7 * radii[0]
    assert window_error(prog.image, pt_reference)[0] < 0.5 * window_error(fixed.image, pt_reference)[0]
