"""Before and after in one process, alternating: another tree's kernels
launched one pixel per lane (LANE_PIXELS = 1, as before lanes took pixels in
turn) against this tree's, path tracing and the default (merging) each.

    git archive ba282b9 kernels | tar -x -C /tmp/base
    python tests/bench_lane_pixels.py --device intel --base-kernels /tmp/base/kernels --rounds 3

Prints, per shipped caustic scene, the marginal Msamples per CPU second
between 256 and 1024 spp (128x128, depth 64; as tests/bench_merge_speed.py)
and merging's rate over path tracing's, before | after. The host code is
this tree's for both.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--device", default="intel")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--base-kernels", required=True)
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    import clpt
    import clpt.constants as constants
    import clpt.program as program
    from clpt.loading import load_scene
    from clpt.pack import pack_scene
    from clpt.resources import shipped_scenes

    scenes = a.scenes or [s for s in shipped_scenes() if pack_scene(load_scene(s)).has_caustics]
    lo, hi = 256, 1024
    kw = dict(width=128, height=128, max_depth=64, seed=1)
    own_kd, own_lp = program.kernel_dir, constants.LANE_PIXELS
    print(f"{a.device}: marginal Msamples per CPU second over {lo}..{hi} spp, 128x128, depth 64, "
          f"best of {a.rounds}, alternating", flush=True)
    print(f"{'scene':32s} {'path':>6s} {'merge':>6s} {'ratio':>6s} | {'path':>6s} {'merge':>6s} {'ratio':>6s}"
          "   (before | after)", flush=True)
    for scene in scenes:
        rs = {}
        for name, photons, before in (("path0", False, True), ("merge0", None, True),
                                      ("path1", False, False), ("merge1", None, False)):
            try:
                if before:
                    constants.LANE_PIXELS = 1
                    program.kernel_dir = lambda: Path(a.base_kernels)
                rs[name] = clpt.Renderer(scene, device=a.device, photons=photons)
                rs[name].render(4, **kw)  # the build, with the settings above
            finally:
                program.kernel_dir, constants.LANE_PIXELS = own_kd, own_lp
        t = {k: {lo: [], hi: []} for k in rs}
        for rnd in range(a.rounds):
            order = list(rs) if rnd % 2 == 0 else list(rs)[::-1]
            for name in order:
                for spp in (lo, hi):
                    c0 = time.process_time()
                    rs[name].render(spp, **kw)
                    t[name][spp].append(time.process_time() - c0)
        rate = {n: (hi - lo) * 128 * 128 / (min(t[n][hi]) - min(t[n][lo])) / 1e6 for n in rs}
        print(f"{scene:32s} {rate['path0']:6.2f} {rate['merge0']:6.2f} {rate['merge0'] / rate['path0']:6.2f} | "
              f"{rate['path1']:6.2f} {rate['merge1']:6.2f} {rate['merge1'] / rate['path1']:6.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
