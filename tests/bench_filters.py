"""The pixel filters measured: against Mitsuba 3 and in speed.

    python tests/bench_filters.py --device pocl [--spp 1024] [--speed-spp 64 --runs 5]

1. cbox_lamp_gaussian.xml (a small bright lamp, Mitsuba's gaussian filter)
   against its stored Mitsuba 3 reference (tests/data/
   cbox_lamp_gaussian_mitsuba.json): the image mean's ratio, the worst
   16x16-pixel block in sigma (both renders' noise), the blocks around the
   lamp, and the outermost ring of pixels; for the gaussian as Mitsuba
   samples it (only inside the film), the gaussian with sample_border (the
   whole filter at the edges), the box and the tent.
2. Speed: the same scene at 128x128 with the box (no filter code) and the
   gaussian, renders alternating, samples per CPU second of this process
   (every thread's: the OpenCL runtime's workers run in it) and per wall
   second, medians of --runs.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import clpt  # noqa: E402
from stats import compare_to_reference, ring_z  # noqa: E402

DATA = HERE / "data"
REF = json.loads((DATA / "cbox_lamp_gaussian_mitsuba.json").read_text())


def scene_with(**kw):
    s = clpt.load_scene(DATA / "cbox_lamp_gaussian.xml", params={"res": REF["width"]})
    pf = dataclasses.replace(s.camera.pixel_filter, **kw)
    return dataclasses.replace(s, camera=dataclasses.replace(s.camera, pixel_filter=pf))


VARIANTS = {"gaussian": {}, "gaussian sample_border": {"sample_border": True},
            "box": {"kind": "box", "stddev": None}, "tent": {"kind": "tent", "stddev": None}}


def accuracy(device, spp):
    print(f"cbox_lamp_gaussian.xml {REF['width']}x{REF['height']}, {spp} spp, against {REF['_source']}")
    for name, kw in VARIANTS.items():
        res = clpt.Renderer(scene_with(**kw), device=device, photons=False).render(spp=spp, seed=1)
        mean = res.image.reshape(-1, 3).mean(axis=0) / np.array(REF["mean_rgb"])
        _, z = compare_to_reference(res, REF)
        print(f"  {name:24s} mean ratio {', '.join(f'{m:.4f}' for m in mean)}  worst block {np.abs(z).max():5.1f} "
              f"sigma  ring {ring_z(res, REF):+5.1f} sigma  blocks by the lamp (1,1) (1,2) (2,1) (2,2): "
              f"{z[1, 1]:+.1f} {z[1, 2]:+.1f} {z[2, 1]:+.1f} {z[2, 2]:+.1f}")


def speed(device, spp, runs, size=128):
    import os
    rs = {k: clpt.Renderer(scene_with(**VARIANTS[k]), device=device, photons=False) for k in ("box", "gaussian")}
    for r in rs.values():
        r.render(spp=4, width=size, height=size)  # builds and first launches
    out = {k: ([], []) for k in rs}
    for i in range(runs):
        for k in (("box", "gaussian") if i % 2 == 0 else ("gaussian", "box")):
            c0, t0 = os.times(), time.perf_counter()
            rs[k].render(spp=spp, width=size, height=size, seed=i)
            c1, t1 = os.times(), time.perf_counter()
            cpu = (c1.user - c0.user) + (c1.system - c0.system)
            n = size * size * spp
            out[k][0].append(n / cpu / 1e6)
            out[k][1].append(n / (t1 - t0) / 1e6)
    print(f"speed, {size}x{size}, {spp} spp, {runs} runs alternating, {rs['box'].states[0].label}:")
    for k, (cpu, wall) in out.items():
        print(f"  {k:9s} {statistics.median(cpu):.3f} Msamples per CPU s (range {min(cpu):.3f}-{max(cpu):.3f}), "
              f"{statistics.median(wall):.3f} per wall s")
    print(f"  gaussian / box: {statistics.median(out['gaussian'][0]) / statistics.median(out['box'][0]):.3f} "
          f"(CPU), {statistics.median(out['gaussian'][1]) / statistics.median(out['box'][1]):.3f} (wall)")


if __name__ == "__main__":
    warnings.simplefilter("ignore")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--speed-spp", type=int, default=64)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    a = ap.parse_args()
    if not a.skip_accuracy:
        accuracy(a.device, a.spp)
    if not a.skip_speed:
        speed(a.device, a.speed_spp, a.runs)
