"""`clpt bench-denoise`: the denoisers measured against a path-traced reference.

For each scene and spp, renders of --seeds seeds (feature buffers on, each
feature-buffer choice) are denoised by the cone filter and by OIDN in its
three modes (cleaned albedo+normal, albedo+normal as they are, colour only),
and for each the relMSE against the reference (means over the seeds, with
their standard errors), the energy kept over the caustic's core (the
pixels where the photon map's part is at least half its peak; against the
raw image and against the reference), and the 2-pixel ring around the lights
(pixels beside a lamp that see none of it in 256 samples) against the
reference's. Then the
denoisers' time at a larger size against a 16-spp render's (wall and CPU
seconds: on a shared machine the CPU seconds are the steadier figure).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..denoise import LUMA, FilterSettings, OidnSettings, apply_denoiser, dilate
from ..image import save_image
from .metrics import relmse
from ..render import Renderer
from .reference import cached_path, reference_image


def methods(with_oidn: bool) -> dict:
    """name -> (settings, aux_specular): what each row of the bench runs.
    The three feature-buffer choices are measured for every denoiser that
    reads them ("glass", the default: mirrors as surfaces, what is seen
    through glass; "surface": both as surfaces; "through": what is seen
    through both)."""
    m = {"raw": (None, "glass"),
         "cone": (FilterSettings(), "glass"),
         "cone (surface)": (FilterSettings(), "surface"),
         "cone (through)": (FilterSettings(), "through")}
    if with_oidn:
        m.update({"oidn albedo+normal (cleaned)": (OidnSettings(aux="clean"), "glass"),
                  "oidn albedo+normal (cleaned, surface)": (OidnSettings(aux="clean"), "surface"),
                  "oidn albedo+normal (cleaned, through)": (OidnSettings(aux="clean"), "through"),
                  "oidn albedo+normal": (OidnSettings(aux="noisy"), "glass"),
                  "oidn colour only": (OidnSettings(aux="none"), "glass")})
    return m


def _oidn_available() -> bool:
    try:
        import pyoidn  # noqa: F401
    except ImportError:
        return False
    return True


def _ring(emitter):
    light = emitter > 0
    return dilate(light, 2) & ~light


def shape_coverage(scene, index, width, height, spp=64, device=None):
    """The fraction of each pixel's camera rays whose first hit is shape
    `index` of scene: the scene rendered with that shape alone emitting 1
    (two-sided, every other shape black and dark), emitters only."""
    from dataclasses import replace

    from ..loading import load_scene
    from ..scene import Material
    sc = load_scene(scene) if not hasattr(scene, "shapes") else scene
    black = Material()
    shapes = [replace(s, material=black, emission=(1.0, 1.0, 1.0) if i == index else (0.0, 0.0, 0.0),
                      two_sided=True) for i, s in enumerate(sc.shapes)]
    marked = replace(sc, shapes=shapes)
    img = Renderer(marked, device=device, photons=False).render(spp, width=width, height=height, max_depth=0,
                                                                seed=7)
    return img.image[..., 1]


def regions(scene, width, height, ref, *, device=None, spp=64) -> dict:
    """Boolean masks (H x W) of the image's parts that denoisers treat
    differently, for per-region errors: "diffuse" (pixels at least half of
    whose camera rays first hit a non-specular, non-emitting shape, minus the
    caustic; a pixel belongs to the shape most of its rays hit), one per mirror or glass shape ("glass ball", "mirror ball" or
    the shape's name: pixels mostly on it), "caustic" (where the photon
    map's part over 256 samples, averaged over 3x3 pixels, is at least a
    quarter of its peak), "lamp reflections" (pixels on mirrors and glass
    where the lamps, seen through the specular chain, bring at least half
    of the reference's luminance) and "brightest 1%" (of the reference's lower half: the
    caustic and the highlights, which a filter must not cut)."""
    from ..loading import load_scene
    sc = load_scene(scene) if not hasattr(scene, "shapes") else scene
    out = {}
    diffuse = np.zeros((height, width), bool)
    spec_all = np.zeros((height, width), bool)
    shapes = [i for i, shp in enumerate(sc.shapes) if not sc.surface(shp).is_emissive]
    covs = np.stack([shape_coverage(sc, i, width, height, spp=spp, device=device) for i in shapes])
    best = np.argmax(covs, axis=0)
    for j, i in enumerate(shapes):
        shp = sc.shapes[i]
        m = sc.surface(shp)
        cov = (best == j) & (covs[j] >= 0.5)  # each pixel in one shape's region at most
        if m.is_specular:
            kind = "glass" if max(m.kt) > 0 else "mirror"
            name = f"{kind} ball" if type(shp).__name__ == "Sphere" else (shp.name or f"{kind} {i}")
            out[name] = out.get(name, np.zeros_like(cov)) | cov
            spec_all |= cov
        else:
            diffuse |= cov
    r = Renderer(sc, device=device, aux=True)
    through = r.render(256, width=width, height=height, seed=11, aux_specular="through").aux
    caustic = None
    if "caustic" in through:
        cl = _box3(through["caustic"] @ LUMA)
        if cl.max() > 0:
            caustic = cl >= 0.25 * cl.max()
    lum = np.asarray(ref) @ LUMA
    refl = spec_all & (through["emission"] @ LUMA >= 0.5 * lum) & (lum > 0)
    res = {"diffuse": diffuse if caustic is None else diffuse & ~caustic, **out}
    if caustic is not None:
        res["caustic"] = caustic
    if refl.any():
        res["lamp reflections"] = refl
    low = np.zeros_like(diffuse)
    low[height // 2:] = True
    res["brightest 1%"] = low & (lum >= np.quantile(lum[low], 0.99))
    return {k: v for k, v in res.items() if v.any()}


def _box3(x):
    p = np.pad(x, 1, mode="edge")
    h, w = x.shape
    return sum(p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)) / 9.0


def region_errors(out, ref, masks) -> dict:
    """Per region: relMSE, and the mean luminance over the reference's."""
    d = {}
    for k, m in masks.items():
        o, r_ = np.asarray(out, np.float64)[m], np.asarray(ref, np.float64)[m]
        d[k] = {"relmse": relmse(o, r_), "energy": float((o @ LUMA).mean() / max((r_ @ LUMA).mean(), 1e-30))}
    return d


def measure_quality(scene, *, spp_list=(16, 64), seeds=(1, 2), width=128, height=128, max_depth=64, ref,
                    device=None, image_path=None, crop_path=None, ms=None) -> list[dict]:
    r = Renderer(scene, device=device, aux=True)
    ms = methods(_oidn_available()) if ms is None else ms
    masks = regions(scene, width, height, ref, device=device)
    # The lamps' pixels from many samples, so the ring holds only pixels that see none of a lamp.
    lamps = r.render(256, width=width, height=height, max_depth=0, seed=99).aux["emitter"]
    ring = _ring(lamps)
    rows = []
    for spp in spp_list:
        acc = {k: {"relmse": [], "core_vs_raw": [], "core_vs_ref": [], "ring": [], "regions": []} for k in ms}
        for seed in seeds:
            runs = {mode: r.render(spp, width=width, height=height, max_depth=max_depth, seed=seed,
                                   aux_specular=mode) for mode in sorted({m for _, m in ms.values()})}
            first = next(iter(runs.values()))
            cl = first.aux["caustic"] @ LUMA
            core = cl >= 0.5 * cl.max() if cl.max() > 0 else None
            outs = {}
            for name, (s, mode) in ms.items():
                res = runs[mode]
                out = res.image if s is None else apply_denoiser(r.states[0].filter, res.image, res.lum_var,
                                                                 res.sample_count, res.aux, s)
                outs[name] = out
                a = acc[name]
                a["relmse"].append(relmse(out, ref))
                a["regions"].append(region_errors(out, ref, masks))
                if ring.any():
                    a["ring"].append(float((out[ring] @ LUMA).mean() / (ref[ring] @ LUMA).mean() - 1))
                if core is not None:
                    a["core_vs_raw"].append(float((out[core] @ LUMA).mean() / (res.image[core] @ LUMA).mean()))
                    a["core_vs_ref"].append(float((out[core] @ LUMA).mean() / (ref[core] @ LUMA).mean()))
            if seed == seeds[0]:
                shown = [outs[k] for k in ("raw", "cone", "oidn albedo+normal (cleaned)") if k in outs]
                shown.append(np.asarray(ref, np.float32))
                if image_path is not None and spp == spp_list[0]:
                    side_by_side(image_path, shown)
                if crop_path is not None:
                    box = _crop_box(masks)
                    if box is not None:
                        side_by_side(str(crop_path).format(spp=spp), [im[box] for im in shown], scale=3)
        for name, a in acc.items():
            reg = {k: {**{q: float(np.mean([d[k][q] for d in a["regions"]])) for q in ("relmse", "energy")},
                       **{q + "_se": _se([d[k][q] for d in a["regions"]]) for q in ("relmse", "energy")}}
                   for k in masks}
            rows.append({"scene": scene, "spp": spp, "method": name, "aux_specular": ms[name][1],
                         **{k: (float(np.mean(v)) if v else None) for k, v in a.items() if k != "regions"},
                         "relmse_se": _se(a["relmse"]),
                         "regions": reg, "region_pixels": {k: int(v.sum()) for k, v in masks.items()}})
    return rows


def _se(values) -> float | None:
    """The standard error of the mean of per-seed values (None for one seed)."""
    return float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) > 1 else None


def _crop_box(masks, pad=4):
    """The rows and columns around the mirror and glass regions (and the caustic)."""
    keys = [k for k in masks if k.endswith("ball") or k == "caustic"]
    if not keys:
        return None
    m = np.any([masks[k] for k in keys], axis=0)
    ys, xs = np.nonzero(m)
    h, w = m.shape
    return (slice(max(ys.min() - pad, 0), min(ys.max() + pad + 1, h)),
            slice(max(xs.min() - pad, 0), min(xs.max() + pad + 1, w)))


def side_by_side(path, images, scale=2):
    """Images in a row (sRGB, each upscaled by `scale`), written to path."""
    row = np.concatenate([np.repeat(np.repeat(im, scale, 0), scale, 1) for im in images], axis=1)
    save_image(path, row)


def _clock(f, settle: float = 0.0):
    """f(), its wall seconds, and the process's CPU seconds through `settle`
    seconds of sleep after it (a render's process goes on using CPU for a
    while after render() returns: it is the render's, not what runs next)."""
    t, c = time.perf_counter(), time.process_time()
    out = f()
    wall = time.perf_counter() - t
    if settle:
        time.sleep(settle)
    return out, wall, time.process_time() - c


SETTLE = 0.5  # seconds of sleep after each timed call, inside its CPU time (_clock)


def measure_time(scene, *, size=512, rounds=2, device=None) -> dict:
    """Median wall and CPU seconds of a 16-spp render and of each denoiser on it."""
    r = Renderer(scene, device=device, aux=True)
    warm = r.render(1, width=size, height=size)  # the lazy device compile
    ms = {k: v for k, (v, mode) in methods(_oidn_available()).items() if v is not None and mode == "glass"}
    for s in ms.values():  # warm every kernel, OIDN's device and the cone filter's buffers for this size
        apply_denoiser(r.states[0].filter, warm.image, warm.lum_var, warm.sample_count, warm.aux, s)
    times = {"render 16 spp": [], **{k: [] for k in ms}}
    for i in range(rounds):
        res, w, c = _clock(lambda: r.render(16, width=size, height=size, seed=1 + i), SETTLE)
        times["render 16 spp"].append((w, c))
        for k, s in ms.items():
            _, w, c = _clock(lambda: apply_denoiser(r.states[0].filter, res.image, res.lum_var, res.sample_count,
                                                    res.aux, s), SETTLE)
            times[k].append((w, c))
    return {k: {"wall_s": float(np.median([t[0] for t in v])), "cpu_s": float(np.median([t[1] for t in v])),
                "wall_range": [float(min(t[0] for t in v)), float(max(t[0] for t in v))]}
            for k, v in times.items()}


def _crop_name(pattern, scene):
    return str(pattern).replace("{scene}", Path(str(scene)).stem)


def run_bench_denoise(a) -> int:
    out = {"quality": [], "time": {}}
    spp_list = [int(s) for s in a.spp.split(",")]
    for scene in a.scene:
        ref = reference_image(scene, a.width, a.height, a.ref_spp,
                              cached_path(a.ref_dir, scene, a.width, a.height, a.ref_spp, a.max_depth), a.device,
                              max_depth=a.max_depth)
        img = None
        if a.image and "caustic" in Path(scene).stem:
            img = a.image
        out["quality"] += measure_quality(scene, spp_list=spp_list, seeds=tuple(range(1, a.seeds + 1)),
                                          width=a.width, height=a.height, max_depth=a.max_depth, ref=ref,
                                          device=a.device, image_path=img,
                                          crop_path=_crop_name(a.crops, scene) if a.crops else None)
        if a.time_size:
            out["time"][scene] = measure_time(scene, size=a.time_size, device=a.device)
    if a.json:
        print(json.dumps(out, indent=1))
        return 0

    def f(v, fmt):
        return "-" if v is None else fmt.format(v)

    print(f"relMSE x1e3 against the path-traced reference ({a.width}x{a.height}, max depth {a.max_depth}, "
          f"means of {a.seeds} seeds); caustic core energy against the raw image and the reference; light ring "
          f"against the reference's")
    for r in out["quality"]:
        print(f"  {r['scene']:22s} {r['spp']:4d} spp  {r['method']:38s} relMSE {r['relmse'] * 1e3:7.3f}"
              f"{'' if r['relmse_se'] is None else ' +-' + format(r['relmse_se'] * 1e3, '.3f')}  "
              f"core/raw {f(r['core_vs_raw'], '{:.3f}')}  core/ref {f(r['core_vs_ref'], '{:.3f}')}  "
              f"ring {f(r['ring'], '{:+.3f}')}")
    print("per region: relMSE x1e3 / mean luminance over the reference's "
          "(energy, +- its standard error over the seeds)")
    for r in out["quality"]:
        cells = "  ".join(f"{k} {v['relmse'] * 1e3:7.3f} / {v['energy']:.3f}"
                          + (f" (+-{v['energy_se']:.3f})" if v["energy_se"] is not None else "")
                          for k, v in r["regions"].items())
        print(f"  {r['scene']:22s} {r['spp']:4d} spp  {r['method']:38s} {cells}")
    for scene, t in out["time"].items():
        print(f"time at {a.time_size}x{a.time_size}, {scene} (medians of 2):")
        base = t["render 16 spp"]
        for k, v in t.items():
            print(f"  {k:30s} wall {v['wall_s']:7.3f} s ({v['wall_range'][0]:.3f}-{v['wall_range'][1]:.3f})  "
                  f"CPU {v['cpu_s']:7.3f} s  ({100 * v['cpu_s'] / base['cpu_s']:.0f}% of the render's CPU time)")
    return 0

