"""Accuracy and speed of the plastic lobes on tests/data/plastic_spheres.xml:
clpt with the plastics as Mitsuba defines them, and with the diffuse + Phong
(rough) / mirror (smooth) approximation the loader used before, against the
stored Mitsuba 3 reference (mean colour ratio, worst 16x16 block in sigma);
then clpt and Mitsuba 3 (LLVM) rendering the scene at the same spp, one after
the other in this run. Mitsuba is never a dependency: it runs in the
interpreter --mitsuba-python names (skipped without it).

    python tests/bench_plastic.py --device pocl --spp 1024 \\
        --mitsuba-python /path/to/venv-with-mitsuba/bin/python
"""

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import clpt
from clpt.mitsuba import plastic_approximation

sys.path.insert(0, str(Path(__file__).parent))
from stats import compare_to_reference  # noqa: E402

DATA = Path(__file__).parent / "data"
MITSUBA = """
import sys, time, mitsuba as mi
mi.set_variant("llvm_ad_rgb")
scene = mi.load_file(sys.argv[1], spp=int(sys.argv[2]))
mi.render(scene, spp=16).numpy()  # JIT compilation
t = time.perf_counter(); img = mi.render(scene, spp=int(sys.argv[2]), seed=1).numpy()
print(time.perf_counter() - t, img[..., :3].reshape(-1, 3).mean(axis=0).tolist())
"""


def approximated(scene):
    shapes = [dataclasses.replace(x, material=plastic_approximation(x.material))
              if isinstance(x.material, clpt.Material) else x for x in scene.shapes]
    return clpt.Scene(camera=scene.camera, shapes=shapes, materials=scene.materials, render=scene.render)


def accuracy(name, renderer, spp, ref):
    """Render spp samples per pixel (after a build) and print the image's mean
    colour over the Mitsuba reference's and its worst 16x16 block."""
    renderer.render(spp=8, seed=0)  # builds
    t = time.perf_counter()
    res = renderer.render(spp=spp, seed=1)
    dt = time.perf_counter() - t
    err, z = compare_to_reference(res, ref)
    ratio = res.image.reshape(-1, 3).mean(axis=0) / np.array(ref["mean_rgb"])
    print(f"clpt, {name}: mean / Mitsuba's {np.round(ratio, 4).tolist()}, worst block "
          f"{np.abs(z).max():.1f} sigma ({(np.abs(z) > 4).sum()} of {z.size} beyond 4), "
          f"{spp} spp in {dt:.2f} s", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default=None)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--mitsuba-python", default=None)
    a = ap.parse_args()
    ref = json.loads((DATA / "plastic_spheres_mitsuba.json").read_text())
    scene = clpt.load_scene(DATA / "plastic_spheres.xml")
    for name, sc in (("Phong/mirror approximation", approximated(scene)), ("plastic lobes", scene)):
        accuracy(name, clpt.Renderer(sc, device=a.device, photons=False), a.spp, ref)
    if a.mitsuba_python:
        env = {**os.environ, "DRJIT_LIBLLVM_PATH": os.environ.get("DRJIT_LIBLLVM_PATH",
                                                                    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")}
        out = subprocess.run([a.mitsuba_python, "-c", MITSUBA, str(DATA / "plastic_spheres.xml"), str(a.spp)],
                             capture_output=True, text=True, env=env, check=True).stdout.split(None, 1)
        print(f"Mitsuba 3 llvm_ad_rgb: {a.spp} spp in {float(out[0]):.2f} s (mean {out[1].strip()})")


if __name__ == "__main__":
    main()
