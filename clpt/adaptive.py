"""Adaptive sample allocation: which pixels get the next samples.

The host decides from per-pixel statistics (means, variances, counts) that
the kernels accumulate; the kernels then sample only the listed pixels, each
continuing its own sample sequence, so an adaptive render stays reproducible.
Pure numpy, over whole images: no loops over pixels.

Two schemes:

- "error" (the default): a pixel's relative error is the standard error of
  its mean luminance over the mean (over sqrt(mean^2 + 0.1^2), as relMSE
  weighs dark pixels), weighed per colour channel as RGB relMSE weighs it
  (colour_weight), and blended with its 3x3 neighbourhood's (the root of
  the mean of its own square and the neighbourhood's mean square) so that a
  pixel whose few samples happened to agree is not stopped too early. Pixels above the
  noise threshold get samples in proportion to how far above it they are,
  until every pixel is below it, or the sample budget or time runs out.
- "paper" (the paper's section 6): after the minimum, each pixel is compared
  with its 8 neighbours; one that differs from most of them ("discrepant")
  keeps full sampling and full depth, the others get a quarter of the
  samples and, if reduce_depth, half the path depth (a deliberate bias the
  paper accepts for speed), or stop if mode is "stop". Two pixels differ
  when their means are apart by more than `disagreement` of the larger and
  by more than 3 standard errors, so that noise alone is no discrepancy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .constants import LUMA
from .errors import SettingsError

DARK_FLOOR = 1e-3  # paper scheme: luminance below which differences are measured against this
# Error scheme: a pixel's standard error is measured against sqrt(mean^2 + ERROR_FLOOR^2), the
# square root of the weight relMSE gives its squared error (luminance squared plus 1e-2), so
# that the samples go where they lower the image's relMSE most. Measured against the mean
# alone (floored at 1e-3), the dark pixels' errors counted up to a hundred times more than
# relMSE counts them: on the caustics box at equal time they drew samples from the
# mid-grey walls that dominate its error, and adaptive sampling lost to uniform.
ERROR_FLOOR = 0.1


@dataclass(frozen=True)
class AdaptiveSettings:
    scheme: str = "error"          # "error" or "paper"
    min_spp: int = 32              # uniform samples before any decision
    threshold: float = 0.02        # error scheme: target relative error of a pixel
    pass_spp: int = 16             # most samples per adaptive pass (error scheme: or the pixel's count, if more)
    disagreement: float = 0.1      # paper scheme: relative luminance difference that counts as disagreeing
    reduce_depth: bool = True      # paper scheme: half depth for the pixels that agree with their neighbours
    paper_mode: str = "reduce"     # paper scheme: "reduce" or "stop" the agreeing pixels

    def check(self):
        if self.scheme not in ("error", "paper"):
            raise SettingsError(f"adaptive: scheme must be 'error' or 'paper' (got {self.scheme!r})")
        for key in ("min_spp", "pass_spp"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v < 2 ** 32:
                raise SettingsError(f"adaptive: {key} must be an integer from 1 to 2^32 - 1 (got {v!r})")
        for key in ("threshold", "disagreement"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or \
                    not (math.isfinite(v) and v > 0):
                raise SettingsError(f"adaptive: {key} must be a number > 0 (got {v!r})")
        if self.paper_mode not in ("reduce", "stop"):
            raise SettingsError(f"adaptive: paper_mode must be 'reduce' or 'stop' (got {self.paper_mode!r})")
        return self


def _neighbourhood_blend(a: np.ndarray) -> np.ndarray:
    """sqrt((a^2 + the 3x3 mean of a^2) / 2), edges repeated. The largest of
    the 3x3 (what allocate_error took before) spread each noisy pixel's error
    over its eight neighbours: on the caustics box it gave the best
    allocation's counts 7-9% less of its gain over uniform sampling."""
    sq = a * a
    p = np.pad(sq, 1, mode="edge")
    h, w = a.shape
    box = np.sum([p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)], axis=0) / 9.0
    return np.sqrt(0.5 * (sq + box))


def channel_variance(mean_rgb: np.ndarray, mean_lum: np.ndarray, lum_var) -> np.ndarray:
    """Each channel's variance (a last axis of 3) where only the luminance's is
    known, as the luminance's scaled by the channel's share of the mean:
    lum_var (m_c / Y)^2. Exact where a pixel's samples are its colour times
    one random factor; colour_weight and metrics.relmse_rgb_denoised assume it."""
    y2 = np.maximum(mean_lum * mean_lum, 1e-30)[..., None]
    return np.asarray(lum_var, np.float64)[..., None] * (mean_rgb * mean_rgb / y2)


def colour_weight(mean_rgb: np.ndarray, mean_lum: np.ndarray) -> np.ndarray:
    """What a unit of a pixel's luminance variance weighs in RGB relMSE, the
    mean over channels of var_c / (m_c^2 + ERROR_FLOOR^2), each channel's
    noise taken as the luminance's scaled by the channel's share of the mean
    (channel_variance): the kernels keep only the luminance's squares.
    A grey pixel weighs 1 / (Y^2 + ERROR_FLOOR^2), as relative_error has it
    without colours; a saturated one otherwise (a red (0.6, 0.02, 0.02)
    about half as much: its noise is in its red channel, its green and blue
    all but noiseless)."""
    return (channel_variance(mean_rgb, mean_lum, 1.0) / (mean_rgb * mean_rgb + ERROR_FLOOR * ERROR_FLOOR)).mean(axis=-1)


def relative_error(mean_lum: np.ndarray, lum_var: np.ndarray, count: np.ndarray, mean_rgb=None) -> np.ndarray:
    """Standard error of each pixel's mean luminance, relative to the mean
    (to sqrt(mean^2 + ERROR_FLOOR^2): relMSE's weighting of dark pixels);
    with mean_rgb (the pixels' mean colours, a last axis of 3), as RGB relMSE
    weighs it (colour_weight)."""
    v = np.maximum(lum_var, 0.0) / np.maximum(count, 1.0)
    if mean_rgb is not None:
        return np.sqrt(v * colour_weight(np.asarray(mean_rgb, np.float64), mean_lum))
    return np.sqrt(v) / np.sqrt(mean_lum * mean_lum + ERROR_FLOOR * ERROR_FLOOR)


def allocation_ceiling(mean_lum, lum_var) -> float:
    """The most any allocation of the same number of samples can lower the
    summed relative variance sum_i v_i / (n_i (m_i^2 + ERROR_FLOOR^2)) below
    uniform sampling's, given each pixel's per-sample luminance variance v_i
    and mean m_i (e.g. from a uniform render and a reference): with s_i =
    sqrt(v_i / (m_i^2 + ERROR_FLOOR^2)), uniform gives P sum s_i^2 / N and
    the best counts (n_i proportional to s_i) give (sum s_i)^2 / N, so the
    ceiling is P sum s_i^2 / (sum s_i)^2 (1 when every pixel is alike). It
    assumes samples of equal cost and independent pixel errors, so it bounds
    what allocate_error can gain on luminance relMSE: no estimate of the
    s_i from a few samples, and no extra cost per adaptive sample, does
    better."""
    s = relative_error(np.asarray(mean_lum, np.float64), np.asarray(lum_var, np.float64), 1.0).ravel()
    total = float(s.sum())
    return float(s.size * (s * s).sum() / (total * total)) if total > 0 else 1.0


def allocate_error(mean_lum, lum_var, count, settings: AdaptiveSettings, budget_left: int, mean_rgb=None):
    """Samples per pixel for the next pass (error scheme), at most budget_left in all;
    the errors weighed by colour where mean_rgb is given (relative_error).

    A pixel above the threshold wants n ((e / t)^2 - 1) more samples (what
    would bring it to the threshold if its error falls as 1/sqrt(n)). When the
    wants exceed the budget, the pixels above the threshold are steered to the
    counts that minimise their summed relative variance (proportional to their
    relative per-sample deviations), so the noisiest regions get the most
    samples even when no pixel can reach the threshold; no pixel gets more than max(pass_spp, its count) in one pass
    (at most doubling its samples, so the passes are few and long enough to
    keep the device busy, yet each sees what the last achieved)."""
    own = relative_error(mean_lum, lum_var, count, mean_rgb)
    err = _neighbourhood_blend(own)
    need = err > settings.threshold
    want = np.where(need, np.maximum(np.ceil(count * ((err / settings.threshold) ** 2 - 1.0)), 1.0), 0.0)
    total = want.sum()
    if budget_left <= 0 or total == 0:
        return np.zeros(want.shape, dtype=np.int64), err
    if total > budget_left:
        # The counts that minimise the summed relative variance of these pixels
        # for the samples there will be: n_i proportional to each one's relative
        # per-sample deviation (sum s_i^2 / n_i under sum n_i = N).
        dev = np.where(need, err * np.sqrt(np.maximum(count, 1.0)), 0.0)
        target = dev * ((count[need].sum() + budget_left) / max(dev.sum(), 1e-300))
        want = np.where(need, np.maximum(target - count, 0.0), 0.0)
        if want.sum() > budget_left:
            want = want * (budget_left / want.sum())
    want = np.minimum(want, np.maximum(count, settings.pass_spp))
    share = np.floor(want).astype(np.int64)
    # What flooring left over goes one sample each to the worst pixels (own error breaks ties).
    rest = int(min(budget_left, np.ceil(want).sum()) - share.sum())
    if rest > 0:
        flat = share.ravel()
        flat[_worst(np.flatnonzero(want.ravel() > flat), err.ravel(), own.ravel(), rest)] += 1
        share = flat.reshape(want.shape)
    return share, err


def _worst(cand: np.ndarray, err: np.ndarray, own: np.ndarray, k: int) -> np.ndarray:
    """The k of the pixels cand (ascending) with the largest err, ties broken
    by the larger own error, then by the lower index: the first k of a
    stable sort by (-err, -own), found by partitioning (a full lexsort of
    the image took 3.3 ms of a round's 11 at 128x128)."""
    if k >= len(cand):
        return cand
    e = err[cand]
    kth = np.partition(e, len(e) - k)[len(e) - k]  # the k-th largest
    sure = cand[e > kth]
    ties = cand[e == kth]
    ties = ties[np.argsort(-own[ties], kind="stable")][:k - len(sure)]
    return np.concatenate([sure, ties])


def discrepant(mean_lum: np.ndarray, disagreement: float, std_err: np.ndarray | None = None) -> np.ndarray:
    """Pixels whose luminance differs from most of their 8 neighbours, by more
    than `disagreement` relatively and (given std_err) more than its noise."""
    h, w = mean_lum.shape
    p = np.pad(mean_lum, 1, mode="edge")
    se = np.zeros((h, w)) if std_err is None else std_err
    pse = np.pad(se, 1, mode="edge")
    votes = np.zeros((h, w), dtype=np.int32)
    for dy in range(3):
        for dx in range(3):
            if dy == 1 and dx == 1:
                continue
            q = p[dy:dy + h, dx:dx + w]
            diff = np.abs(mean_lum - q)
            scale = np.maximum(np.maximum(mean_lum, q), DARK_FLOOR)
            noise = 3.0 * np.sqrt(se * se + pse[dy:dy + h, dx:dx + w] ** 2)
            votes += (diff > disagreement * scale) & (diff > noise)
    return votes >= 5


def allocate_paper(mean_lum, settings: AdaptiveSettings, max_depth: int, std_err=None):
    """Samples and depth limit per pixel for the next pass (paper's scheme)."""
    d = discrepant(mean_lum, settings.disagreement, std_err)
    full = settings.pass_spp
    if settings.paper_mode == "stop":
        n = np.where(d, full, 0)
    else:
        n = np.where(d, full, max(1, full // 4))
    depth = np.full(mean_lum.shape, max_depth, dtype=np.int64)
    if settings.reduce_depth and settings.paper_mode == "reduce":
        depth = np.where(d, max_depth, max_depth // 2)
    return n.astype(np.int64), depth, d


def sample_map_image(count: np.ndarray) -> np.ndarray:
    """A heat map (black - blue - red - yellow - white) of samples per pixel,
    as linear RGB in [0, 1], scaled to the largest count."""
    t = count.astype(np.float64) / max(float(count.max()), 1.0)
    stops = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
    colours = np.array([[0, 0, 0], [0.05, 0.1, 0.8], [0.85, 0.1, 0.1], [1.0, 0.85, 0.0], [1, 1, 1]])
    rgb = np.stack([np.interp(t, stops, colours[:, c]) for c in range(3)], axis=-1)
    # The colours are display values: undo the sRGB curve the image writer applies.
    return np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4).astype(np.float32)
