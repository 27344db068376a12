"""A/B in one process: the bunny box (tests/data/cbox_bunny.xml, its walls
OBJ files without normals, so smooth triangles with their face normal) with
those triangles packed smooth (A, as before clpt.pack.FLAT_NORMAL_EPS) or
flat (B, the default: the big walls leave the BVH). Renderers built once,
rendered in alternating rounds; Msamples per CPU second and image means.

    python tests/ab_flat_normals.py [--device intel] [--rounds 6] [--spp 8]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def main():
    import clpt
    import clpt.pack as pk
    import realscene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--spp", type=int, default=8)
    a = ap.parse_args()
    bunny = realscene.bunny_path()
    if bunny is None:
        raise SystemExit("ab_flat_normals: needs /work/shared/meshes/bunny.ply or $CLPT_BUNNY")
    xml = HERE / "data" / "cbox_bunny.xml"
    default = pk.FLAT_NORMAL_EPS
    runs = {}
    for name, eps in (("A smooth", -1.0), ("B flat", default)):
        pk.FLAT_NORMAL_EPS = eps  # -1: no triangle counts as flat
        try:
            r = clpt.Renderer(clpt.load_scene(xml, params={"bunny": str(bunny)}), device=a.device, photons=False)
        finally:
            pk.FLAT_NORMAL_EPS = default
        first = r.render(1, seed=0)
        runs[name] = (r, [], [], first.image.shape[0] * first.image.shape[1])
    for i in range(a.rounds):
        for r, rates, means, n in runs.values():
            c = time.process_time()
            res = r.render(a.spp, seed=i + 1, pass_seconds=1e9)
            rates.append(n * a.spp / (time.process_time() - c) / 1e6)
            means.append(float(res.image.mean()))
    for name, (r, rates, means, _) in runs.items():
        print(f"{name}: {r.features.describe()}\n  Msamples/CPU-s best {max(rates):.3f} median "
              f"{statistics.median(rates):.3f}; image mean {statistics.fmean(means):.5f} +- "
              f"{statistics.stdev(means) / len(means) ** 0.5:.5f}")


if __name__ == "__main__":
    main()
