"""`clpt bench-denoise`: the denoisers measured against a path-traced reference.

For each scene and spp, renders of two seeds (feature buffers on) are
denoised by the cone filter and by OIDN in its three modes (cleaned
albedo+normal, albedo+normal as they are, colour only), and for each the
relMSE against the reference, the energy kept over the caustic's core (the
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

from ..denoise import LUMA, FilterSettings, OidnSettings, apply_denoiser
from ..image import save_image
from .metrics import relmse
from ..render import Renderer
from .reference import cached_path, reference_image


def methods(with_oidn: bool) -> dict:
    m = {"raw": None, "cone": FilterSettings()}
    if with_oidn:
        m.update({"oidn albedo+normal (cleaned)": OidnSettings(aux="clean"),
                  "oidn albedo+normal": OidnSettings(aux="noisy"),
                  "oidn colour only": OidnSettings(aux="none")})
    return m


def _oidn_available() -> bool:
    try:
        import pyoidn  # noqa: F401
    except ImportError:
        return False
    return True


def _ring(emitter):
    light = emitter > 0
    pad = np.pad(light, 2)
    h, w = light.shape
    near = np.zeros_like(light)
    for dy in range(5):
        for dx in range(5):
            near |= pad[dy:dy + h, dx:dx + w]
    return near & ~light


def measure_quality(scene, *, spp_list=(16, 64), seeds=(1, 2), width=128, height=128, max_depth=64, ref,
                    device=None, image_path=None) -> list[dict]:
    r = Renderer(scene, device=device, aux=True)
    ms = methods(_oidn_available())
    # The lamps' pixels from many samples, so the ring holds only pixels that see none of a lamp.
    lamps = r.render(256, width=width, height=height, max_depth=0, seed=99).aux["emitter"]
    ring = _ring(lamps)
    rows = []
    for spp in spp_list:
        acc = {k: {"relmse": [], "core_vs_raw": [], "core_vs_ref": [], "ring": []} for k in ms}
        for seed in seeds:
            res = r.render(spp, width=width, height=height, max_depth=max_depth, seed=seed)
            cl = res.aux["caustic"] @ LUMA
            core = cl >= 0.5 * cl.max() if cl.max() > 0 else None
            outs = {}
            for name, s in ms.items():
                out = res.image if s is None else apply_denoiser(r.states[0].filter, res.image, res.lum_var,
                                                                 res.sample_count, res.aux, s)
                outs[name] = out
                a = acc[name]
                a["relmse"].append(relmse(out, ref))
                if ring.any():
                    a["ring"].append(float((out[ring] @ LUMA).mean() / (ref[ring] @ LUMA).mean() - 1))
                if core is not None:
                    a["core_vs_raw"].append(float((out[core] @ LUMA).mean() / (res.image[core] @ LUMA).mean()))
                    a["core_vs_ref"].append(float((out[core] @ LUMA).mean() / (ref[core] @ LUMA).mean()))
            if image_path is not None and seed == seeds[0] and spp == spp_list[0]:
                side_by_side(image_path, [outs[k] for k in ms if k in ("raw", "cone", "oidn albedo+normal (cleaned)")]
                             + [np.asarray(ref, np.float32)])
        for name, a in acc.items():
            rows.append({"scene": scene, "spp": spp, "method": name,
                         **{k: (float(np.mean(v)) if v else None) for k, v in a.items()}})
    return rows


def side_by_side(path, images, scale=2):
    """Images in a row (sRGB, each upscaled by `scale`), written to path."""
    row = np.concatenate([np.repeat(np.repeat(im, scale, 0), scale, 1) for im in images], axis=1)
    save_image(path, row)


def _clock(f):
    t, c = time.perf_counter(), time.process_time()
    out = f()
    return out, time.perf_counter() - t, time.process_time() - c


def measure_time(scene, *, size=512, rounds=2, device=None) -> dict:
    """Median wall and CPU seconds of a 16-spp render and of each denoiser on it."""
    r = Renderer(scene, device=device, aux=True)
    r.render(1, width=size, height=size)  # the lazy device compile
    small = r.render(1, width=64, height=64)
    ms = {k: v for k, v in methods(_oidn_available()).items() if v is not None}
    for s in ms.values():  # warm every kernel and OIDN's device
        apply_denoiser(r.states[0].filter, small.image, small.lum_var, small.sample_count, small.aux, s)
    times = {"render 16 spp": [], **{k: [] for k in ms}}
    for i in range(rounds):
        res, w, c = _clock(lambda: r.render(16, width=size, height=size, seed=1 + i))
        times["render 16 spp"].append((w, c))
        for k, s in ms.items():
            _, w, c = _clock(lambda: apply_denoiser(r.states[0].filter, res.image, res.lum_var, res.sample_count,
                                                    res.aux, s))
            times[k].append((w, c))
    return {k: {"wall_s": float(np.median([t[0] for t in v])), "cpu_s": float(np.median([t[1] for t in v])),
                "wall_range": [float(min(t[0] for t in v)), float(max(t[0] for t in v))]}
            for k, v in times.items()}


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
                                          device=a.device, image_path=img)
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
        print(f"  {r['scene']:22s} {r['spp']:4d} spp  {r['method']:30s} relMSE {r['relmse'] * 1e3:7.3f}  "
              f"core/raw {f(r['core_vs_raw'], '{:.3f}')}  core/ref {f(r['core_vs_ref'], '{:.3f}')}  "
              f"ring {f(r['ring'], '{:+.3f}')}")
    for scene, t in out["time"].items():
        print(f"time at {a.time_size}x{a.time_size}, {scene} (medians of 2):")
        base = t["render 16 spp"]
        for k, v in t.items():
            print(f"  {k:30s} wall {v['wall_s']:7.3f} s ({v['wall_range'][0]:.3f}-{v['wall_range'][1]:.3f})  "
                  f"CPU {v['cpu_s']:7.3f} s  ({100 * v['cpu_s'] / base['cpu_s']:.0f}% of the render's CPU time)")
    return 0

