"""Small launches spread over the compute units, measured (README, "Lanes
take pixels in turn").

    python tests/bench_small_launches.py [--device intel] [--rounds 5]

The Cornell box at 32x32 to 96x96, rendered in one process with each
work-item taking lanes x LANE_PIXELS pixels whatever the launch ("before")
and as many as still give every compute unit GROUPS_PER_UNIT work-groups
(clpt/constants.py work_item_entries, "after"), in alternating rounds; wall
Msamples/s, medians. The images are the same bits (checked here too).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import clpt

CASES = ((32, 4096), (48, 2048), (64, 1024), (96, 512))  # (side, spp): about 0.2-0.5 s a render


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--scene", default="cornell_box")
    ap.add_argument("--rounds", type=int, default=5)
    a = ap.parse_args()
    for side, spp in CASES:
        r = clpt.Renderer(a.scene, device=a.device)
        trace = r.states[0].trace
        fitted = trace.entries_for
        fixed = lambda n: trace.entries  # noqa: E731  (four pixels per lane, always)
        r.render(2, width=side, height=side)
        walls, images, entries = {"before": [], "after": []}, {}, {}
        for _ in range(a.rounds):
            for name, fn in (("before", fixed), ("after", fitted)):
                trace.entries_for = fn
                t = time.perf_counter()
                res = r.render(spp, width=side, height=side, seed=1)
                walls[name].append(time.perf_counter() - t)
                images[name], entries[name] = res.image, trace.wi_entries
        rate = {k: side * side * spp / statistics.median(v) / 1e6 for k, v in walls.items()}
        same = np.array_equal(images["before"], images["after"])
        print(f"{a.scene} {side}x{side} {spp} spp on {trace.dctx.label}: pixels per work-item "
              f"{entries['before']} -> {entries['after']}, {rate['before']:.2f} -> {rate['after']:.2f} "
              f"Msamples/s ({rate['after'] / rate['before']:.2f}x); same bits: {same}", flush=True)
        if not same:
            return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
