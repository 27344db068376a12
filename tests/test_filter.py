"""The edge-aware cone filter: the kernel against its numpy twin, and the
properties a denoiser must keep."""

import numpy as np
import pytest

import clpt
from clpt.denoise import ConeFilter, FilterSettings, reference_cone_filter
from clpt.metrics import relmse


@pytest.fixture(scope="module")
def cone(probes):
    probe = probes(1)
    return ConeFilter(probe.dctx, probe.program)


def guides(h, w, normal=(0, 0, 1), albedo=0.5, depth=2.0):
    n = np.zeros((h, w, 3), np.float32)
    n[...] = normal
    return n, np.full((h, w, 3), albedo, np.float32), np.full((h, w), depth, np.float32)


def noisy(rng, h, w, level=0.3, sigma=0.05):
    img = (level + rng.normal(0, sigma, (h, w, 3))).astype(np.float32)
    return img, np.full((h, w), sigma ** 2, np.float32)


@pytest.mark.parametrize("settings", [FilterSettings(), FilterSettings(width=1, iterations=1),
                                      FilterSettings(width=3, iterations=2, sigma_luminance=1.0)])
def test_kernel_matches_numpy_twin(cone, settings):
    rng = np.random.default_rng(0)
    h, w = 20, 23
    img, var = noisy(rng, h, w)
    n, a, d = guides(h, w)
    n[:, 12:] = (1, 0, 0)               # a crease
    a[5:9] = (0.8, 0.2, 0.1)            # a painted stripe
    d += rng.uniform(0, 0.5, (h, w)).astype(np.float32)
    img[:, 17:] *= 3                    # a shadow edge
    got = cone(img, var, n, a, d, settings)
    ref = reference_cone_filter(img, var, n, a, d, settings)
    assert np.allclose(got, ref, rtol=2e-4, atol=1e-6)


def test_constant_region_stays_exactly_constant(cone):
    h, w = 16, 16
    img = np.full((h, w, 3), (0.3, 0.5, 0.7), np.float32)
    var = np.random.default_rng(1).uniform(0, 0.1, (h, w)).astype(np.float32)  # whatever the noise estimate
    out = cone(img, var, *guides(h, w), FilterSettings(width=3, iterations=4))
    assert np.array_equal(out, img)


def test_width_zero_is_the_identity(cone):
    rng = np.random.default_rng(2)
    img, var = noisy(rng, 9, 11)
    assert np.array_equal(cone(img, var, *guides(9, 11), FilterSettings(width=0)), img)


@pytest.mark.parametrize("edge", ["normal", "luminance"])
def test_a_sharp_edge_stays_sharp(cone, edge):
    """Two flat regions side by side: each stays flat and the step stays a step."""
    h, w = 12, 20
    img = np.full((h, w, 3), 0.2, np.float32)
    img[:, 10:] = 0.8
    var = np.full((h, w), 1e-6, np.float32)
    n, a, d = guides(h, w)
    if edge == "normal":
        n[:, 10:] = (1, 0, 0)  # perpendicular surfaces: the weight across is exactly 0
    out = cone(img, var, n, a, d, FilterSettings(width=3, iterations=3))
    if edge == "normal":
        assert np.array_equal(out, img)
    else:  # a step of 0.6 where the noise is 0.001: weight e^-(0.6 / 0.006) across
        assert np.abs(out - img).max() < 1e-6


def test_zero_variance_and_black_pixels(cone):
    h, w = 10, 10
    img = np.zeros((h, w, 3), np.float32)
    img[3:6, 3:6] = 1.0
    var = np.zeros((h, w), np.float32)
    n, a, d = guides(h, w)
    a[:, :5] = 0.0  # black surfaces: no albedo to divide by
    n[0] = 0.0      # pixels that saw no surface
    out = cone(img, var, n, a, d, FilterSettings())
    assert np.isfinite(out).all() and out.min() >= 0
    assert np.array_equal(out[7:], img[7:])  # flat black region with no noise: untouched


def test_filter_cuts_error_on_a_noisy_render(device_spec):
    r = clpt.Renderer("cornell_box", device=device_spec, aux=True)
    ref = r.render(2048, width=48, height=48, seed=1).image
    res = r.render(8, width=48, height=48, seed=2, filter=FilterSettings())
    raw, filt = relmse(res.image, ref), relmse(res.filtered, ref)
    assert filt < raw / 3, (raw, filt)
    assert res.aux["normal"].shape == (48, 48, 3) and np.isfinite(res.filtered).all()
