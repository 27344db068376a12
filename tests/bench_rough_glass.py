"""Accuracy and speed of the rough dielectric on tests/data/rough_glass.xml:
clpt with roughdielectric as Mitsuba defines it, and with the smooth
dielectric the loader mapped it to before, against the stored Mitsuba 3
reference (mean colour ratio, worst 16x16 block in sigma); then clpt and
Mitsuba 3 (LLVM) rendering the scene at the same spp, one after the other in
this run (tests/bench_lights.py speed). Mitsuba is never a dependency: it runs
in the interpreter --mitsuba-python names (skipped without it).

    python tests/bench_rough_glass.py --device pocl --spp 1024 \\
        --mitsuba-python /path/to/venv-with-mitsuba/bin/python
"""

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import clpt

sys.path.insert(0, str(Path(__file__).parent))
from bench_lights import speed  # noqa: E402
from bench_plastic import accuracy  # noqa: E402

DATA = Path(__file__).parent / "data"


def smooth(scene):
    """The scene with its rough dielectrics as the smooth dielectric (of their transmittance)."""
    def sm(m):
        if isinstance(m, clpt.Material) and m.rough_dielectric_lobe:
            return dataclasses.replace(m, rough_dielectric_lobe=False, kt=m.kgt)
        return m
    shapes = [dataclasses.replace(x, material=sm(x.material)) for x in scene.shapes]
    return clpt.Scene(camera=scene.camera, shapes=shapes, materials=scene.materials, render=scene.render)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default=None)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--speed-spp", type=int, default=256)
    ap.add_argument("--mitsuba-python", default=None)
    a = ap.parse_args()
    ref = json.loads((DATA / "rough_glass_mitsuba.json").read_text())
    scene = clpt.load_scene(DATA / "rough_glass.xml")
    for name, sc, photons in (("smooth dielectric (before)", smooth(scene), None),
                              ("rough dielectric", scene, False)):
        accuracy(name, clpt.Renderer(sc, device=a.device, photons=photons), a.spp, ref)
    speed(a.device, a.mitsuba_python, spp=a.speed_spp, res=64, xml=DATA / "rough_glass.xml")


if __name__ == "__main__":
    main()
