"""The edge-aware cone filter (kernels/filter.cl), run from the host.

The image is divided by the first-hit albedo (demodulated), filtered in
`iterations` a-trous passes of a cone kernel of `width` pixels (steps 1, 2,
4, ...), with weights cut where normals, depths, albedos or values (beyond
their noise) differ, and multiplied by the albedo again. A numpy twin of the
kernel (`reference_cone_filter`) is there for the tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from .constants import LUMA, LUMA_WEIGHTS
from .program import note_time

ALBEDO_FLOOR = 1e-3


@dataclass(frozen=True)
class FilterSettings:
    width: int = 2               # cone radius (pixels) of each pass; 0: no filtering
    iterations: int = 3          # a-trous passes, steps 1, 2, 4, ...
    sigma_normal: float = 32.0   # exponent of the normals' cosine
    sigma_depth: float = 0.1     # relative depth change per pixel of distance that costs a factor e
    sigma_albedo: float = 0.1
    sigma_luminance: float = 4.0  # value differences, in standard deviations of the noise
    interval: int = 0            # filter the preview every N passes (0: only the final image)

    def check(self):
        from .scene import SceneError
        if self.width < 0 or self.iterations < 1:
            raise SceneError("filter: width must be >= 0 and iterations >= 1")
        for k in ("sigma_normal", "sigma_depth", "sigma_albedo", "sigma_luminance"):
            if not getattr(self, k) > 0:
                raise SceneError(f"filter: {k} must be > 0")
        return self


def demodulate(color, var, albedo):
    """Colour / albedo (where the albedo is not black), and its variance."""
    alb = np.where(albedo > ALBEDO_FLOOR, albedo, 1.0)
    lum_alb = np.maximum(alb @ LUMA, ALBEDO_FLOOR)
    return color / alb, var / lum_alb ** 2, alb


class ConeFilter:
    """The filter's kernel and buffers on one device."""

    def __init__(self, dctx, program):
        self.dctx = dctx
        self.kernel = cl.Kernel(program, "cone_filter")
        self.kernel_times = {}  # "cone_filter" -> device seconds per launch

    def __call__(self, color, var, normal, albedo, depth, settings: FilterSettings):
        """Filtered colour (H x W x 3 float32) from the guides (H x W arrays)."""
        h, w = color.shape[:2]
        if settings.width == 0:
            return color.astype(np.float32).copy()
        irr, v, alb = demodulate(color.astype(np.float64), var.astype(np.float64), albedo.astype(np.float64))
        ctx, q = self.dctx.context, self.dctx.queue
        mf = cl.mem_flags
        n = h * w

        def buf4(a3, w4=None):
            x = np.zeros((n, 4), np.float32)
            x[:, :3] = a3.reshape(n, 3)
            if w4 is not None:
                x[:, 3] = w4.reshape(n)
            return cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=x)

        c = [buf4(irr), cl.Buffer(ctx, mf.READ_WRITE, n * 16)]
        vb = [cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=v.astype(np.float32).reshape(n)),
              cl.Buffer(ctx, mf.READ_WRITE, n * 4)]
        nb = buf4(normal)
        ab = buf4(albedo, depth)
        src = 0
        events = []
        for it in range(settings.iterations):
            events.append(self.kernel(q, (n,), None, c[src], vb[src], nb, ab, np.uint32(w), np.uint32(h),
                        np.int32(settings.width), np.int32(1 << it), np.float32(settings.sigma_normal),
                        np.float32(settings.sigma_depth), np.float32(settings.sigma_albedo),
                        np.float32(settings.sigma_luminance), c[1 - src], vb[1 - src]))
            src = 1 - src
        out = np.empty((n, 4), np.float32)
        cl.enqueue_copy(q, out, c[src])
        q.finish()
        for ev in events:
            note_time(self.kernel_times, "cone_filter", ev)
        return (out[:, :3].reshape(h, w, 3) * alb).astype(np.float32)


def reference_cone_filter(color, var, normal, albedo, depth, settings: FilterSettings):
    """numpy twin of ConeFilter (slow; for tests on small images)."""
    h, w = color.shape[:2]
    if settings.width == 0:
        return color.astype(np.float32).copy()
    irr, v, alb = demodulate(color.astype(np.float64), var.astype(np.float64), albedo.astype(np.float64))
    c = irr.astype(np.float32)
    v = v.astype(np.float32)
    has = (normal * normal).sum(-1) > 0
    wr, wg, wb = LUMA_WEIGHTS
    lum = lambda a: wr * a[..., 0] + wg * a[..., 1] + wb * a[..., 2]  # noqa: E731  (float32, as the kernel)
    for it in range(settings.iterations):
        step = 1 << it
        acc = np.zeros_like(c)
        wsum = np.ones((h, w), np.float32)
        w2v = v.copy()
        lp = lum(c)
        r_ = settings.width
        for dy in range(-r_, r_ + 1):
            for dx in range(-r_, r_ + 1):
                if dx == 0 and dy == 0:
                    continue
                r = np.sqrt(dx * dx + dy * dy)
                ws = 1 - r / (r_ + 1)
                if ws <= 0:
                    continue
                ys, xs = np.mgrid[0:h, 0:w]
                qy, qx = ys + dy * step, xs + dx * step
                ok = (qy >= 0) & (qy < h) & (qx >= 0) & (qx < w)
                qy, qx = np.clip(qy, 0, h - 1), np.clip(qx, 0, w - 1)
                wt = np.full((h, w), ws, np.float32)
                hq = has[qy, qx]
                ok &= has == hq
                cosn = np.maximum((normal * normal[qy, qx]).sum(-1), 0.0)
                wt = np.where(has, wt * cosn ** int(settings.sigma_normal), wt)
                da = albedo - albedo[qy, qx]
                wt = wt * np.exp(-(da * da).sum(-1) / settings.sigma_albedo ** 2)
                wt = wt * np.exp(-np.abs(depth - depth[qy, qx]) /
                                 (settings.sigma_depth * np.maximum(depth, 1e-6) * r * step + 1e-12))
                wt = wt * np.exp(-np.abs(lp - lp[qy, qx]) / (settings.sigma_luminance * np.sqrt(v + v[qy, qx]) + 1e-6))
                wt = np.where(ok & (wt > 0), wt, 0.0).astype(np.float32)
                acc += wt[..., None] * (c[qy, qx] - c)
                wsum += wt
                w2v += wt * wt * v[qy, qx]
        c = c + acc / wsum[..., None]
        v = w2v / (wsum * wsum)
    return (c * alb).astype(np.float32)
