"""The stratified sampler (kernels/sampler.h) in renders, against
independent numbers: the same image in expectation, with less noise where
the camera's position and the first vertex's decisions make a pixel's
variance (edges, the lamp's soft shadows, the walls' direct light).

Both are measured from the spread of whole renders over seeds, not from
the renders' own per-pixel variances: with stratified samples a pixel's
sample variance over-states its error, which is the point."""

import numpy as np
import pytest

import clpt

LUMA = np.array([0.2126, 0.7152, 0.0722])
SIZE, SPP, SEEDS = 24, 16, 32


@pytest.fixture(scope="module")
def seed_renders(device_spec):
    out = {}
    for sampler in ("stratified", "independent"):
        r = clpt.Renderer("cornell_box", device=device_spec, sampler=sampler)
        out[sampler] = np.stack([r.render(SPP, width=SIZE, height=SIZE, max_depth=3, seed=100 + s).image @ LUMA
                                 for s in range(SEEDS)])
    return out


def test_stratified_and_independent_agree(seed_renders):
    """Means over 32 seeds, in 4x4-pixel blocks, differ by their standard errors (seed to seed) only."""
    blocks = {k: v.reshape(SEEDS, SIZE // 4, 4, SIZE // 4, 4).mean((2, 4)).reshape(SEEDS, -1)
              for k, v in seed_renders.items()}
    s, i = blocks["stratified"], blocks["independent"]
    z = (s.mean(0) - i.mean(0)) / np.sqrt(s.var(0, ddof=1) / SEEDS + i.var(0, ddof=1) / SEEDS)
    assert np.all(np.isfinite(z))
    # 36 blocks: |z| beyond 4 has probability below 0.3% for any of them; the rms of 36 standard normals
    # is within 1 +- 0.35 at 3 sigma (Student's t with 31 dof widens it by a few percent)
    assert np.abs(z).max() < 4.0, np.abs(z).max()
    assert np.sqrt(np.mean(z ** 2)) < 1.4, np.sqrt(np.mean(z ** 2))


def test_stratified_is_less_noisy(seed_renders):
    """The seed-to-seed variance, summed over the image, is lower. At 16 spp it is 0.65-0.7 times
    the independent sampler's on the Cornell box (bench-denoise: raw relMSE 12.5e-3 against 18.5e-3 at
    128x128); its estimate from 32 seeds of 576 pixels is good to a few percent."""
    var = {k: v.var(0, ddof=1).sum() for k, v in seed_renders.items()}
    ratio = var["stratified"] / var["independent"]
    assert ratio < 0.85, ratio


def test_sampler_is_a_build_option(device_spec):
    r = clpt.Renderer("cornell_box", device=device_spec, sampler="independent")
    assert "sampler=independent" in r.features.describe()
    assert r.features.defines()["CLPT_STRATIFIED_DEPTH"] == 0
    assert clpt.Renderer("cornell_box", device=device_spec).features.defines()["CLPT_STRATIFIED_DEPTH"] == 1
    with pytest.raises(ValueError, match="sampler must be one of stratified, independent"):
        clpt.Renderer("cornell_box", device=device_spec, sampler="sobol")
