"""Environment-lit rendering, measured (the figures in README, "Environment and directional lights").

    python tests/bench_envmap.py [--device intel] [--res 128] [--spp 256]
        [--mitsuba-python /path/to/python-with-mitsuba]

Samples/s of tests/data/env_spheres.xml (a diffuse and a rough gold sphere
on a plane under an HDR sky, path traced with MIS between the map's
importance sampling and BSDF sampling) in clpt and, with --mitsuba-python,
in Mitsuba 3 LLVM in the same run (its own process; the first render,
which compiles, left out): bench_lights.speed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_lights  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default=None)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--mitsuba-python", default=None)
    a = ap.parse_args()
    bench_lights.speed(a.device, a.mitsuba_python, spp=a.spp, res=a.res, xml=HERE / "data" / "env_spheres.xml")


if __name__ == "__main__":
    main()
