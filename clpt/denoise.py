"""Denoisers: the edge-aware cone filter (kernels/filter.cl), and Intel Open
Image Denoise (OIDN) when pyoidn is installed (pip install 'clpt[oidn]').

Both are fed from the renderer's feature buffers (render.py, CLPT_AUX):
per pixel the normal, albedo and depth of the first surface seen (by
default, aux_specular="glass", mirrors as surfaces of albedo kr and what is
seen through glass: the first vertex that is not glass, the glass's
throughput folded into its albedo; "surface": glass too as a surface of
albedo kr + kt; "through": the first non-delta vertex seen through both),
the share of samples that see an emitter directly or through
mirrors and glass (where it is most, the pixel is flagged; an emitter that is
the feature vertex gives its own colour as albedo), the emission seen so, and
the photon map's caustic part. Both leave that emission out and add it back
where the pixel's samples confirm it (`kept_emission`: a lamp, its
reflections and refractions; not a lamp that one sample in sixteen met
through the edge of a glass ball, which is noise and is filtered).

The cone filter also leaves out the caustics where they are concentrated
(already a density estimate; filtering them again spreads them); the few
photons scattered over the walls are filtered with the rest
(`kept_caustic_share`). The rest is divided by the albedo (demodulated),
its fireflies are clamped (filter.cl: a pixel brighter than all 8
neighbours by more than `firefly_k` standard errors, unless its own samples
confirm it to `confirm_k` of its own standard errors), and `iterations`
a-trous passes of a cone kernel of `width` pixels (steps 1, 2, 4, ...)
smooth it where normals, depths, albedos, emitter flags and values (their
3x3 means, beyond the pixel's noise) agree; the last pass (`fit_last`) fits
a plane in screen position to its taps instead of averaging them, so a
gradient (a wall's falloff, a soft shadow) is not flattened and its value
test can be looser. A numpy twin (`reference_cone_filter`) is there for the tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .constants import LUMA, LUMA_WEIGHTS, dot_rows
from .errors import SceneError, SettingsError

ALBEDO_FLOOR = 1e-3
MAX_WIDTH = 16
OIDN_AUX = ("clean", "noisy", "none")


@dataclass(frozen=True)
class FilterSettings:
    width: int = 1               # cone radius (pixels) of each pass; 0: no filtering; at most MAX_WIDTH
    iterations: int = 3          # a-trous passes, steps 1, 2, 4, ... (passes past the image's size do nothing)
    sigma_normal: int = 32       # exponent of the normals' cosine, 1 to 127
    sigma_depth: float = 0.1     # relative depth change per pixel of distance that costs a factor e
    sigma_albedo: float = 0.1
    sigma_luminance: float = 2.5  # differences of 3x3-smoothed values, in standard errors of the pixel's noise
    guide_floor: float = 0.3     # least guide weight of a tap (edge pixels, whose guides are mixtures)
    fit_last: bool = True        # the last pass fits a plane (in screen position) to its taps instead of
                                 # averaging them: illumination gradients (the walls' falloff, soft shadows) are
                                 # not flattened, so its taps may differ more
    fit_sigma_luminance: float = 3.5  # ... its sigma_luminance
    fit_guide_floor: float = 0.0      # ... and guide_floor
    firefly_k: float = 3.0       # clamp pixels above all 8 neighbours by this many standard errors; 0: off
    confirm_k: float = 2.0       # a bright value the pixel's own samples confirm to this many standard errors
                                 # is kept (lamps seen directly or in mirrors and glass; the clamp's exemption)
    keep_caustics: bool = True   # add the photon map's caustics back unfiltered (where they are concentrated)
    caustic_share: float = 0.2   # ... where they bring at least this share of the 3x3's luminance (a ramp from half
                                 # to 1.5 times it); elsewhere (the few photons scattered over the walls, noise) they
                                 # are filtered with the rest; 0: all of them kept out
    interval: int = 0            # filter the preview every N passes (0: only the final image)

    def check(self):
        if isinstance(self.width, bool) or not isinstance(self.width, (int, np.integer)) \
                or not 0 <= self.width <= MAX_WIDTH:
            raise SettingsError(f"filter: width must be an integer from 0 to {MAX_WIDTH} (got {self.width!r})")
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, (int, np.integer)) \
                or self.iterations < 1:
            raise SettingsError(f"filter: iterations must be an integer >= 1 (got {self.iterations!r})")
        if isinstance(self.sigma_normal, bool) or not isinstance(self.sigma_normal, (int, np.integer)) \
                or not 1 <= self.sigma_normal <= 127:
            raise SettingsError(f"filter: sigma_normal must be an integer from 1 to 127 (got {self.sigma_normal!r})")
        for k in ("sigma_depth", "sigma_albedo", "sigma_luminance", "fit_sigma_luminance"):
            if not getattr(self, k) > 0:
                raise SettingsError(f"filter: {k} must be > 0")
        if not self.firefly_k >= 0:
            raise SettingsError("filter: firefly_k must be >= 0")
        if not self.confirm_k >= 0:
            raise SettingsError("filter: confirm_k must be >= 0")
        if not 0 <= self.caustic_share <= 1:
            raise SettingsError("filter: caustic_share must be from 0 to 1")
        return self

    def passes(self, width: int, height: int) -> int:
        """The passes that do something: steps up to the image's size."""
        size = max(width, height, 1)
        return min(int(self.iterations), max(1, int(np.ceil(np.log2(size))) + 1))


@dataclass(frozen=True)
class OidnSettings:
    """Intel Open Image Denoise, fed colour and (aux) the feature buffers:
    "clean" prefilters albedo and normal with OIDN first and tells it they
    are clean; "noisy" passes them as they are; "none" gives colour only."""

    aux: str = "clean"
    quality: str = "high"        # "high", "balanced" or "fast"
    interval: int = 0

    def check(self):
        if self.aux not in OIDN_AUX:
            raise SettingsError(f"oidn: aux must be one of {', '.join(OIDN_AUX)} (got {self.aux!r})")
        if self.quality not in ("high", "balanced", "fast"):
            raise SettingsError(f"oidn: quality must be high, balanced or fast (got {self.quality!r})")
        oidn_module()
        return self


def oidn_module():
    """pyoidn, or a one-line error saying how to get it."""
    try:
        import pyoidn  # optional (clpt[oidn]): imported when asked for
    except ImportError:
        raise SceneError("the OIDN denoiser needs pyoidn: pip install 'clpt[oidn]'") from None
    return pyoidn


def demodulate(color, var, albedo):
    """Colour / albedo (where the albedo is not black), and its variance."""
    alb = np.where(albedo > ALBEDO_FLOOR, albedo, 1.0)
    lum_alb = np.maximum(dot_rows(alb, LUMA.astype(alb.dtype)), ALBEDO_FLOOR)  # in the inputs' precision
    return color / alb, var / lum_alb ** 2, alb


class Planar:
    """Planar images as filter.cl lays them out: rows of `pitch` (the width
    rounded up to 16: whole work-items of 8 or 16 pixels) floats, each plane
    with `margin` zeros before and after."""

    def __init__(self, width: int, height: int, radius: int, max_step: int):
        self.width, self.height = width, height
        self.pitch = -(-width // 16) * 16
        self.margin = radius * max_step + 16
        self.plane = self.pitch * height + 2 * self.margin


def _lum(a):
    wr, wg, wb = LUMA_WEIGHTS
    return wr * a[..., 0] + wg * a[..., 1] + wb * a[..., 2]


def reference_firefly(c, v, k, k_confirm=None):
    """numpy twin of filter_firefly: (colour, variance) after the clamp
    (k_confirm: the pixel's own standard errors that exempt it; k if None)."""
    k_confirm = k if k_confirm is None else k_confirm
    h, w = v.shape
    lp = _lum(c)
    pad_l = np.pad(lp, 1, constant_values=-np.inf)
    pad_v = np.pad(v, 1, constant_values=np.nan)
    lmax = np.full((h, w), -np.inf, np.float32)
    vs = []
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            sl = (slice(1 + dy, 1 + dy + h), slice(1 + dx, 1 + dx + w))
            vs.append(pad_v[sl])
            if dx or dy:
                lmax = np.maximum(lmax, pad_l[sl])
    vs = np.sort(np.stack(vs), axis=0)  # NaN (outside) last
    count = np.isfinite(vs).sum(0)
    vmed = np.take_along_axis(vs, (count // 2)[None], 0)[0]
    bound = lmax + k * np.sqrt(vmed)
    clip = (count > 1) & (lp > bound) & (lp - k_confirm * np.sqrt(v) <= bound)
    s = np.where(clip, np.maximum(bound, 0) / np.where(clip, lp, 1), 1.0)
    return (c * s[..., None]).astype(np.float32), np.where(clip, vmed, v).astype(np.float32)


def smooth3(x):
    """x (H x W) averaged over each pixel's 3x3 in the image, weights (1 2 1) x (1 2 1)."""
    h, w = x.shape
    kern = np.array([1, 2, 1], np.float32)
    xp, wp = np.pad(x, 1), np.pad(np.ones((h, w), np.float32), 1)
    s = sum(kern[a] * kern[b] * xp[a:a + h, b:b + w] for a in range(3) for b in range(3))
    return s / sum(kern[a] * kern[b] * wp[a:a + h, b:b + w] for a in range(3) for b in range(3))


def reference_cone_filter(color, var, normal, albedo, depth, settings: FilterSettings, emitter=None):
    """numpy twin of the cone filter (clpt/engine/passes.py FilterPass; slow, for tests on small images)."""
    h, w = color.shape[:2]
    if settings.width == 0:
        return color.astype(np.float32).copy()
    irr, v, alb = demodulate(color.astype(np.float64), var.astype(np.float64), albedo.astype(np.float64))
    c = irr.astype(np.float32)
    v = v.astype(np.float32)
    if settings.firefly_k > 0:
        c, v = reference_firefly(c, v, settings.firefly_k, settings.confirm_k)
    has = (normal * normal).sum(-1) > 0
    flag = np.zeros((h, w), bool) if emitter is None else emitter > 0.5
    ys, xs = np.mgrid[0:h, 0:w]
    r_ = min(settings.width, max(w, h))
    passes = settings.passes(w, h)
    f32 = np.float32
    for it in range(passes):
        step = 1 << it
        fit = settings.fit_last and it == passes - 1
        sigma_l, floor = ((settings.fit_sigma_luminance, settings.fit_guide_floor) if fit
                          else (settings.sigma_luminance, settings.guide_floor))
        lp = smooth3(_lum(c))
        sl = sigma_l * np.sqrt(smooth3(v)) + 1e-6
        acc = np.zeros_like(c)
        wsum = np.ones((h, w), np.float32)
        w2v = v.copy()
        mom = {k: np.zeros((h, w), np.float32) for k in ("x", "y", "xx", "yy", "xy")}
        accx, accy = np.zeros_like(c), np.zeros_like(c)
        for dy in range(-r_, r_ + 1):
            for dx in range(-r_, r_ + 1):
                if dx == 0 and dy == 0:
                    continue
                r = np.sqrt(dx * dx + dy * dy)
                ws = 1 - r / (r_ + 1)
                if ws <= 0:
                    continue
                qy, qx = ys + dy * step, xs + dx * step
                ok = (qy >= 0) & (qy < h) & (qx >= 0) & (qx < w)
                qy, qx = np.clip(qy, 0, h - 1), np.clip(qx, 0, w - 1)
                ok &= (has == has[qy, qx]) & (flag == flag[qy, qx])
                cosn = np.maximum((normal * normal[qy, qx]).sum(-1), 0.0)
                g = np.where(has, cosn ** int(settings.sigma_normal), 1.0)
                da = albedo - albedo[qy, qx]
                g = g * np.exp(-((da * da).sum(-1) / settings.sigma_albedo ** 2
                                 + np.abs(depth - depth[qy, qx])
                                 / (settings.sigma_depth * np.maximum(depth, 1e-6) * step) / r))
                wt = ws * (g + floor) * np.exp(-np.abs(lp - lp[qy, qx]) / sl)
                wt = np.where(ok & (wt > 0), wt, 0.0).astype(np.float32)
                d = c[qy, qx] - c
                acc += wt[..., None] * d
                wsum += wt
                w2v += wt * wt * v[qy, qx]
                if fit:  # the tap's position in the window, -1 to 1
                    xt, yt = f32(dx / r_), f32(dy / r_)
                    wx, wy = wt * xt, wt * yt
                    mom["x"] += wx
                    mom["y"] += wy
                    mom["xx"] += wx * xt
                    mom["yy"] += wy * yt
                    mom["xy"] += wx * yt
                    accx += wx[..., None] * d
                    accy += wy[..., None] * d
        if fit:
            c = c + plane_intercept(wsum, mom, acc, accx, accy)
        else:
            c = c + acc / wsum[..., None]
        v = w2v / (wsum * wsum)
    return (c * alb).astype(np.float32)


def plane_intercept(wsum, mom, acc, accx, accy):
    """The weighted least-squares plane a + b x + c y through the taps'
    differences from the centre (acc, accx, accy: the sums of w d, w x d, w y d;
    mom: of w x, w y, w x^2, w y^2, w x y; wsum: of w, the centre's 1 included),
    a little ridge (1e-3 wsum) on the slopes: a, by the first row of the normal
    matrix's cofactors, as filter.cl computes it (float32)."""
    lam = np.float32(1e-3) * wsum
    axx, ayy, sx, sy, sxy = mom["xx"] + lam, mom["yy"] + lam, mom["x"], mom["y"], mom["xy"]
    m0 = axx * ayy - sxy * sxy
    m1 = sxy * sy - sx * ayy
    m2 = sx * sxy - axx * sy
    inv = np.float32(1) / (wsum * m0 + sx * m1 + sy * m2)
    return (m0[..., None] * acc + m1[..., None] * accx + m2[..., None] * accy) * inv[..., None]


def kept_emission(aux, count, k: float):
    """The emission the denoisers leave out and add back (H x W x 3): a
    pixel's emission seen directly or through mirrors and glass, where the
    share f of its n samples that see an emitter so is confirmed: its
    relative standard error, sqrt((1 - f) / (f n)), at most 1 / k (f n >=
    k^2 (1 - f)), or in one of its 8 neighbours (the edge of a lamp's image,
    or of its reflection's). Elsewhere (a lamp reached by one sample in
    sixteen, through the edge of a glass ball) the emission is noise and is
    filtered with the rest. k = 0 keeps all of it out."""
    emission = aux["emission"]
    if not k > 0:
        return emission
    e = np.asarray(aux["emitter"])
    # Only pixels that see an emitter (f > 0) can be confirmed: the test runs on those alone.
    idx = np.flatnonzero(e > 0)
    f = np.clip(e.ravel()[idx], 0.0, 1.0)
    n = np.broadcast_to(count, e.shape).ravel()[idx]
    confirmed = np.zeros(e.shape, bool)
    confirmed.ravel()[idx[f * np.maximum(n, 1.0) >= k * k * (1.0 - f)]] = True
    # The edge of a confirmed image (a lamp's, or its reflection's) is kept too.
    # (chosen in float32: no float64 image in between)
    mask = dilate(confirmed, 1)
    out = np.zeros(np.shape(emission), np.float32)
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows):  # only the rows a lamp's image spans (a masked copy of the whole image took 1 ms at 512x512)
        a, b = rows[0], rows[-1] + 1
        out[a:b] = np.where(mask[a:b, :, None], np.asarray(emission[a:b], np.float32), np.float32(0))
    return out


def kept_caustic_share(caustic, image, share: float):
    """The part (H x W, 0 to 1) of each pixel's photon-map caustic the cone
    filter leaves out: the caustic's share of the luminance over the pixel's
    3x3 (edge pixels repeated outside the image), s, ramped from 0 at
    s = share / 2 to 1 at s = 1.5 share. A caustic's core is kept (it is a density estimate already,
    filtering it again spreads it); the scattered photons of a mirror's or
    glass ball's light on the walls, a few percent of their luminance, are
    filtered with the rest. share 0: all of it kept; None where the image has
    no caustic."""
    if not share > 0:
        return np.ones(caustic.shape[:2], np.float32)
    if not caustic.any():  # no caustic (no photon map, or nothing specular): nothing to weigh
        return None
    c = box3(dot_rows(caustic.astype(np.float32, copy=False), LUMA.astype(np.float32)))
    lum = box3(dot_rows(np.asarray(image, np.float32), LUMA.astype(np.float32)))
    s = c / np.maximum(lum, 1e-30)
    return np.clip((s - 0.5 * share) / share, 0.0, 1.0).astype(np.float32, copy=False)


def box3(x):
    """x (H x W) summed over each pixel's 3x3, the image's edge pixels repeated outside."""
    p = np.pad(x, 1, mode="edge")
    rows = p[:-2] + p[1:-1] + p[2:]
    return rows[:, :-2] + rows[:, 1:-1] + rows[:, 2:]


def dilate(mask, r: int):
    """mask (H x W bool) grown by r pixels in each direction (a square)."""
    h, w = mask.shape
    pad = np.pad(mask, ((0, 0), (r, r)))
    rows = np.zeros_like(mask)
    for dx in range(2 * r + 1):  # a square is a row's dilation, then a column's
        rows |= pad[:, dx:dx + w]
    pad = np.pad(rows, ((r, r), (0, 0)))
    out = np.zeros_like(mask)
    for dy in range(2 * r + 1):
        out |= pad[dy:dy + h]
    return out


def apply_denoiser(cone, image, lum_var, count, aux, settings):
    """The denoised image (H x W x 3) of a render: image, its per-sample
    luminance variance and sample counts (H x W), the feature images (aux,
    with "caustic" and "caustic_var"), settings a FilterSettings (cone, on
    `cone`, a FilterPass) or an OidnSettings."""
    # Emission seen directly, or through mirrors and glass, is not noise to
    # smooth where the pixel's samples confirm it: both denoisers leave it out
    # (next to a lamp, OIDN would otherwise spread it into a halo; the cone
    # filter would average a lamp's reflection with the dark mirror around it).
    k = settings.confirm_k if isinstance(settings, FilterSettings) else FilterSettings.confirm_k
    keep = kept_emission(aux, count, k)
    if isinstance(settings, OidnSettings):
        return keep + oidn_denoise(image - keep, aux["albedo"], aux["normal"], settings)
    # Nor are the photon map's caustics, for the cone filter: a density
    # estimate already, filtering them again would spread them.
    # Only where they are concentrated, though: the few photons scattered over
    # the walls (a mirror's and a glass ball's light) are noise like the rest.
    rest_var = lum_var
    if settings.keep_caustics:
        share = kept_caustic_share(aux["caustic"], image, settings.caustic_share)
        if share is not None:
            keep = keep + aux["caustic"] * share[..., None]
            rest_var = np.maximum(lum_var - aux["caustic_var"] * share, 0.0)
    mean_var = rest_var / np.maximum(count, 1.0)
    out = cone(image - keep, mean_var, aux["normal"], aux["albedo"], aux["depth"], settings,
               emitter=aux["emitter"])
    out += keep  # in place: the filter's result is a new array
    return np.maximum(out, 0.0, out=out).astype(np.float32, copy=False)


def oidn_denoise(color, albedo, normal, settings: OidnSettings):
    """OIDN's RT filter on a linear HDR image (H x W x 3) with our feature
    buffers; "clean" first denoises albedo and normal on their own."""
    pyoidn = oidn_module()
    col = np.ascontiguousarray(np.maximum(np.nan_to_num(color), 0), np.float32)
    if settings.aux == "none":
        out = pyoidn.denoise(col, hdr=True, quality=settings.quality)
    else:
        alb = np.ascontiguousarray(np.clip(albedo, 0, 1), np.float32)
        nrm = np.ascontiguousarray(np.clip(normal, -1, 1), np.float32)
        clean = settings.aux == "clean"
        if clean:
            # "balanced" prefiltering: a third of "high"'s time, the same error (bench-denoise)
            pre = "fast" if settings.quality == "fast" else "balanced"
            alb, nrm = _oidn_prefilter(pyoidn, alb, "albedo", pre), _oidn_prefilter(pyoidn, nrm, "normal", pre)
        out = pyoidn.denoise(col, alb, nrm, hdr=True, clean_aux=clean, quality=settings.quality)
    return np.maximum(np.asarray(out, np.float32), 0)


_OIDN_DEVICE = []


def _oidn_prefilter(pyoidn, img, slot, quality):
    """One auxiliary image denoised by OIDN (the RT filter with only that image set)."""
    if not _OIDN_DEVICE:
        dev = pyoidn.Device()
        dev.commit()
        _OIDN_DEVICE.append(dev)
    dev = _OIDN_DEVICE[0]
    out = np.empty_like(img)
    flt = pyoidn.Filter(dev, pyoidn.OIDN_FILTER_TYPE_RT)
    try:
        flt.set_image(slot, img, pyoidn.OIDN_FORMAT_FLOAT3)
        flt.set_image(pyoidn.OIDN_IMAGE_OUTPUT, out, pyoidn.OIDN_FORMAT_FLOAT3)
        flt.set_quality({"high": pyoidn.OIDN_QUALITY_HIGH, "balanced": pyoidn.OIDN_QUALITY_BALANCED,
                         "fast": pyoidn.OIDN_QUALITY_FAST}[quality])
        flt.commit()
        flt.execute()
    finally:
        flt.release()
    return out
