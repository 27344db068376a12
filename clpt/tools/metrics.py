"""Image error metrics against a reference, for the studies (adaptive
sampling, the filter, the speed/accuracy trade-off).

- rmse: root mean squared error over pixels and channels.
- relmse: mean of (x - r)^2 / (r^2 + eps), the relative MSE renderers report
  (eps = 1e-2 keeps dark pixels from dominating).
- relmse_luma: the same on luminance, less the reference's own noise (the
  variance of each reference pixel's mean): (x - r)^2 overestimates the
  squared error by that variance on average, and in the caustics of a
  path-traced reference it can be as large as a good estimator's error.
- relmse_rgb_denoised: relmse less the reference's own noise per channel,
  taken as its luminance noise times (r_c / Y)^2 (the kernels keep only the
  luminance's squares; clpt.adaptive.channel_variance, which the adaptive
  allocation's colour_weight uses too).
- ssim: structural similarity of the luminance (Wang et al. 2004, Gaussian
  window sigma 1.5), on the tone-mapped (clamped sRGB) images, so it judges
  what a viewer sees.
- flip: NVIDIA's FLIP perceptual difference, when the `flip-evaluator`
  package is installed (pip install flip-evaluator); None otherwise.
"""

from __future__ import annotations

import numpy as np

from ..constants import LUMA



def rmse(img, ref) -> float:
    d = np.asarray(img, np.float64) - np.asarray(ref, np.float64)
    return float(np.sqrt((d * d).mean()))


def relmse(img, ref, eps: float = 1e-2) -> float:
    img, ref = np.asarray(img, np.float64), np.asarray(ref, np.float64)
    return float(((img - ref) ** 2 / (ref * ref + eps)).mean())


def relmse_rgb_denoised(img, ref, ref_lum_var, eps: float = 1e-2) -> float:
    """RGB relMSE against ref (H x W x 3) less the reference's own noise,
    each channel's taken as ref_lum_var (per pixel: the variance of the
    reference's luminance mean) times (r_c / Y)^2 (adaptive.channel_variance)."""
    from ..adaptive import channel_variance

    img, ref = np.asarray(img, np.float64), np.asarray(ref, np.float64)
    noise = channel_variance(ref, ref @ LUMA, ref_lum_var)
    return float((((img - ref) ** 2 - noise) / (ref * ref + eps)).mean())


def relmse_luma(img, ref, ref_var=None, eps: float = 1e-2) -> float:
    """Luminance relMSE against ref (both H x W x 3, or N x 3 for a region),
    with ref_var (per pixel: the variance of the reference's luminance mean)
    taken out; without it, the plain luminance relMSE."""
    y = np.asarray(img, np.float64) @ LUMA
    yr = np.asarray(ref, np.float64) @ LUMA
    se = (y - yr) ** 2
    if ref_var is not None:
        se = se - np.asarray(ref_var, np.float64)
    return float((se / (yr * yr + eps)).mean())


def _gauss_blur(x, sigma=1.5, radius=5):
    t = np.arange(-radius, radius + 1)
    k = np.exp(-0.5 * (t / sigma) ** 2)
    k /= k.sum()
    pad = np.pad(x, radius, mode="reflect")
    rows = sum(k[i] * pad[:, i:i + x.shape[1]] for i in range(2 * radius + 1))
    return sum(k[i] * rows[i:i + x.shape[0], :] for i in range(2 * radius + 1))


def _display_luma(img):
    from ..image import linear_to_srgb
    return linear_to_srgb(np.asarray(img, np.float64)) @ LUMA


def ssim(img, ref) -> float:
    x, y = _display_luma(img), _display_luma(ref)
    if min(x.shape) < 11:
        return float("nan")
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    mx, my = _gauss_blur(x), _gauss_blur(y)
    sxx = _gauss_blur(x * x) - mx * mx
    syy = _gauss_blur(y * y) - my * my
    sxy = _gauss_blur(x * y) - mx * my
    s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return float(s.mean())


def flip(img, ref) -> float | None:
    """Mean FLIP error (LDR, on sRGB images), or None without flip-evaluator."""
    try:
        import flip_evaluator
    except ImportError:
        return None
    from ..image import linear_to_srgb
    a = np.ascontiguousarray(linear_to_srgb(np.asarray(ref, np.float64)).astype(np.float32))
    b = np.ascontiguousarray(linear_to_srgb(np.asarray(img, np.float64)).astype(np.float32))
    _, mean, _ = flip_evaluator.evaluate(a, b, "LDR")
    return float(mean)


def all_metrics(img, ref) -> dict:
    out = {"rmse": rmse(img, ref), "relmse": relmse(img, ref), "ssim": ssim(img, ref)}
    f = flip(img, ref)
    if f is not None:
        out["flip"] = f
    return out
