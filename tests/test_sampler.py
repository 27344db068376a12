"""The named dimensions (kernels/sampler.h): past the stratified vertices
each decision reads the rng.h group and component the table in sampler.h
gives it; the camera's position and the first vertex's decisions come from
scrambled (0,2)-sequences, every power-of-two run of a pixel's samples a
whole net, each pair of dimensions in its own order."""

import numpy as np
import pyopencl as cl
import pytest

from stats import ALPHA, chi2_test, sidak
from test_rng import draw

pytestmark = pytest.mark.portability

PHOTON_SEED_SALT = 0x5BD1E995
STRATIFIED_DEPTH = 1  # kernels/sampler.h CLPT_STRATIFIED_DEPTH
# probe_sampler's outputs that are stratified pairs at depth 0: camera x y, the light's point, the pick with
# the merge decision, the lobe's direction, the lobe with Fresnel's choice
PAIRS = {"camera": (0, 1), "light point": (3, 4), "pick, merge": (2, 5), "direction": (7, 8),
         "lobe, fresnel": (6, 9)}


@pytest.mark.parametrize("lanes", [1, 8])
def test_named_dimensions_are_the_groups_of_the_table(probes, lanes):
    probe = probes(lanes)
    rng = np.random.default_rng(3)
    n = 64
    pixel = rng.integers(0, 1 << 20, n).astype(np.uint32)
    sample = rng.integers(0, 1 << 16, n).astype(np.uint32)
    depth = rng.integers(STRATIFIED_DEPTH, 40, n).astype(np.uint32)
    seed, bounce = 77, 5
    ctx, q, mf = probe.dctx.context, probe.dctx.queue, cl.mem_flags
    ins = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a) for a in (pixel, sample, depth)]
    out = np.zeros(18 * n, dtype=probe.real)
    ob = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    cl.Kernel(probe.program, "probe_sampler")(q, (n // lanes,), (1,), np.uint32(seed), np.uint32(bounce), *ins, ob)
    cl.enqueue_copy(q, out, ob)
    q.finish()
    got = out.reshape(n // lanes, 18, lanes).transpose(0, 2, 1).reshape(n, 18).T
    z = np.zeros(n, dtype=np.uint32)
    cam = draw(probe, seed, pixel, sample, z)
    vertex = draw(probe, seed, pixel, sample, depth * 2 + 1)
    bsdf = draw(probe, seed, pixel, sample, depth * 2 + 2)
    pseed = seed ^ PHOTON_SEED_SALT
    emit0, emit1 = draw(probe, pseed, pixel, z, z), draw(probe, pseed, pixel, z, z + 1)
    bounce_g = draw(probe, pseed, pixel, z, z + 2 + bounce)
    want = [None, None, vertex[0], vertex[1], vertex[2], vertex[3], bsdf[0], bsdf[1], bsdf[2], bsdf[3],
            emit0[0], emit0[1], emit0[2], emit0[3], emit1[0], emit1[1], bounce_g[0], bounce_g[1]]
    for k, w in enumerate(want):
        if w is not None:  # (the camera's numbers are stratified: tests below)
            assert np.array_equal(got[k], w), k


def sampler_draws(probe, seed, pixel, sample, depth):
    """probe_sampler's 18 numbers (rows) for each (pixel, sample, depth)."""
    n = max(np.size(a) for a in (pixel, sample, depth))
    pixel, sample, depth = (np.broadcast_to(np.asarray(a, np.uint32), (n,)).copy() for a in (pixel, sample, depth))
    lanes = probe.lanes
    pad = -(-n // lanes) * lanes
    ctx, q, mf = probe.dctx.context, probe.dctx.queue, cl.mem_flags
    ins = []
    for a in (pixel, sample, depth):
        h = np.zeros(pad, np.uint32)
        h[:n] = a
        ins.append(cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=h))
    out = np.zeros(18 * pad, dtype=probe.real)
    ob = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    cl.Kernel(probe.program, "probe_sampler")(q, (pad // lanes,), (1,), np.uint32(seed), np.uint32(0), *ins, ob)
    cl.enqueue_copy(q, out, ob)
    q.finish()
    return out.reshape(pad // lanes, 18, lanes).transpose(0, 2, 1).reshape(pad, 18).T[:, :n].astype(np.float64)


def is_net(x, y):
    """Whether 2^m points are a (0, m, 2)-net in base 2: one point in each
    elementary interval of area 2^-m, of every shape (2^k by 2^(m-k))."""
    n = len(x)
    m = int(np.log2(n))
    assert 1 << m == n
    for k in range(m + 1):
        cells = np.floor(x * (1 << k)).astype(np.int64) * (1 << (m - k)) + np.floor(y * (1 << (m - k)))
        if len(np.unique(cells)) != n:
            return False
    return True


@pytest.mark.parametrize("lanes", [1, 8])
def test_each_pixels_power_of_two_runs_are_nets(probes, lanes):
    """Samples 0-15, 16-31, 32-47 and 0-63 of a pixel (a pass's run, or the
    render so far) put one point in every elementary interval, for every
    stratified pair; deeper vertices do not (independent numbers)."""
    probe = probes(lanes)
    for seed, pixel in ((1, 0), (7, 12345), (4000000000, 99)):
        u = sampler_draws(probe, seed, pixel, np.arange(64), 0)
        for name, (a, b) in PAIRS.items():
            for lo, hi in ((0, 16), (16, 32), (32, 48), (0, 64)):
                assert is_net(u[a, lo:hi], u[b, lo:hi]), (name, seed, pixel, lo, hi)
        deep = sampler_draws(probe, seed, pixel, np.arange(64), STRATIFIED_DEPTH)
        assert not all(is_net(deep[a, :16], deep[b, :16]) for a, b in list(PAIRS.values())[1:])


def test_stratified_numbers_uniform_and_pairs_unrelated(probes):
    """Over pixels, each stratified number is uniform, and numbers of
    different pairs (and of a pair and the independent ones) are jointly
    uniform. Within a pixel, two pairs take its samples in unrelated orders:
    of 16 samples, 8 have x < 1/2 in each pair, and how many have both is
    Binomial(8, 1/2) (mean 4, variance 2): the scrambles keep samples 2k and
    2k+1 in opposite halves in both pairs, and independently for each k
    pick whether the halves match. Pairs that followed one another would
    give 0 or 8 (variance 16); independent numbers, Binomial(16, 1/4)
    (variance 3)."""
    probe = probes(8)
    n_pix = 4096
    pix = np.repeat(np.arange(n_pix, dtype=np.uint32), 16)
    smp = np.tile(np.arange(16, dtype=np.uint32), n_pix)
    u = sampler_draws(probe, 11, pix, smp, 0)
    first = u[:, ::16]  # sample 0 of each pixel
    names = list(PAIRS)
    trials = 10 + len(names) * (len(names) - 1) // 2 + 4
    for k in range(10):
        h, _ = np.histogram(first[k], bins=64, range=(0, 1))
        p, stat, dof = chi2_test(h, np.full(64, n_pix / 64))
        assert p > sidak(ALPHA, trials), f"number {k}: chi2 {stat:.1f}/{dof}"
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            a, b = PAIRS[names[i]][0], PAIRS[names[j]][1]
            h, _, _ = np.histogram2d(first[a], first[b], bins=8, range=[(0, 1), (0, 1)])
            p, stat, dof = chi2_test(h, np.full(h.shape, n_pix / 64))
            assert p > sidak(ALPHA, trials), f"{names[i]} x {names[j]}: chi2 {stat:.1f}/{dof}"
            both = ((u[a] < 0.5) & (u[b] < 0.5)).reshape(n_pix, 16).sum(1)
            assert (np.bincount(((u[a] < 0.5)).reshape(n_pix, 16).sum(1)) == [0] * 8 + [n_pix]).all()
            z_mean = (both.mean() - 4) / np.sqrt(2 / n_pix)
            assert abs(z_mean) < 4.5, (names[i], names[j], both.mean())
            # the sample variance's standard error: sqrt((mu4 - sigma^4) / n), mu4 = 11 for Binomial(8, 1/2)
            assert abs(both.var() - 2) < 4.5 * np.sqrt((11 - 4) / n_pix), (names[i], names[j], both.var())


def test_stratified_numbers_pure_function_of_key(probes):
    """The same numbers at any lane width and precision, and new ones for another seed."""
    pix = np.arange(256, dtype=np.uint32) * 7919
    smp = np.arange(256, dtype=np.uint32) % 37
    a = sampler_draws(probes(1), 5, pix, smp, 0)
    b = sampler_draws(probes(8), 5, pix, smp, 0)
    c = sampler_draws(probes(8, True), 5, pix, smp, 0)
    assert np.array_equal(a, b) and np.array_equal(a, c)
    assert not np.array_equal(a[:10], sampler_draws(probes(8), 6, pix, smp, 0)[:10])
