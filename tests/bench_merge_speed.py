"""Photon merging's samples per CPU second against the path tracer's, on the
shipped caustic scenes.

    python tests/bench_merge_speed.py --device intel --rounds 3 cornell_box_caustics fig09_mirror_and_green_glass

For each scene, two Renderers on the device: the default (`clpt render
SCENE`: photon merging where the pilot chooses it, progressive maps) and
path tracing alone (`Renderer(scene, photons=False)`, as `--no-photons`).
Each round renders both at LO and HI samples per pixel (default 256 and
1024, 128x128, depth 64, a fixed seed), the two methods alternating (AB
BA AB ...), each render timed in this process's CPU seconds (every
thread's: the OpenCL runtime's workers run in it) and in kernel device
seconds (profiling events). The marginal cost of a sample is the
difference between the two renders over (HI - LO) * pixels: the pilot, the
builds and the first map cancel out. Best of the rounds (the fastest of
each render), in Msamples per CPU second; the ratio is merging's over path
tracing's (the target: at least 0.5). --json writes every render's times.

--base-kernels DIR adds a third method to the same rounds: the default
render built from another tree's kernels/ folder (e.g. `git archive main
kernels | tar -x -C /tmp/base`), so that a change's before and after are
measured side by side, under the same load (the host code is this tree's).
On a machine other jobs share, the best of 3 rounds still moved by about
10% between runs here: a difference smaller than that needs more rounds.
(The kernel columns are profiling-event seconds: PoCL's exceed its CPU
seconds at times; compare CPU seconds.)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", help="shipped scenes (default: those with caustics)")
    ap.add_argument("--device", default="intel")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--lo", type=int, default=256)
    ap.add_argument("--hi", type=int, default=1024)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--depth", type=int, default=64)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", default=None)
    ap.add_argument("--base-kernels", default=None, help="a kernels/ folder to render the default with as well")
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    import clpt
    import clpt.program as program
    from clpt.loading import load_scene
    from clpt.pack import pack_scene
    from clpt.resources import shipped_scenes

    scenes = a.scenes or [s for s in shipped_scenes() if pack_scene(load_scene(s)).has_caustics]
    kw = dict(width=a.size, height=a.size, max_depth=a.depth, seed=a.seed)
    n_pix = a.size * a.size
    out = {}
    print(f"{a.device}: {a.size}x{a.size}, depth {a.depth}, marginal over {a.lo}..{a.hi} spp, best of {a.rounds}",
          flush=True)
    print(f"{'scene':32s} {'path':>7s} {'merge':>7s} {'ratio':>6s}  {'kernel path':>11s} {'merge':>7s} {'ratio':>6s}"
          "  chosen", flush=True)
    for s in scenes:
        rs = {"merge": clpt.Renderer(s, device=a.device), "path": clpt.Renderer(s, device=a.device, photons=False)}
        if a.base_kernels:
            own = program.kernel_dir
            program.kernel_dir = lambda: Path(a.base_kernels)
            try:
                rs["base"] = clpt.Renderer(s, device=a.device)
            finally:
                program.kernel_dir = own
        chosen = ""
        for name, r in rs.items():
            res = r.render(4, **kw)  # builds, first launches, the pilot's cached trial
            if name == "merge":
                pl = res.stats.photon_pilot
                chosen = pl.get("choice", "?") if isinstance(pl, dict) else "no pilot"
        times = {k: {"cpu": {a.lo: [], a.hi: []}, "kernel": {a.lo: [], a.hi: []}} for k in rs}
        for rnd in range(a.rounds):
            order = list(rs) if rnd % 2 == 0 else list(rs)[::-1]
            for name in order:
                for spp in (a.lo, a.hi):
                    c0 = time.process_time()
                    res = rs[name].render(spp, **kw)
                    times[name]["cpu"][spp].append(time.process_time() - c0)
                    times[name]["kernel"][spp].append(sum(sum(v) for v in res.stats.kernel_seconds.values()))
        rate = {}
        for name, t in times.items():
            for what in ("cpu", "kernel"):
                dt = min(t[what][a.hi]) - min(t[what][a.lo])
                rate[name, what] = (a.hi - a.lo) * n_pix / dt / 1e6 if dt > 0 else float("nan")
        base = ""
        if "base" in rs:
            base = (f"  base merge {rate['base', 'cpu']:5.2f} ratio {rate['base', 'cpu'] / rate['path', 'cpu']:4.2f}"
                    f" (merge/base {rate['merge', 'cpu'] / rate['base', 'cpu']:4.2f})")
        print(f"{s:32s} {rate['path', 'cpu']:7.2f} {rate['merge', 'cpu']:7.2f} "
              f"{rate['merge', 'cpu'] / rate['path', 'cpu']:6.2f}  {rate['path', 'kernel']:11.2f} "
              f"{rate['merge', 'kernel']:7.2f} {rate['merge', 'kernel'] / rate['path', 'kernel']:6.2f}  {chosen}{base}",
              flush=True)
        out[s] = {"times": times, "rate": {f"{k[0]}_{k[1]}": v for k, v in rate.items()}, "chosen": chosen}
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
