"""The pixel filters' sampling (kernels/camera.h): offsets drawn through the
probe kernel against the filters as Mitsuba 3 defines them (chi-square over
the filter's support, within the film and across its edge), the gaussian's
table against the filter, the kernels' inverses against exact ones, and
edge inputs."""

import math

import numpy as np
import pytest

from clpt.constants import GAUSSIAN_HALF_MASS, GAUSSIAN_TABLE_BINS, gaussian_filter_table, gaussian_table_cdf
from clpt.engine.launch import fill_pixel_filter
from clpt.layout import FILTER
from clpt.scene import PixelFilter
from stats import ALPHA, chi2_test, sidak

KINDS = {"box": 0, "tent": 1, "gaussian": 2}
N = 200_000
BINS = 41
# (filter, pixel centre, image width): inside the film, at its edge, one pixel in, and a film
# narrower than the filter.
FILTERS = [PixelFilter("box"), PixelFilter("tent"), PixelFilter("tent", radius=2.5), PixelFilter("gaussian"),
           PixelFilter("gaussian", stddev=0.25), PixelFilter("gaussian", stddev=1.3)]
PLACES = [(100.5, 200), (0.5, 200), (1.5, 200), (199.5, 200), (1.5, 3)]
CASES = [(f, c, n, border) for f in FILTERS for c, n in PLACES for border in (False, True)
         if not (border and c == 100.5) and (f.kind != "box" or c == 100.5)]


def weight(pf: PixelFilter, x):
    """Mitsuba's filter (up to a constant): box, tent, windowed gaussian."""
    x = np.asarray(x, dtype=np.float64)
    r = pf.extent
    if pf.kind == "tent":
        return np.maximum(0.0, 1 - np.abs(x) / r)
    if pf.kind == "gaussian":
        s = pf.sigma
        return np.maximum(0.0, np.exp(-x * x / (2 * s * s)) - math.exp(-r * r / (2 * s * s)))
    return ((x >= -0.5) & (x < 0.5)).astype(np.float64)


def table_model(s):
    """What the kernels sample for the gaussian, in units of its radius, for
    s in [0, 1): (the density, the half's CDF), as clpt/constants.py tabulates it."""
    nodes = gaussian_filter_table()
    s = np.asarray(s, dtype=np.float64)
    k = np.minimum(np.searchsorted(nodes, s, side="right") - 1, GAUSSIAN_TABLE_BINS - 1)
    s0, s1 = nodes[k], nodes[k + 1]
    w, d = s1 - s0, s - s0
    g0, g1 = np.exp(-8 * s0 ** 2) - np.exp(-8.0), np.exp(-8 * s1 ** 2) - np.exp(-8.0)
    q0, q1 = gaussian_table_cdf(k), gaussian_table_cdf(k + 1)
    dens = (g0 + (g1 - g0) * d / w) / ((g0 + g1) * w / 2) * (q1 - q0) * GAUSSIAN_HALF_MASS
    frac = (g0 * d + (g1 - g0) * d * d / (2 * w)) / ((g0 + g1) * w / 2)
    return dens, q0 + frac * (q1 - q0)


def table_integral(pf: PixelFilter, x):
    """The integral from 0 to x (odd, in the units of `integral`) of the kernels' gaussian."""
    x = np.asarray(x, dtype=np.float64)
    r = pf.extent
    _, cdf = table_model(np.minimum(np.abs(x) / r, 1 - 1e-16))
    return np.sign(x) * r * GAUSSIAN_HALF_MASS * np.where(np.abs(x) >= r, 1.0, cdf)


def integral(pf: PixelFilter, x):
    """The filter's integral from 0 to x, |x| <= its radius, in double."""
    x = np.asarray(x, dtype=np.float64)
    r = pf.extent
    if pf.kind == "tent":
        return x - x * np.abs(x) / (2 * r)
    if pf.kind == "gaussian":
        s = pf.sigma
        erf = np.vectorize(math.erf)
        return s * math.sqrt(math.pi / 2) * erf(x / (s * math.sqrt(2))) - math.exp(-r * r / (2 * s * s)) * x
    return x


def support(pf, c, n, border):
    r = pf.extent
    return (-r, r) if border else (max(-r, -c), min(r, n - c))


def exact_inverse(pf, u, c, n, border, integral=integral, bounds=None):
    """The offset whose CDF (over the support) is u, by bisection in double
    (the support's ends through `bounds`, the same integral by default)."""
    lo, hi = support(pf, c, n, border)
    a, b = (bounds or integral)(pf, lo), (bounds or integral)(pf, hi)
    t = a + np.asarray(u, dtype=np.float64) * (b - a)
    x0, x1 = np.full(len(t), lo), np.full(len(t), hi)
    for _ in range(64):
        m = 0.5 * (x0 + x1)
        below = integral(pf, m) < t
        x0, x1 = np.where(below, m, x0), np.where(below, x1, m)
    return 0.5 * (x0 + x1)


def offsets(probe, pf, u, c, n, border):
    real = probe.real
    rec = fill_pixel_filter(FILTER.zeros(real == np.float64), pf)
    return probe.run("probe_pixel_filter", [u, np.full(len(u), c)], 1,
                     scalars=(np.int32(KINDS[pf.kind]), real(rec["radius"]), np.uint32(border),
                              real(n)))[0][:len(u)]


def label(case):
    pf, c, n, border = case
    extra = f" r={pf.radius}" if pf.radius else f" s={pf.stddev}" if pf.stddev else ""
    return f"{pf.kind}{extra} c={c} n={n}{' border' if border else ''}"


@pytest.mark.parametrize("case", CASES, ids=label)
def test_filter_offsets_follow_the_filter(probes, case):
    pf, c, n, border = case
    u = np.random.default_rng(7).random(N, dtype=np.float32)
    x = offsets(probes(8), pf, u, c, n, border).astype(np.float64)
    lo, hi = support(pf, c, n, border)
    assert np.isfinite(x).all() and (x >= lo).all() and (x <= hi).all(), (x.min(), x.max(), lo, hi)
    edges = np.linspace(lo, hi, BINS + 1)
    h, _ = np.histogram(x, bins=edges)
    mass = np.diff(integral(pf, edges))
    expected = mass / mass.sum() * N
    p, stat, dof = chi2_test(h, expected)
    if p <= sidak(ALPHA, len(CASES)):
        np.savez(f"/tmp/clpt_filter_{KINDS[pf.kind]}.npz", observed=h, expected=expected, edges=edges)
    assert p > sidak(ALPHA, len(CASES)), f"chi2 {stat:.1f} for {dof} dof, p = {p:.3g}"
    # The expected counts come from the integral of the filter Mitsuba weights with (checked
    # here by quadrature per bin, midpoint rule on 256 points).
    t = (np.arange(256) + 0.5) / 256
    quad = np.array([weight(pf, a + (b - a) * t).mean() * (b - a) for a, b in zip(edges[:-1], edges[1:])])
    assert np.allclose(mass / mass.sum(), quad / quad.sum(), rtol=1e-4, atol=1e-7)


def test_gaussian_table_is_the_filter():
    """The gaussian is sampled through its table: a density within 2.6e-5 of
    the filter's peak everywhere, its CDF continuous and exact at the nodes."""
    pf = PixelFilter("gaussian", stddev=0.25)  # radius 1: s = x
    s = np.linspace(0, 1, 1_000_001)[:-1]
    dens, cdf = table_model(s)
    assert np.abs(dens - weight(pf, s)).max() / weight(pf, 0.0) < 2.6e-5
    exact = integral(pf, s) / integral(pf, 1.0)
    assert np.abs(cdf - exact).max() < 1e-6
    assert (np.diff(cdf) >= 0).all()


@pytest.mark.parametrize("double", [False, True], ids=["float", "double"])
@pytest.mark.parametrize("lanes", [1, 8])
@pytest.mark.parametrize("pf", [PixelFilter("tent", radius=1.5), PixelFilter("gaussian"),
                                PixelFilter("gaussian", stddev=3.0)], ids=lambda p: p.kind + str(p.extent))
def test_filter_inverse_is_exact(probes, pf, lanes, double):
    """The kernels invert exactly what they sample (the tent; the gaussian's
    table interpolant), to the precision of the build's reals, in the tails
    too and across the film's edge."""
    rng = np.random.default_rng(3)
    u = np.concatenate([rng.random(4000), [0.0, 1e-7, 0.5, 1 - 2.0 ** -24, 1 - (1e-15 if double else 2.0 ** -24)]])
    u = u.astype(np.float64 if double else np.float32)
    model = table_integral if pf.kind == "gaussian" else integral
    for c, n, border in ((50.5, 100, False), (0.5, 100, False), (1.5, 100, False), (0.5, 100, True)):
        x = offsets(probes(lanes, double=double), pf, u, c, n, border).astype(np.float64)
        # The kernel cuts the gaussian at the film's edge by its exact CDF (erf), within 1e-6
        # of its table's.
        want = exact_inverse(pf, u.astype(np.float64), c, n, border, integral=model, bounds=integral)
        # An offset error de moves the CDF by f(x) de: compare in the CDF (probability), where
        # float's rounding of u itself is 6e-8.
        lo, hi = support(pf, c, n, border)
        a, b = model(pf, lo), model(pf, hi)
        err_p = np.abs(model(pf, x) - model(pf, want)) / (b - a)
        tol = 1e-12 if double else 2e-6
        assert err_p.max() < tol, (c, border, err_p.max(), u[np.argmax(err_p)])
        # In offset, where the filter is not near 0 (at its radius an offset error is no error in
        # probability).
        body = weight(pf, want) > 0.01
        dx = np.abs(x - want)[body].max()
        assert dx < (1e-9 if double else 1e-4) * pf.extent, (c, border, dx)
        assert lo <= x.min() and x.max() <= hi


def test_box_offsets_are_the_uniform_position(probes):
    u = np.random.default_rng(1).random(1000, dtype=np.float32)
    x = offsets(probes(8), PixelFilter(), u, 10.5, 100, False)
    assert np.array_equal(x, u - np.float32(0.5))
