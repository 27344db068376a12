"""The counter-based RNG (kernels/rng.h): uniform, independent across
dimensions, pixels and samples, and a pure function of its key."""

import numpy as np
import pytest

from stats import ALPHA, chi2_test, sidak

pytestmark = pytest.mark.portability

N = 1 << 18


def draw(probe, seed, pixel, sample, group):
    return np.stack(probe.run("probe_rng", [pixel, sample, group], 4, scalars=(np.uint32(seed),)), 0)


def keys(kind, n=N):
    i = np.arange(n, dtype=np.uint32)
    z = np.zeros(n, dtype=np.uint32)
    return {"pixels": (i, z, z), "samples": (z, i, z), "groups": (z, z, i),
            "mixed": (i % 512, i // 512, i % 7)}[kind]


@pytest.mark.parametrize("kind", ["pixels", "samples", "groups", "mixed"])
def test_uniform_and_independent(probes, kind):
    u = draw(probes(8), 1234, *keys(kind)).astype(np.float64)
    assert (u >= 0).all() and (u < 1).all()
    trials = 4 * (4 + 6)
    for d in range(4):  # each dimension uniform
        h, _ = np.histogram(u[d], bins=128, range=(0, 1))
        p, stat, dof = chi2_test(h, np.full(128, N / 128))
        assert p > sidak(ALPHA, trials), f"dimension {d}: chi2 {stat:.1f}/{dof}, p = {p:.3g}"
    for a in range(4):  # pairs of dimensions jointly uniform
        for b in range(a + 1, 4):
            h, _, _ = np.histogram2d(u[a], u[b], bins=24, range=[(0, 1), (0, 1)])
            p, stat, dof = chi2_test(h, np.full(h.shape, N / h.size))
            assert p > sidak(ALPHA, trials), f"dims {a},{b}: chi2 {stat:.1f}/{dof}, p = {p:.3g}"


def test_neighbours_uncorrelated(probes):
    """Adjacent pixels, samples and dimension groups draw unrelated numbers."""
    i = np.arange(N, dtype=np.uint32)
    z = np.zeros(N, dtype=np.uint32)
    base = draw(probes(8), 7, i, z, z)[0]
    for other in (draw(probes(8), 7, i + 1, z, z)[0], draw(probes(8), 7, i, z + 1, z)[0],
                  draw(probes(8), 7, i, z, z + 1)[0], draw(probes(8), 8, i, z, z)[0]):
        r = np.corrcoef(base, other)[0, 1]
        assert abs(r) < 5 / np.sqrt(N), f"correlation {r:.4f}"


def test_pure_function_of_key(probes):
    """Same key, same numbers: across lane widths and precisions, in any order."""
    pix, smp, grp = keys("mixed", 4096)
    a = draw(probes(1), 99, pix, smp, grp)
    b = draw(probes(8), 99, pix, smp, grp)
    c = draw(probes(8, True), 99, pix, smp, grp)
    perm = np.random.default_rng(0).permutation(4096)
    d = draw(probes(8), 99, pix[perm], smp[perm], grp[perm])
    assert np.array_equal(a, b)
    assert np.array_equal(a.astype(np.float64), c)
    assert np.array_equal(a[:, perm], d)
    assert not np.array_equal(a, draw(probes(8), 100, pix, smp, grp))
