"""What adaptive sampling's counts are worth, apart from time: uniform's
summed RGB relative variance over that of an adaptive render's counts, for
as many samples.

    python tests/bench_allocation.py cornell_box_caustics --device intel

Renders --renders uniform images of --spp-each samples with their own seeds;
each pixel's per-sample variance per channel comes from their spread, and
the pixels' means from their mean. With S_i^2 = sum_c var_c / (m_c^2 + eps)
(RGB relMSE's weight, eps 1e-2 as clpt compare), uniform counts give
P sum S_i^2 / N and counts n_i give sum S_i^2 / n_i: the gain printed is
their ratio at equal N (and the same for luminance, the film's own
variance). The ceiling is the best counts' (n_i proportional to S_i). Then
adaptive renders of each --adaptive-spp (another seed) give their counts'
gain. No reference and no timing: the counts alone, so that changes to the
allocation can be compared without the noise of equal-time runs (an
adaptive sample's extra cost is not in it: tests/bench_adaptive_merge.py
measures at equal CPU time).

The ceiling from the renders' own spread over-states what any allocation
can reach: the counts proportional to S_i and the S_i they are judged by
share the same noise. So the renders are also split in two halves (even
and odd seeds): counts from one half's S_i (the pixel's own, and blended
with its 3x3 neighbourhood as allocate_error does), judged by the other
half's S_i^2, both ways, averaged (no pixel below 1/32 of the mean, as
min_spp's 32 of 1024). That under-states the best counts a
little (each half is noisier than all the renders), so the attainable gain
lies between it and the ceiling. The counts the renders' film variance
gives (each pixel's own per-sample luminance variance, weighed by colour
and blended as allocate_error does, from all the renders' samples) are
judged the same way: what allocate_error would reach if it knew the
film's variance exactly.
"""

from __future__ import annotations

import warnings

import numpy as np
from bench_adaptive_merge import scene_parser


def main(argv=None) -> int:
    ap = scene_parser(__doc__)
    ap.add_argument("--renders", type=int, default=16)
    ap.add_argument("--spp-each", type=int, default=64)
    ap.add_argument("--adaptive-spp", default="256,1024")
    ap.add_argument("--threshold", type=float, default=1e-3)
    ap.add_argument("--photons", choices=("scene", "off"), default="scene")
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")

    from clpt.adaptive import ERROR_FLOOR, AdaptiveSettings, _neighbourhood_blend, relative_error
    from clpt.constants import LUMA
    from clpt.loading import load_scene
    from clpt.render import Renderer

    r = Renderer(load_scene(a.scene), device=a.device, **({"photons": False} if a.photons == "off" else {}))
    kw = dict(width=a.width, height=a.height)
    imgs, lum_var = [], []
    for k in range(a.renders):
        res = r.render(a.spp_each, seed=100 + k, **kw)
        imgs.append(res.image.astype(np.float64))
        lum_var.append(res.lum_var.astype(np.float64))
    imgs = np.array(imgs)
    mean = imgs.mean(axis=0)
    eps = ERROR_FLOOR ** 2
    S2 = (imgs.var(axis=0, ddof=1) * a.spp_each / (mean * mean + eps)).sum(axis=-1).ravel()
    lum = mean @ LUMA
    s2 = (np.mean(lum_var, axis=0) / (lum * lum + eps)).ravel()
    P = S2.size

    def gain(w, n):  # uniform's summed relative variance over n's, at equal samples
        return float(P * w.sum() / (n.sum() * (w / n).sum()))

    print(f"{a.scene}, {a.width}x{a.height}, {a.renders} x {a.spp_each} spp uniform: ceiling RGB "
          f"{P * S2.sum() / np.sqrt(S2).sum() ** 2:.3f}, luminance {P * s2.sum() / np.sqrt(s2).sum() ** 2:.3f}")
    shape = (a.height, a.width)

    def rel_var(part):  # each pixel's S_i^2 from a subset of the renders (their own mean)
        m = part.mean(axis=0)
        return (part.var(axis=0, ddof=1) * a.spp_each / (m * m + eps)).sum(axis=-1).ravel()

    def blended(s):
        return _neighbourhood_blend(s.reshape(shape)).ravel()

    def floored(n):  # no pixel below 1/32 of the mean: AdaptiveSettings' min_spp at 1024 spp
        n = n / max(n.mean(), 1e-300)
        return np.maximum(n, 1.0 / 32)

    halves = (rel_var(imgs[0::2]), rel_var(imgs[1::2]))
    own = np.mean([gain(halves[1 - k], floored(np.sqrt(halves[k]))) for k in (0, 1)])
    blend = np.mean([gain(halves[1 - k], floored(blended(np.sqrt(halves[k])))) for k in (0, 1)])
    film = relative_error(lum.reshape(shape), np.mean(lum_var, axis=0), 1.0, mean.reshape(shape + (3,)))
    film_n = floored(_neighbourhood_blend(film).ravel())
    film_gain = np.mean([gain(h, film_n) for h in halves])
    print(f"cross-validated (counts from one half's spread, judged by the other's), RGB: the pixel's own "
          f"{own:.3f}, blended {blend:.3f}; the film variance's counts (blended, colour) {film_gain:.3f}")
    for spp in (int(x) for x in a.adaptive_spp.split(",")):
        res = r.render(spp, seed=7, **kw, adaptive=AdaptiveSettings(threshold=a.threshold))
        n = res.sample_count.astype(np.float64).ravel()
        print(f"adaptive {spp} spp: its counts' gain RGB {gain(S2, n):.3f} (by each half's spread "
              f"{gain(halves[0], n):.3f}, {gain(halves[1], n):.3f}), luminance {gain(s2, n):.3f} "
              f"({res.stats.adaptive_rounds} rounds, {n.min():.0f}-{n.max():.0f} samples a pixel)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
