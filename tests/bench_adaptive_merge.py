"""Uniform against adaptive sampling at equal CPU time, errors against a
reference: on a machine other jobs share, wall-clock time limits are noisy,
so each method's samples per pixel are chosen to fill the same CPU seconds
of this process (every thread's, the OpenCL runtime's workers included).
With --wall, the same seconds of wall-clock time instead: what a user
waits for. The two differ where a runtime leaves cores idle (PoCL's threads
sleep when they have no work, Intel's spin), so a method that keeps fewer
cores busy looks cheaper in CPU time than it is.

    python tests/bench_adaptive_merge.py cornell_box_caustics --device intel \\
        --cpu-seconds 6 --seeds 1,2,3 --ref /tmp/ref.exr --ref-spp 65536

For each seed and method: a probe render of 64 spp measures the CPU cost
per sample per pixel; the render then gets the spp that fill --cpu-seconds
(up to twice more, rescaled by its own cost, while it misses by more than
5%); the errors are also given scaled to exactly --cpu-seconds (times the
CPU seconds used over --cpu-seconds, as for an error falling as 1/time). The
scene's photon settings apply (the pilot chooses merging or path tracing).
Prints per run the CPU seconds, spp, relMSE (RGB, eps 1e-2, as clpt compare;
and with the reference's own noise taken out, each channel's taken as its
luminance noise times (r_c / Y)^2: metrics.relmse_rgb_denoised)
and the luminance relMSE with the reference's own noise taken out, then the
means and the ratios uniform / adaptive (above 1: adaptive is better), and
the ceiling of that ratio for luminance relMSE: what the best allocation of
the uniform render's samples would gain, from its per-pixel variances
(clpt.adaptive.allocation_ceiling; samples of equal cost, pixel errors
independent, so the photon maps' shared noise is not in it).
The reference is read from --ref, or path traced with --ref-spp and saved
there. Run it from another tree with PYTHONPATH=that/tree to measure that
tree's clpt.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import numpy as np

from clpt.features import SAMPLERS


def scene_parser(doc: str) -> argparse.ArgumentParser:
    """The adaptive benches' arguments: a scene, a device and the image size."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--device", default="intel")
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=128)
    return ap


def main(argv=None) -> int:
    ap = scene_parser(__doc__)
    ap.add_argument("--max-depth", type=int, default=None)
    ap.add_argument("--cpu-seconds", type=float, default=6.0)
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--ref", required=True, help="reference EXR (rendered and saved if missing)")
    ap.add_argument("--ref-spp", type=int, default=16384)
    ap.add_argument("--threshold", type=float, default=None,
                    help="the adaptive noise threshold (default: AdaptiveSettings'; one the time cannot reach "
                         "makes adaptive sampling use all of it)")
    ap.add_argument("--sampler", choices=SAMPLERS, default="stratified")
    ap.add_argument("--wall", action="store_true", help="equal wall-clock time instead of CPU time")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    clock = time.perf_counter if a.wall else time.process_time
    unit = "wall s" if a.wall else "CPU s"  # --cpu-seconds: of this unit
    warnings.simplefilter("ignore")

    from clpt.adaptive import AdaptiveSettings, allocation_ceiling
    from clpt.constants import LUMA
    from clpt.loading import load_scene
    from clpt.render import Renderer
    from clpt.tools import metrics
    from clpt.tools.reference import reference_image

    scene = load_scene(a.scene)
    W, H = a.width, a.height
    ref = reference_image(scene, W, H, a.ref_spp, a.ref, a.device, max_depth=a.max_depth)
    r = Renderer(scene, device=a.device, sampler=a.sampler)
    kw = dict(width=W, height=H, max_depth=a.max_depth)
    methods = {"uniform": {}, "adaptive": {"adaptive": AdaptiveSettings() if a.threshold is None else
                                                 AdaptiveSettings(threshold=a.threshold)}}
    for m in methods.values():  # first launches (kernel builds) kept out of the timings
        r.render(64, seed=999, **kw, **m)
    runs = []
    T = a.cpu_seconds
    for seed in (int(s) for s in a.seeds.split(",")):
        for name, m in methods.items():
            c = clock()
            r.render(64, seed=seed + 1000, **kw, **m)
            per = (clock() - c) / 64
            spp = max(1, int(T / per))
            for _ in range(3):
                c = clock()
                res = r.render(spp, seed=seed, **kw, **m)
                used = clock() - c
                if abs(used - T) <= 0.05 * T:
                    break
                spp = max(1, int(spp * T / max(used, 1e-9)))
            img = res.image.astype(np.float64)
            errors = {"relmse": metrics.relmse(img, ref),
                      "relmse_denoised": (metrics.relmse_rgb_denoised(img, ref, ref.noise_map)
                                          if ref.noise_map is not None else float("nan")),
                      "relmse_luma_denoised": metrics.relmse_luma(img, ref, ref.noise_map)}
            row = {"method": name, "seed": seed, "cpu_seconds": used, "spp": float(res.sample_count.mean()),
                   **errors,
                   # As if the render had taken exactly T CPU seconds (error ~ 1 / time):
                   # what is left of the calibration's miss.
                   **{k + "_at_T": v * used / T for k, v in errors.items()},
                   "choice": (res.stats.photon_pilot or {}).get("choice"),
                   # The most any allocation of these samples could gain (luminance, pixel noise alone):
                   "ceiling": allocation_ceiling(ref @ LUMA, res.lum_var) if name == "uniform" else None,
                   "rounds": res.stats.adaptive_rounds}
            runs.append(row)
            if not a.json:
                print(f"  seed {seed} {name:9s} {used:6.2f} {unit} {row['spp']:8.1f} spp  relMSE {row['relmse']:.3e}"
                      f" (- ref noise {row['relmse_denoised']:.3e})"
                      f"  luma relMSE - ref noise {row['relmse_luma_denoised']:.3e}  [{row['choice']}]", flush=True)
    summary = {}
    for name in methods:
        rows = [x for x in runs if x["method"] == name]
        summary[name] = {k: float(np.mean([x[k] for x in rows])) for k in
                         ("cpu_seconds", "spp", "relmse", "relmse_denoised", "relmse_luma_denoised", "relmse_at_T",
                          "relmse_denoised_at_T", "relmse_luma_denoised_at_T")}
    gain = {k: summary["uniform"][k] / summary["adaptive"][k] for k in
            ("relmse", "relmse_denoised", "relmse_luma_denoised", "relmse_at_T", "relmse_denoised_at_T",
             "relmse_luma_denoised_at_T")}
    if a.json:
        print(json.dumps({"runs": runs, "summary": summary, "gain": gain,
                          "ceiling": float(np.mean([x["ceiling"] for x in runs if x["ceiling"] is not None]))},
                         indent=1))
        return 0
    for name, s in summary.items():
        print(f"{name:9s} mean: {s['cpu_seconds']:6.2f} {unit} {s['spp']:8.1f} spp  relMSE {s['relmse']:.3e}"
              f" (- ref noise {s['relmse_denoised']:.3e})  luma relMSE - ref noise {s['relmse_luma_denoised']:.3e}")
    ceilings = [x["ceiling"] for x in runs if x["ceiling"] is not None]
    print(f"the best allocation of uniform's samples would lower the luminance relMSE {np.mean(ceilings):.3f}x "
          f"(clpt.adaptive.allocation_ceiling: equal cost per sample, independent pixel errors)")
    print(f"lanes {r.features.lanes}; uniform / adaptive: relMSE {gain['relmse']:.3f}x "
          f"(- ref noise {gain['relmse_denoised']:.3f}x), luma relMSE - ref noise "
          f"{gain['relmse_luma_denoised']:.3f}x; scaled to {T:g} {unit} (error x {unit} / {T:g}): relMSE "
          f"{gain['relmse_at_T']:.3f}x (- ref noise {gain['relmse_denoised_at_T']:.3f}x), luma relMSE - ref noise "
          f"{gain['relmse_luma_denoised_at_T']:.3f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
