"""Lane widths on one device: build seconds and Msamples/s of every shipped
scene (or those named) at 1 and 16 lanes, the kernels built cold (no cache),
rendered at 128x128, 32 spp, seed 1. What clpt/tune.py's predictions for
Intel's runtime rest on.

    python tests/bench_tune.py DEVICE [SCENE ...]
"""

import sys
import time
import warnings

from clpt.render import Renderer
from clpt.resources import shipped_scenes


def main(argv):
    warnings.simplefilter("ignore")
    device, scenes = argv[0], argv[1:] or shipped_scenes()
    for s in scenes:
        row = [f"{s:34}"]
        for lanes in (1, 16):
            t0 = time.perf_counter()
            r = Renderer(s, device=device, lanes=lanes, use_cache=False, local_size=16)
            built = time.perf_counter() - t0
            r.render(1, width=64, height=64)  # first launches
            t1 = time.perf_counter()
            r.render(32, width=128, height=128, seed=1)
            rate = 32 * 128 * 128 / (time.perf_counter() - t1) / 1e6
            row.append(f"{lanes:2} lanes: build {built:5.2f} s, {rate:5.2f} Msamples/s")
        print("  ".join(row), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
