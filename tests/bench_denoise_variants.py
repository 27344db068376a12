"""Variants of the cone filter measured against the shipped one, in numpy
(clpt/denoise.py's twin, so nothing here touches the kernels):

    python tests/bench_denoise_variants.py --device intel [--seeds 4] [--spp 16,64] [--variants cone,reg,...]

Each scene is rendered at 128x128 (max depth 64) for --seeds seeds and each
spp, and every variant's output compared with the path-traced reference that
`clpt bench-denoise --ref-spp N` caches (rendered here when missing): the
whole image's relMSE and, per region of bench-denoise (diffuse walls, the
mirror and glass balls, the caustic, the lamps' reflections, the brightest
1%), relMSE and the mean luminance over the reference's.

Variants (all start from the same demodulated, firefly-clamped image and the
same guides as the shipped filter):
  cone        the shipped filter's numpy twin (reference_cone_filter): two
              averaging passes, then one that fits a plane (fit_last)
  avg         the same with the last pass averaging too (fit_last=False)
  reg         the three cone passes, then a first-order weighted regression
              of the *noisy* colour on screen position within a 7x7 window,
              the weights (cone kernel, guides, values) taken from the
              filtered image; the intercept is the output
  reg-late    two cone passes (steps 1, 2), then the same regression of the
              filtered colour over a 5x5 window of step 4
  reg-disc    as reg-late over the 12 taps within 2 steps (a disc) and without
              the guides' floor: the best regression found (16 spp, 4 seeds:
              2.05e-3 against the cone's 2.13e-3 on the caustics box, 1.50e-3
              against 1.61e-3 on cornell_box), for 1.5 passes' more work
  sym         energy-conserving passes: symmetric weights (the value term's
              noise the larger of both pixels', the depth term's scale their
              mean depth) normalised by the larger of both pixels' weight
              sums, so that what one pixel gives its neighbour is what the
              neighbour takes
  cross       each render split into two halves of spp/2 samples (two seeds);
              each half filtered with the value weights of the other
              (cross-filtering), the two averaged; against "halves", each
              half filtered with its own weights
  splat       the emission the filter would smooth (unconfirmed: a lamp met by
              a few samples through glass) taken out of the cone's input and
              added back spread by an energy-conserving 7-tap binomial splat
  sure        five averaging passes; each pixel takes the output after 2, 3,
              4 or 5 passes whose SURE estimate of the squared error (with
              the weights held fixed: the product of the passes' self-weights
              is the output's derivative in its input), summed over 5x5, is
              least
  halfsel     the same choice among 2, 3 and 4 passes by the squared
              difference, over 11x11, of each half's filtered image from the
              other half's raw one (an unbiased error estimate up to a
              constant), applied to the whole render's filtered images
  ivw         taps weighted by the inverse square root of their (3x3-smoothed)
              variance over the pixel's: less noisy pixels count more
  steps421    the passes' steps reversed, 4, 2, 1
  lamp-pool   the unconfirmed emission kept out of the filter where the 3x3's
              hits together confirm it (sum f n >= (1 - F), k = 1), and added
              back as the 3x3's mean
  oidn        OIDN with cleaned albedo and normal (needs pyoidn)
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from clpt.denoise import (LUMA, FilterSettings, OidnSettings, _lum, apply_denoiser, demodulate,  # noqa: E402
                          dilate, kept_caustic_share, kept_emission, reference_cone_filter, reference_firefly,
                          smooth3)
from clpt.tools.metrics import relmse  # noqa: E402

ALL = ("cone", "avg", "reg", "reg-late", "reg-disc", "sym", "halves", "cross", "splat", "sure", "halfsel", "ivw",
       "steps421", "lamp-pool", "oidn")
HALVES = ("halves", "cross", "halfsel")


def shifted(a, dy, dx):
    """a[y + dy, x + dx] (zeros outside) and where that is inside the image."""
    h, w = a.shape[:2]
    out = np.zeros_like(a)
    ok = np.zeros((h, w), bool)
    dst = (slice(max(0, -dy), min(h, h - dy)), slice(max(0, -dx), min(w, w - dx)))
    src = (slice(max(0, dy), min(h, h + dy)), slice(max(0, dx), min(w, w + dx)))
    out[dst] = a[src]
    ok[dst] = True
    return out, ok


class Guides:
    def __init__(self, normal, albedo, depth, emitter):
        self.n, self.a, self.z = normal, albedo, depth
        self.has = (normal * normal).sum(-1) > 0
        self.flag = np.zeros(depth.shape, bool) if emitter is None else emitter > 0.5

    def weight(self, dy, dx, r, step, s, symmetric=False):
        """The guides' factor g (normals, albedo, depth) and the taps' validity."""
        mn, ok = shifted(self.n, dy, dx)
        ma, _ = shifted(self.a, dy, dx)
        mz, _ = shifted(self.z, dy, dx)
        mh, _ = shifted(self.has, dy, dx)
        mf, _ = shifted(self.flag, dy, dx)
        ok &= (self.has == mh) & (self.flag == mf)
        g = np.where(self.has, np.maximum((self.n * mn).sum(-1), 0.0) ** int(s.sigma_normal), 1.0)
        da = self.a - ma
        scale = 0.5 * (self.z + mz) if symmetric else self.z
        return g * np.exp(-((da * da).sum(-1) / s.sigma_albedo ** 2
                            + np.abs(self.z - mz) / (s.sigma_depth * np.maximum(scale, 1e-6) * step) / r)), ok


def taps(radius, step, rmax=None):
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            r = np.hypot(dx, dy)
            ws = 1 - r / (radius + 1)
            if (dx or dy) and ws > 0 and (rmax is None or r <= rmax):
                yield dy * step, dx * step, r, ws


def value_weights(c_guide, v_guide, gd, step, s, radius=1, symmetric=False, floor=None, rmax=None, ivw=0.0):
    """{(dy, dx): weight} of the cone kernel, with the value term from c_guide
    (ivw: times (v_p / v_q)^ivw, the variances smoothed over 3x3)."""
    lp, vs = smooth3(_lum(c_guide)), smooth3(v_guide)
    floor = s.guide_floor if floor is None else floor
    out = {}
    for dy, dx, r, ws in taps(radius, step, rmax):
        g, ok = gd.weight(dy, dx, r, step, s, symmetric)
        lq, _ = shifted(lp, dy, dx)
        vq, _ = shifted(vs, dy, dx)
        sl = s.sigma_luminance * np.sqrt(np.maximum(vs, vq) if symmetric else vs) + 1e-6
        w = ws * (g + floor) * np.exp(-np.abs(lp - lq) / sl)
        if ivw:
            w = w * (vs / np.maximum(vq, 1e-12)) ** ivw
        out[(dy, dx)] = np.where(ok, w, 0.0)
    return out


def cone_pass(c, v, gd, step, s, c_guide=None, v_guide=None, symmetric=False, ivw=0.0, self_weight=None):
    """One averaging pass: (colour, variance); self_weight, a list, gets the centre's share."""
    W = value_weights(c if c_guide is None else c_guide, v if v_guide is None else v_guide, gd, step, s,
                      symmetric=symmetric, ivw=ivw)
    wsum = 1 + sum(W.values())
    acc, var, selfw = np.zeros_like(c), np.zeros_like(v), np.ones_like(v)
    for (dy, dx), w in W.items():
        m = w / (np.maximum(wsum, shifted(wsum, dy, dx)[0]) if symmetric else wsum)
        cq, _ = shifted(c, dy, dx)
        vq, _ = shifted(v, dy, dx)
        acc += m[..., None] * (cq - c)
        selfw -= m
        var += m * m * vq
    if self_weight is not None:
        self_weight.append(selfw)
    return c + acc, selfw ** 2 * v + var


def regression(c_in, c_guide, v_guide, gd, s, radius, step, floor=None, rmax=None):
    """The intercept of a weighted first-order fit of c_in on screen position."""
    h, w = v_guide.shape
    W = value_weights(c_guide, v_guide, gd, step, s, radius=radius, floor=floor, rmax=rmax)
    A = np.zeros((h, w, 3, 3))
    B = np.zeros((h, w, 3, 3))
    items = [((0, 0), np.ones((h, w)))] + list(W.items())
    for (dy, dx), wt in items:
        x = np.array([1.0, dx / (radius * step), dy / (radius * step)])
        cq = shifted(c_in, dy, dx)[0] if (dy or dx) else c_in
        A += wt[..., None, None] * np.outer(x, x)
        B += wt[..., None, None] * x[:, None] * cq[..., None, :]
    A += 1e-3 * A[..., :1, :1] * np.diag([0.0, 1.0, 1.0])  # a little ridge on the slopes
    return np.linalg.solve(A, B)[..., 0, :]


def prepared(color, var, albedo, s):
    c, v, alb = demodulate(color.astype(np.float64), var.astype(np.float64), albedo.astype(np.float64))
    if s.firefly_k > 0:
        c, v = reference_firefly(c.astype(np.float32), v.astype(np.float32), s.firefly_k, s.confirm_k)
    return c.astype(np.float64), v.astype(np.float64), alb


def box(x, r):
    """x (H x W) summed over each pixel's (2r+1)^2 (zeros outside)."""
    h, w = x.shape
    p = np.pad(x, r)
    return sum(p[dy:dy + h, dx:dx + w] for dy in range(2 * r + 1) for dx in range(2 * r + 1))


def variant_cone(kind):
    def cone(color, var, normal, albedo, depth, s, emitter=None):
        c, v, alb = prepared(color, var, albedo, s)
        gd = Guides(normal, albedo, depth, emitter)
        c0, v0 = c, v
        if kind == "reg":
            for it in range(3):
                c, v = cone_pass(c, v, gd, 1 << it, s)
            c = regression(c0, c, v, gd, s, radius=3, step=1)
        elif kind == "reg-late":
            for it in range(2):
                c, v = cone_pass(c, v, gd, 1 << it, s)
            c = regression(c, c, v, gd, s, radius=2, step=4)
        elif kind == "reg-disc":
            for it in range(2):
                c, v = cone_pass(c, v, gd, 1 << it, s)
            c = regression(c, c, v, gd, s, radius=2, step=4, floor=0.0, rmax=2.0)
        elif kind == "sym":
            for it in range(3):
                c, v = cone_pass(c, v, gd, 1 << it, s, symmetric=True)
        elif kind in ("ivw", "steps421"):
            for step in ((1, 2, 4) if kind == "ivw" else (4, 2, 1)):
                c, v = cone_pass(c, v, gd, step, s, ivw=0.5 if kind == "ivw" else 0.0)
        elif kind == "sure":
            outs, sure, selfw = [], [], []
            for it in range(5):
                c, v = cone_pass(c, v, gd, 1 << it, s, self_weight=selfw)
                if it >= 1:  # SURE: |F - y|^2 - n var + 2 var dF/dy, dF/dy the self-weights' product
                    e = ((c - c0) ** 2).sum(-1) + 3 * v0 * (2 * np.prod(selfw, axis=0) - 1)
                    outs.append(c)
                    sure.append(box(e, 2))
            c = np.take_along_axis(np.array(outs), np.argmin(sure, 0)[None, ..., None], 0)[0]
        return (c * alb).astype(np.float32)
    return cone


def splat(x, taps_=(1, 6, 15, 20, 15, 6, 1)):
    """x spread by a separable binomial kernel, each pixel's kernel renormalised to the image (energy kept)."""
    k = np.asarray(taps_, np.float64) / sum(taps_)
    r = len(k) // 2
    h, w = x.shape[:2]

    def conv(a):
        p = np.pad(a, [(r, r), (0, 0)] + [(0, 0)] * (a.ndim - 2))
        a = sum(k[i] * p[i:i + h] for i in range(len(k)))
        p = np.pad(a, [(0, 0), (r, r)] + [(0, 0)] * (a.ndim - 2))
        return sum(k[i] * p[:, i:i + w] for i in range(len(k)))
    return conv(x / conv(np.ones((h, w)))[..., None])


def halves_filter(a, b, full, s, cross):
    """Each half filtered with the other's value weights (cross) or its own, averaged (what
    apply_denoiser keeps out, decided on the whole render, is kept out of both)."""
    aux = full["aux"]
    keep_mask = (kept_emission(aux, full["count"], s.confirm_k) @ LUMA > 0)[..., None]
    share = kept_caustic_share(aux["caustic"], full["image"], s.caustic_share)
    share = np.zeros(keep_mask.shape, np.float32) if share is None else share[..., None]
    gd = Guides(aux["normal"], aux["albedo"], aux["depth"], aux["emitter"])
    cs, vs = [], []
    for h in (a, b):
        kh = h["aux"]["caustic"] * share + np.where(keep_mask, h["aux"]["emission"], 0.0)
        rv = np.maximum(h["lum_var"] - h["aux"]["caustic_var"] * share[..., 0], 0) / np.maximum(h["count"], 1)
        c, v, alb = prepared(h["image"] - kh, rv, aux["albedo"], s)
        cs.append(c)
        vs.append(v)
    for it in range(3):
        o = (1, 0) if cross else (0, 1)
        cs, vs = map(list, zip(*[cone_pass(cs[i], vs[i], gd, 1 << it, s, c_guide=cs[o[i]], v_guide=vs[o[i]])
                                 for i in (0, 1)]))
    keep = aux["caustic"] * share + np.where(keep_mask, aux["emission"], 0.0)
    return np.maximum(keep + 0.5 * (cs[0] + cs[1]) * alb, 0).astype(np.float32)


def pass_outputs(run, s, passes):
    """The filtered images (modulated, what the host keeps out added back) after each of `passes` averaging passes."""
    got = {}

    def cone(color, var, normal, albedo, depth, s_, emitter=None):
        c, v, alb = prepared(color, var, albedo, s_)
        gd = Guides(normal, albedo, depth, emitter)
        for it in range(max(passes)):
            c, v = cone_pass(c, v, gd, 1 << it, s_)
            if it + 1 in passes:
                got[it + 1] = c * alb
        return np.zeros_like(color)
    keep = apply_denoiser(cone, run["image"], run["lum_var"], run["count"], run["aux"], s)
    return [np.maximum(keep + got[k], 0) for k in passes]


def halfsel(run, s, passes=(2, 3, 4), r=5):
    a, b = run["halves"]
    fa, fb, full = (pass_outputs(x, s, passes) for x in (a, b, run))
    err = [box(((x - b["image"]) ** 2 + (y - a["image"]) ** 2).sum(-1), r) for x, y in zip(fa, fb)]
    return np.take_along_axis(np.array(full), np.argmin(err, 0)[None, ..., None], 0)[0].astype(np.float32)


def lamp_pool(run, s, k=1.0):
    """Unconfirmed emission confirmed by the 3x3's hits together: kept out, added back as its 3x3 mean."""
    aux = run["aux"]
    u = np.maximum(aux["emission"] - kept_emission(aux, run["count"], s.confirm_k), 0)
    hit = (u @ LUMA) > 0
    f, n = np.clip(aux["emitter"], 0, 1), np.maximum(run["count"], 1.0)
    hits, tot = box(f * n * hit, 1), box(n, 1)
    group = (hits > 0) & (hits >= k * k * (1 - hits / tot))
    out_ = np.where((dilate(group, 1) & hit)[..., None], u, 0.0)
    back = np.where(group[..., None], np.stack([box(out_[..., i], 1) for i in range(3)], -1)
                    / box(np.ones(f.shape), 1)[..., None], 0.0)
    out = apply_denoiser(reference_cone_filter, run["image"] - out_, run["lum_var"], run["count"], aux, s)
    return np.maximum(out + back, 0).astype(np.float32)


def run_variant(kind, run, s=FilterSettings()):
    args = (run["image"], run["lum_var"], run["count"], run["aux"])
    if kind == "raw":
        return run["image"]
    if kind == "cone":
        return apply_denoiser(reference_cone_filter, *args, s)
    if kind == "avg":
        return apply_denoiser(reference_cone_filter, *args, replace(s, fit_last=False))
    if kind == "halfsel":
        return halfsel(run, s)
    if kind == "lamp-pool":
        return lamp_pool(run, s)
    if kind in ("reg", "reg-late", "reg-disc", "sym", "ivw", "steps421", "sure"):
        return apply_denoiser(variant_cone(kind), *args, s)
    if kind == "oidn":
        return apply_denoiser(None, *args, OidnSettings(aux="clean"))
    if kind == "splat":
        unconfirmed = np.maximum(run["aux"]["emission"] - kept_emission(run["aux"], run["count"], s.confirm_k), 0)
        out = apply_denoiser(reference_cone_filter, run["image"] - unconfirmed, *args[1:], s)
        return np.maximum(out + splat(unconfirmed), 0).astype(np.float32)
    if kind in ("halves", "cross"):
        return halves_filter(*run["halves"], run, s, cross=kind == "cross")
    raise ValueError(kind)


def as_run(res):
    return dict(image=res.image, lum_var=res.lum_var, count=res.sample_count,
                aux={k: np.asarray(v) for k, v in res.aux.items()})


def combined(a, b):
    """Two half renders as one (means; the sample counts added)."""
    return dict(image=0.5 * (a["image"] + b["image"]), lum_var=0.5 * (a["lum_var"] + b["lum_var"]),
                count=a["count"] + b["count"], aux={k: 0.5 * (a["aux"][k] + b["aux"][k]) for k in a["aux"]},
                halves=(a, b))


def main(argv=None) -> int:
    from clpt.render import Renderer
    from clpt.tools.bench_denoise import region_errors, regions
    from clpt.tools.reference import cached_path, reference_image

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scene", nargs="*", default=["cornell_box_caustics", "cornell_box"])
    p.add_argument("--spp", default="16,64")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--ref-spp", type=int, default=32768)
    p.add_argument("--ref-dir", default=".clpt-references")
    p.add_argument("--device", default=None)
    p.add_argument("--variants", default="raw," + ",".join(ALL))
    a = p.parse_args(argv)
    kinds = a.variants.split(",")
    W = H = 128
    for scene in a.scene:
        ref = reference_image(scene, W, H, a.ref_spp, cached_path(a.ref_dir, scene, W, H, a.ref_spp, 64), a.device,
                              max_depth=64)
        masks = regions(scene, W, H, ref, device=a.device)
        r = Renderer(scene, device=a.device, aux=True)
        for spp in (int(x) for x in a.spp.split(",")):
            runs = [as_run(r.render(spp, width=W, height=H, max_depth=64, seed=k)) for k in range(1, a.seeds + 1)]
            halves = []
            if set(HALVES) & set(kinds):  # both halves' combination is what "cone" is compared on there
                halves = [combined(*(as_run(r.render(spp // 2, width=W, height=H, max_depth=64, seed=1000 * j + k))
                                     for j in (1, 2))) for k in range(1, a.seeds + 1)]
            for kind in kinds:
                for label, rs in ((kind, runs if kind not in HALVES else halves),
                                  ) + ((("cone (halves' sum)", halves),) if kind in ("cross", "halfsel") else ()):
                    outs = [run_variant("cone" if label.startswith("cone (") else kind, x) for x in rs]
                    whole = np.mean([relmse(o, ref) for o in outs])
                    regs = [region_errors(o, ref, masks) for o in outs]
                    cells = "  ".join(f"{k} {np.mean([g[k]['relmse'] for g in regs]) * 1e3:.3f}/"
                                      f"{100 * np.mean([g[k]['energy'] for g in regs]):.1f}%" for k in masks)
                    print(f"{scene:22s} {spp:3d} spp {label:20s} relMSE x1e3 {whole * 1e3:7.3f} | {cells}",
                          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
