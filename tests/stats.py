"""Statistics for the tests: a chi-square goodness-of-fit test with pooling of
sparse cells, and a mean-within-k-sigma check."""

import math

import numpy as np


def _gammainc_upper(a: float, x: float) -> float:
    """Regularized upper incomplete gamma Q(a, x): series below a + 1, else a
    continued fraction (modified Lentz)."""
    if x <= 0:
        return 1.0
    lg = math.lgamma(a)
    if x < a + 1:
        term = total = 1.0 / a
        ap = a
        for _ in range(10000):
            ap += 1
            term *= x / ap
            total += term
            if abs(term) < abs(total) * 1e-15:
                break
        return max(0.0, 1.0 - total * math.exp(-x + a * math.log(x) - lg))
    b = x + 1 - a
    c = 1e300
    d = 1 / b
    h = d
    for i in range(1, 10000):
        an = -i * (i - a)
        b += 2
        d = an * d + b
        d = 1e-300 if abs(d) < 1e-300 else d
        c = b + an / c
        c = 1e-300 if abs(c) < 1e-300 else c
        d = 1 / d
        delta = d * c
        h *= delta
        if abs(delta - 1) < 1e-15:
            break
    return math.exp(-x + a * math.log(x) - lg) * h


def chi2_sf(stat: float, dof: int) -> float:
    return _gammainc_upper(dof / 2.0, stat / 2.0)


def chi2_test(observed, expected, min_expected: float = 5.0):
    """p-value that `observed` counts come from `expected` (same total).
    Cells expected below min_expected are pooled together, as in Mitsuba's
    chi-square tests. Returns (p_value, statistic, degrees of freedom)."""
    obs = np.asarray(observed, dtype=np.float64).ravel()
    exp = np.asarray(expected, dtype=np.float64).ravel()
    order = np.argsort(exp)
    obs, exp = obs[order], exp[order]
    small = exp < min_expected
    o_pool, e_pool = obs[small].sum(), exp[small].sum()
    obs, exp = obs[~small], exp[~small]
    if e_pool >= min_expected:
        obs, exp = np.append(obs, o_pool), np.append(exp, e_pool)
    elif o_pool > 0 and len(exp):
        obs[0] += o_pool
        exp[0] += e_pool
    stat = float(((obs - exp) ** 2 / exp).sum())
    dof = len(exp) - 1
    return chi2_sf(stat, dof), stat, dof


# Significance level per test, Sidak-corrected by each test for its number of trials.
ALPHA = 0.01


def sidak(alpha: float, trials: int) -> float:
    return 1.0 - (1.0 - alpha) ** (1.0 / trials)


def assert_mean_within(samples_mean, expected, sigma_of_mean, k=5.0, what="mean"):
    err = abs(float(samples_mean) - float(expected))
    assert err <= k * float(sigma_of_mean), (
        f"{what}: {samples_mean:.6g} differs from {expected:.6g} by {err:.3g} "
        f"= {err / max(sigma_of_mean, 1e-300):.1f} sigma (allowed {k})")


LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def compare_to_reference(res, ref):
    """A render (a clpt RenderResult) against a Mitsuba reference stored by
    tests/mitsuba_measure.py --reference: (largest relative error of the
    image's mean colour, z-scores of the reference's luminance blocks against
    the render's, from both renders' noise)."""
    mean_err = np.abs(res.image.reshape(-1, 3).mean(axis=0) / np.array(ref["mean_rgb"]) - 1).max()
    b, (h, w) = ref["block"], res.image.shape[:2]

    def blocks(x):
        return x.reshape(h // b, b, w // b, b).sum(axis=(1, 3)) / b ** 2

    lum, var = blocks(res.image @ LUMINANCE), blocks(res.lum_var / res.sample_count) / b ** 2
    z = (lum - np.array(ref["block_luminance"])) / np.sqrt(var + np.array(ref["block_luminance_var"]))
    return mean_err, z


def assert_matches_reference(res, ref, mean_tol=0.005, z_max=4.0):
    """The check every Mitsuba-reference scene makes: the image's mean colour
    within mean_tol of the reference's and no block beyond z_max sigma of
    both renders' noise (compare_to_reference)."""
    mean_err, z = compare_to_reference(res, ref)
    assert mean_err < mean_tol, f"image mean off by {mean_err:.2%}"
    assert np.abs(z).max() < z_max, f"a block is {np.abs(z).max():.1f} sigma off:\n{np.round(z, 1)}"


def ring_z(res, ref):
    """The z-score of the image's outermost ring of pixels (mean luminance)
    against the reference's ("ring_luminance")."""
    h, w = res.image.shape[:2]
    ring = np.ones((h, w), dtype=bool)
    ring[1:-1, 1:-1] = False
    lum = (res.image @ LUMINANCE)[ring].mean()
    var = (res.lum_var / res.sample_count)[ring].sum() / ring.sum() ** 2
    return (lum - ref["ring_luminance"]) / math.sqrt(var + ref["ring_luminance_var"])
