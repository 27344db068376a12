"""Point and spot lights, measured (the figures in README, "Point and spot lights").

    python tests/bench_lights.py [--device intel] [--size 48] [--times 5,20] [--ref-spp 262144]
        [--mitsuba-python /path/to/python-with-mitsuba]

1. Equal time, a point light through a glass ball (tests/test_lights.py's
   scene): the default render (caustic photons merged) against
   photons=False, relMSE over the caustic region (pixels where a long
   photon render exceeds a long path-traced one by at least 5% of the
   largest such excess: the light that only photons carry) and over the
   image, against a long photon render of another seed.
2. Speed of tests/data/spot_box.xml (path traced, 64x64): clpt's samples/s
   and, with --mitsuba-python, Mitsuba 3 LLVM's in the same run (its own
   process; the first render, which compiles, left out).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import clpt  # noqa: E402
from clpt.photons import PhotonSettings  # noqa: E402

import test_lights  # noqa: E402

LUMA = np.array([0.2126, 0.7152, 0.0722])

MITSUBA_TIMING = r"""
import json, sys, time
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
scene = mi.load_file(sys.argv[1], res=int(sys.argv[2]))
spp = int(sys.argv[3])
mi.render(scene, spp=spp, seed=0)  # compiles
best = []
for k in range(3):
    t = time.perf_counter()
    img = mi.render(scene, spp=spp, seed=k + 1)
    _ = float(mi.TensorXf(img).numpy().mean())
    best.append(time.perf_counter() - t)
print(json.dumps({"seconds": best, "spp": spp}))
"""


def relmse(img, ref, mask, eps=1e-2):
    a, b = img @ LUMA, ref @ LUMA
    return float((((a - b) ** 2) / (b * b + eps))[mask].mean())


def equal_time(device, size, times, ref_spp):
    scene = test_lights._point(size)
    pm_r = clpt.Renderer(scene, device=device)
    pt_r = clpt.Renderer(scene, device=device, photons=False)
    t = time.perf_counter()
    ref = pm_r.render(ref_spp, seed=1000, max_depth=8).image
    pt_long = pt_r.render(ref_spp, seed=2000, max_depth=8).image
    print(f"references: {ref_spp} spp each, {time.perf_counter() - t:.0f} s", flush=True)
    excess = (ref - pt_long) @ LUMA
    region = excess >= 0.05 * excess.max()
    print(f"caustic region: {int(region.sum())} of {size * size} pixels; path traced it holds "
          f"{float((pt_long @ LUMA)[region].sum() / (ref @ LUMA)[region].sum()):.2%} of the photon render's energy")
    rows = []
    for T in times:
        a = pm_r.render(1 << 20, seed=1, max_depth=8, time_limit=T)
        b = pt_r.render(1 << 20, seed=1, max_depth=8, time_limit=T)
        whole = np.ones(region.shape, bool)
        row = {"seconds": T, "photons_spp": float(a.sample_count.mean()), "pt_spp": float(b.sample_count.mean()),
               "photons_choice": (a.stats.photon_pilot or {}).get("choice"),
               "caustic_relmse_photons": relmse(a.image, ref, region), "caustic_relmse_pt": relmse(b.image, ref, region),
               "image_relmse_photons": relmse(a.image, ref, whole), "image_relmse_pt": relmse(b.image, ref, whole)}
        row["caustic_ratio"] = row["caustic_relmse_pt"] / row["caustic_relmse_photons"]
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def speed(device, mitsuba_python, spp=256, res=64, xml=None):
    """Samples/s of clpt and of Mitsuba 3 LLVM (best of three renders each, in
    this run) on an XML scene with a `res` parameter (spot_box.xml by default)."""
    xml = xml or HERE / "data" / "spot_box.xml"
    scene = clpt.load_scene(xml, params={"res": res})
    r = clpt.Renderer(scene, device=device, photons=False)
    r.render(16, seed=0)  # builds
    secs = []
    for k in range(3):
        t = time.perf_counter()
        r.render(spp, seed=k + 1)
        secs.append(time.perf_counter() - t)
    out = {"clpt_samples_per_s": res * res * spp / min(secs), "clpt_seconds": secs}
    if mitsuba_python:
        env = dict(os.environ, DRJIT_LIBLLVM_PATH=os.environ.get("DRJIT_LIBLLVM_PATH",
                                                                "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"))
        p = subprocess.run([mitsuba_python, "-c", MITSUBA_TIMING, str(xml), str(res), str(spp)], env=env,
                           capture_output=True, text=True, check=True)
        m = json.loads(p.stdout.strip().splitlines()[-1])
        out["mitsuba_samples_per_s"] = res * res * spp / min(m["seconds"])
        out["mitsuba_seconds"] = m["seconds"]
        out["ratio"] = out["clpt_samples_per_s"] / out["mitsuba_samples_per_s"]
    print(json.dumps(out), flush=True)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", type=int, default=48)
    ap.add_argument("--times", default="5,20")
    ap.add_argument("--ref-spp", type=int, default=262144)
    ap.add_argument("--mitsuba-python", default=None)
    ap.add_argument("--skip-equal-time", action="store_true")
    a = ap.parse_args()
    if not a.skip_equal_time:
        equal_time(a.device, a.size, [float(x) for x in a.times.split(",")], a.ref_spp)
    speed(a.device, a.mitsuba_python)


if __name__ == "__main__":
    main()
