"""Adaptive sample allocation: the host's decisions (pure numpy) and adaptive
renders, which must converge to the same image as uniform sampling."""

import numpy as np
import pytest

import clpt
from clpt.adaptive import (ERROR_FLOOR, AdaptiveSettings, allocate_error, allocate_paper, allocation_ceiling,
                           colour_weight, discrepant, relative_error)
from clpt.adaptive import _worst
from clpt.constants import LUMA

from stats import assert_mean_within


def test_error_allocation_follows_the_error_and_the_budget():
    lum = np.full((8, 8), 0.5)
    var = np.full((8, 8), 1e-6)  # converged: relative error 1e-3 / 0.5 at 4 samples
    var[2, 3] = 0.5              # one noisy pixel
    count = np.full((8, 8), 4.0)
    s = AdaptiveSettings(threshold=0.05, pass_spp=16)
    n, err = allocate_error(lum, var, count, s, budget_left=10_000)
    assert n[2, 3] == 16
    # Its neighbours get samples too (their estimate might be the lucky one);
    # pixels two steps away do not.
    assert (n[1:4, 2:5] > 0).all() and n[5:, 5:].sum() == 0 and n[0, 0] == 0
    n2, _ = allocate_error(lum, var, count, s, budget_left=20)
    assert n2.sum() == 20 and n2[2, 3] == n2.max()  # shared by need, the worst pixel first
    n3, _ = allocate_error(lum, var, count, s, budget_left=0)
    assert n3.sum() == 0
    # Dark pixels are measured against relMSE's floor (0.1 in luminance), bright ones against their mean.
    assert relative_error(np.array([0.0]), np.array([1e-4]), np.array([1.0]))[0] == pytest.approx(0.1)
    assert relative_error(np.array([2.0]), np.array([4e-2]), np.array([4.0]))[0] == pytest.approx(0.05, rel=2e-3)
    # A pixel's error is blended with its 3x3's, not raised to their largest: the noisy
    # pixel's neighbour gets sqrt((own^2 + mean of the 3x3's squares) / 2).
    own = relative_error(lum, var, count)
    box = (own[1:4, 1:4] ** 2).mean()
    assert err[2, 2] == pytest.approx(np.sqrt(0.5 * (own[2, 2] ** 2 + box)), rel=1e-12)
    assert own[2, 2] < err[2, 2] < 0.5 * err[2, 3]


def test_the_left_over_samples_go_to_the_worst_pixels_as_a_full_sort_orders_them():
    # _worst partitions instead of sorting the image: the same pixels as the
    # first k candidates of a stable sort by (-err, -own), ties (many, with
    # integer errors) included.
    rng = np.random.default_rng(7)
    for trial in range(400):
        n = int(rng.integers(1, 200))
        err = rng.integers(0, 4, n).astype(float) if trial % 2 else rng.random(n)
        own = rng.integers(0, 3, n).astype(float)
        cand = np.flatnonzero(rng.random(n) < 0.7)
        k = int(rng.integers(1, n + 2))
        order = np.lexsort((-own, -err))
        expect = order[np.isin(order, cand)][:k]
        got = _worst(cand, err, own, k)
        assert len(got) == len(expect) and set(got.tolist()) == set(expect.tolist())


def test_colour_weight_is_what_rgb_relmse_makes_of_the_luminance_noise():
    """Where a pixel's samples are its colour times one random factor, each
    channel's variance is the luminance's times (m_c / Y)^2: colour_weight
    times the luminance variance is then exactly RGB relMSE's weighting of
    the channels' variances. Grey pixels weigh as without colours."""
    rng = np.random.default_rng(5)
    m = rng.uniform(0.0, 3.0, (40, 3)) * rng.uniform(0.0, 1.0, (40, 1)) ** 3  # saturated, dark and bright
    sigma2 = rng.uniform(0.01, 4.0, 40)  # the factor's variance
    y = m @ LUMA
    var_c = m * m * sigma2[:, None]
    var_y = y * y * sigma2
    rgb = (var_c / (m * m + ERROR_FLOOR ** 2)).mean(axis=1)
    assert colour_weight(m, y) * var_y == pytest.approx(rgb, rel=1e-9)
    grey = np.repeat(y[:, None], 3, axis=1)
    assert relative_error(y, var_y, 4.0, grey) == pytest.approx(relative_error(y, var_y, 4.0), rel=1e-9)
    # A red pixel and a grey one of the same luminance and luminance noise: RGB relMSE
    # counts the red one's about half as much (its green and blue are all but noiseless).
    red = np.array([[0.6, 0.02, 0.02]])
    yr = red @ LUMA
    assert 0.4 < colour_weight(red, yr)[0] * (yr[0] ** 2 + ERROR_FLOOR ** 2) < 0.6


def test_colour_weighted_allocation_lowers_rgb_relmse():
    """Rounds of allocate_error on a 16x16 image of grey and saturated
    pixels with exactly known variances (each pixel's colour times a random
    factor): with the colours, the final counts give a lower summed RGB
    relative variance than without them, for as many samples."""
    rng = np.random.default_rng(11)
    shape = (16, 16)
    m = np.repeat(rng.uniform(0.05, 1.0, shape + (1,)), 3, axis=2)
    sat = rng.random(shape) < 0.5
    hue = rng.integers(0, 3, shape)
    for c in range(3):
        m[..., c] = np.where(sat & (hue != c), 0.02 * m[..., c], m[..., c])
    y = m @ LUMA
    sigma2 = rng.lognormal(0.0, 0.7, shape)
    var_y = y * y * sigma2
    S2 = ((m * m * sigma2[..., None]) / (m * m + ERROR_FLOOR ** 2)).sum(axis=-1)  # RGB weight per sample

    def final_counts(mean_rgb):
        s = AdaptiveSettings(threshold=1e-4)
        count = np.full(shape, 32.0)
        for _ in range(12):
            n, _ = allocate_error(y, var_y, count, s, budget_left=int(count.size * 32), mean_rgb=mean_rgb)
            count = count + n
        return count

    def error_times_samples(n):  # summed RGB relative variance, per sample spent
        return float((S2 / n).sum() * n.sum())

    with_colour, without = final_counts(m), final_counts(None)
    assert abs(with_colour.sum() / without.sum() - 1.0) < 0.01
    assert error_times_samples(without) > 1.02 * error_times_samples(with_colour)
    # and within 4% of the best counts' (n_i proportional to sqrt(S2_i); 2.2% here; without colours 5%)
    assert error_times_samples(with_colour) < 1.04 * np.sqrt(S2).sum() ** 2


def test_allocation_ceiling_is_the_best_allocations_gain():
    """The ceiling is uniform's summed relative variance over that of the
    counts proportional to s_i; random other counts of the same total never
    beat it; alike pixels give 1."""
    rng = np.random.default_rng(2)
    mean = rng.uniform(0.0, 2.0, (16, 16))
    var = rng.lognormal(-3.0, 1.5, (16, 16))
    w = var / (mean * mean + ERROR_FLOOR ** 2)  # each pixel's relative variance per sample
    N = 1000.0 * w.size

    def summed(n):
        return float((w / n).sum())

    s = np.sqrt(w)
    best = summed(N * s / s.sum())
    ceiling = allocation_ceiling(mean, var)
    assert ceiling == pytest.approx(summed(np.full(w.shape, N / w.size)) / best, rel=1e-12)
    assert ceiling > 1.5  # (these pixels differ a lot)
    for _ in range(50):
        other = rng.uniform(0.1, 1.0, w.shape)
        assert summed(N * other / other.sum()) >= best
    assert allocation_ceiling(np.ones((4, 4)), np.full((4, 4), 0.3)) == pytest.approx(1.0, rel=1e-12)
    assert allocation_ceiling(np.ones((4, 4)), np.zeros((4, 4))) == 1.0


def test_paper_scheme_finds_pixels_that_disagree_with_their_neighbours():
    lum = np.full((7, 7), 0.4)
    lum[3, 3] = 2.0                     # an outlier: differs from all 8 neighbours
    lum[:, 0] = 0.1                     # an edge: its pixels agree with 5 of 8
    d = discrepant(lum, 0.1)
    assert d[3, 3] and d.sum() == 1
    s = AdaptiveSettings(scheme="paper", pass_spp=16)
    n, depth, _ = allocate_paper(lum, s, 8)
    assert n[3, 3] == 16 and n[0, 0] == 4 and depth[3, 3] == 8 and depth[0, 0] == 4
    n, depth, _ = allocate_paper(lum, AdaptiveSettings(scheme="paper", paper_mode="stop"), 8)
    assert n[0, 0] == 0 and (depth == 8).all()


@pytest.fixture(scope="module")
def caustics(device_spec):
    return clpt.Renderer("cornell_box_caustics", device=device_spec, photons=False)


@pytest.fixture(scope="module")
def uniform_reference(caustics):
    return caustics.render(4096, width=24, height=24, seed=1)


@pytest.mark.parametrize("settings", [
    AdaptiveSettings(min_spp=32, threshold=0.03, pass_spp=32),
    AdaptiveSettings(scheme="paper", min_spp=32, pass_spp=32, reduce_depth=False),
], ids=["error", "paper_no_depth_cut"])
def test_adaptive_render_converges_to_the_uniform_image(caustics, uniform_reference, settings):
    """Where samples go does not bias the image (beyond the paper's optional
    depth cut, which is off here)."""
    res = caustics.render(256, width=24, height=24, seed=2, adaptive=settings)
    assert res.stats.adaptive_rounds >= 1 and res.sample_count.min() >= 32
    assert res.sample_count.max() > res.sample_count.min()  # samples went where they were needed
    ref = uniform_reference
    var = res.lum_var / res.sample_count + ref.lum_var / ref.sample_count
    d = res.image[..., 1].astype(np.float64) - ref.image[..., 1]
    assert_mean_within(d.mean(), 0.0, np.sqrt(var.sum()) / var.size, 5.0, what="adaptive - uniform")
    assert res.stats.camera_rays == res.sample_count.sum()  # inactive pixels traced nothing


def test_paper_depth_cut_is_a_visible_switchable_bias(device_spec):
    """Halving the depth of the calm pixels darkens them: the paper's trade of
    accuracy for speed, off with reduce_depth=False."""
    r = clpt.Renderer("cornell_box", device=device_spec)
    cut = r.render(96, width=16, height=16, seed=3, max_depth=2,
                   adaptive=AdaptiveSettings(scheme="paper", min_spp=16, pass_spp=16))
    full = r.render(96, width=16, height=16, seed=3, max_depth=2,
                    adaptive=AdaptiveSettings(scheme="paper", min_spp=16, pass_spp=16, reduce_depth=False))
    assert cut.image.mean() < full.image.mean() * 0.97


def test_adaptive_budget_and_reproducibility(caustics):
    s = AdaptiveSettings(min_spp=8, threshold=0.001, pass_spp=8)
    a = caustics.render(24, width=16, height=16, seed=4, adaptive=s)
    b = caustics.render(24, width=16, height=16, seed=4, adaptive=s)
    assert np.array_equal(a.image, b.image) and np.array_equal(a.sample_count, b.sample_count)
    assert a.sample_count.sum() <= 24 * 256  # the budget: spp on average
    assert a.sample_count.sum() > 20 * 256


def test_noisy_pixels_get_the_samples(caustics):
    """Pixels that are noisy after the first samples (glass, caustics, the
    light's edge) end up with more samples than calm walls."""
    res = caustics.render(64, width=32, height=32, seed=5,
                          adaptive=AdaptiveSettings(min_spp=16, threshold=0.02, pass_spp=16))
    # Noisy as the error scheme measures it: relative to the mean, dark pixels to relMSE's floor.
    rel = np.sqrt(res.lum_var / res.sample_count) / np.sqrt(res.image.mean(-1) ** 2 + 0.1 ** 2)
    noisy = rel > np.percentile(rel, 90)
    assert res.sample_count[noisy].mean() > 1.5 * res.sample_count[~noisy].mean()


def test_adaptive_rounds_gather_from_maps_at_the_uniform_rate(device_spec):
    """With progressive photon merging, adaptive rounds gather from as many
    fresh photon maps as their samples fill at spp_per_map samples of every
    pixel per map, as the uniform phase does: one map per round let a map's
    photons serve up to eight times the samples (noise shared by all of them,
    unseen by the per-pixel error) and kept the radius wide. Each pixel's
    samples stay its own sequence, so the render is reproducible."""
    r = clpt.Renderer("cornell_box_caustics", device=device_spec)
    ps = clpt.PhotonSettings(pilot=False, spp_per_map=4)
    ad = AdaptiveSettings(min_spp=4, pass_spp=64, threshold=1e-3)
    a = r.render(48, width=16, height=16, seed=2, photons=ps, adaptive=ad)
    b = r.render(48, width=16, height=16, seed=2, photons=ps, adaptive=ad)
    assert np.array_equal(a.image, b.image) and np.array_equal(a.sample_count, b.sample_count)
    iterations = sorted({m["iteration"] for m in a.stats.photon_maps})
    assert iterations == list(range(len(iterations)))  # every map once, in order
    spp = a.sample_count.mean()
    assert spp > 40 and a.stats.adaptive_rounds >= 2
    # The samples per map as in the uniform phase (4 per pixel), within the rounding of each
    # round's map count (one map per round gave 6 here, 1 + the rounds).
    assert len(iterations) >= spp / 4 - a.stats.adaptive_rounds / 2
