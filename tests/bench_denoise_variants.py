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
  cone        the shipped filter's numpy twin (reference_cone_filter)
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
  oidn        OIDN with cleaned albedo and normal (needs pyoidn)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from clpt.denoise import (LUMA, FilterSettings, OidnSettings, _lum, apply_denoiser, demodulate,  # noqa: E402
                          kept_caustic_share, kept_emission, reference_cone_filter, reference_firefly, smooth3)
from clpt.tools.metrics import relmse  # noqa: E402

ALL = ("cone", "reg", "reg-late", "reg-disc", "sym", "halves", "cross", "splat", "oidn")


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


def value_weights(c_guide, v_guide, gd, step, s, radius=1, symmetric=False, floor=None, rmax=None):
    """{(dy, dx): weight} of the cone kernel, with the value term from c_guide."""
    lp, vs = smooth3(_lum(c_guide)), smooth3(v_guide)
    floor = s.guide_floor if floor is None else floor
    out = {}
    for dy, dx, r, ws in taps(radius, step, rmax):
        g, ok = gd.weight(dy, dx, r, step, s, symmetric)
        lq, _ = shifted(lp, dy, dx)
        vq, _ = shifted(vs, dy, dx)
        sl = s.sigma_luminance * np.sqrt(np.maximum(vs, vq) if symmetric else vs) + 1e-6
        out[(dy, dx)] = np.where(ok, ws * (g + floor) * np.exp(-np.abs(lp - lq) / sl), 0.0)
    return out


def cone_pass(c, v, gd, step, s, c_guide=None, v_guide=None, symmetric=False):
    W = value_weights(c if c_guide is None else c_guide, v if v_guide is None else v_guide, gd, step, s,
                      symmetric=symmetric)
    wsum = 1 + sum(W.values())
    acc, var, selfw = np.zeros_like(c), np.zeros_like(v), np.ones_like(v)
    for (dy, dx), w in W.items():
        m = w / (np.maximum(wsum, shifted(wsum, dy, dx)[0]) if symmetric else wsum)
        cq, _ = shifted(c, dy, dx)
        vq, _ = shifted(v, dy, dx)
        acc += m[..., None] * (cq - c)
        selfw -= m
        var += m * m * vq
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


def variant_cone(kind):
    def cone(color, var, normal, albedo, depth, s, emitter=None):
        c, v, alb = prepared(color, var, albedo, s)
        gd = Guides(normal, albedo, depth, emitter)
        c0 = c
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


def run_variant(kind, run, s=FilterSettings()):
    args = (run["image"], run["lum_var"], run["count"], run["aux"])
    if kind == "raw":
        return run["image"]
    if kind == "cone":
        return apply_denoiser(reference_cone_filter, *args, s)
    if kind in ("reg", "reg-late", "reg-disc", "sym"):
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
            if {"halves", "cross"} & set(kinds):  # both halves' combination is what "cone" is compared on there
                halves = [combined(*(as_run(r.render(spp // 2, width=W, height=H, max_depth=64, seed=1000 * j + k))
                                     for j in (1, 2))) for k in range(1, a.seeds + 1)]
            for kind in kinds:
                for label, rs in ((kind, runs if kind not in ("halves", "cross") else halves),
                                  ) + ((("cone (halves' sum)", halves),) if kind == "cross" else ()):
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
