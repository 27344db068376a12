"""The cone filter's time against a 16-spp render's, and where it goes.

    python tests/bench_filter_time.py --device intel --rounds 10
    python tests/bench_filter_time.py --device pocl --a /tmp/base/.venv/bin/python --b .venv/bin/python

Each round renders the scene (16 spp, 512x512, feature buffers on) and
filters it (apply_denoiser with the default FilterSettings, as `clpt render
--filter` does), both timed in this process's CPU seconds (every thread's:
the OpenCL runtime's workers run in it) and wall seconds; the CPU times run
on through --settle seconds of sleep after each (a render's process goes on
using about 0.1 s of CPU for a while after render() returns, on Intel's
runtime and PoCL alike: without the sleep it falls on the filter's time); the filter's
kernels' device seconds come from their profiling events. Rounds alternate
between the scenes and, with --a/--b, between two trees' interpreters (one
child process per tree and --per-child rounds: AB BA AB ...). Prints medians and ranges,
the filter's share of the render (the ratio of the medians), and with
--profile a breakdown of one filter call's host time by function (cProfile).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

CHILD = r"""
import cProfile, io, json, pstats, sys, time, warnings
from pathlib import Path
warnings.simplefilter("ignore")
import numpy as np
import clpt
from clpt.denoise import FilterSettings, apply_denoiser
device, size, spp, rounds, profile = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5] == "1"
settle = float(sys.argv[6])
scenes = sys.argv[7:]
rs = {}
for s in scenes:
    r = clpt.Renderer(s, device=device, aux=True)
    warm = r.render(1, width=size, height=size)  # the device compile
    # the filter's kernels and its buffers for this size (made once per size)
    apply_denoiser(r.states[0].filter, warm.image, warm.lum_var, warm.sample_count, warm.aux, FilterSettings())
    rs[s] = r
out = {s: [] for s in scenes}
for i in range(rounds):
    for s in scenes:
        r = rs[s]
        t, c = time.perf_counter(), time.process_time()
        res = r.render(spp, width=size, height=size, seed=1 + i)
        rw = time.perf_counter() - t
        time.sleep(settle)  # the render's CPU goes on for a while after it returns: counted as the render's
        rc = time.process_time() - c
        f = r.states[0].filter
        f.counters.take()
        args = (res.image, res.lum_var, res.sample_count, res.aux, FilterSettings())
        t, c = time.perf_counter(), time.process_time()
        apply_denoiser(f, *args)
        fw = time.perf_counter() - t
        time.sleep(settle)
        fc = time.process_time() - c
        _, secs = f.counters.take()
        row = {"render_cpu": rc, "render_wall": rw, "filter_cpu": fc, "filter_wall": fw,
               "kernels": {k: sum(v) for k, v in secs.items()}}
        if profile and i == 0:
            pr = cProfile.Profile()
            pr.enable()
            apply_denoiser(f, *args)
            pr.disable()
            f.counters.take()
            st = io.StringIO()
            pstats.Stats(pr, stream=st).sort_stats("tottime").print_stats(14)
            row["profile"] = st.getvalue()
        out[s].append(row)
print("JSON" + json.dumps({"tree": str(Path(clpt.__file__).parent), **out}))
"""


def child(python, a, rounds, profile):
    env = dict(os.environ)
    env.setdefault("CLPT_TUNE", "query")
    # From a neutral directory: `python -c` puts the working directory first on sys.path, and a
    # tree's checkout there would be imported instead of the interpreter's own installed tree.
    scenes = [str(Path(s).resolve()) if Path(s).suffix else s for s in a.scenes]
    python = os.path.abspath(python) if os.sep in python else python
    p = subprocess.run([python, "-c", CHILD, a.device, str(a.size), str(a.spp), str(rounds), "1" if profile else "0",
                        str(a.settle), *scenes], capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())
    line = [x for x in p.stdout.splitlines() if x.startswith("JSON")]
    if p.returncode or not line:
        sys.exit(f"{python}: failed\n{p.stderr[-3000:]}")
    return json.loads(line[-1][4:])


def summary(rows, key):
    v = [r[key] for r in rows]
    return statistics.median(v), min(v), max(v)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="intel")
    ap.add_argument("--scenes", default="cornell_box,cornell_box_caustics")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=10, help="rounds (per tree with --a/--b)")
    ap.add_argument("--per-child", type=int, default=1, help="with --a/--b: rounds per child process")
    ap.add_argument("--a", default=sys.executable, help="tree A's python")
    ap.add_argument("--b", default=None, help="tree B's python (A/B alternating, one child per tree and round)")
    ap.add_argument("--settle", type=float, default=0.5,
                    help="seconds of sleep after the render and after the filter, inside their CPU times: a render "
                         "leaves ~0.1 s of CPU work running in the process after it returns, which would otherwise "
                         "land on the filter's")
    ap.add_argument("--profile", action="store_true", help="print one filter call's host profile per scene")
    a = ap.parse_args(argv)
    a.scenes = [s for s in a.scenes.split(",") if s]
    trees = {"A": a.a} if a.b is None else {"A": a.a, "B": a.b}
    got = {t: {s: [] for s in a.scenes} for t in trees}
    names = {}
    if a.b is None:
        res = child(a.a, a, a.rounds, a.profile)
        names["A"] = res["tree"]
        for s in a.scenes:
            got["A"][s] = res[s]
    else:
        for i in range(-(-a.rounds // a.per_child)):
            order = ("A", "B") if i % 2 == 0 else ("B", "A")
            for t in order:
                res = child(trees[t], a, a.per_child, a.profile and i < 2)
                if i == 0:
                    names[t] = res["tree"]
                for s in a.scenes:
                    got[t][s] += res[s]
    print(f"{a.device}, {a.size}x{a.size}, render {a.spp} spp vs apply_denoiser(FilterSettings()), "
          f"{a.rounds} rounds; medians [min, max], CPU and wall seconds")
    for s in a.scenes:
        for t, py in trees.items():
            rows = got[t][s]
            rc, fc = summary(rows, "render_cpu"), summary(rows, "filter_cpu")
            rw, fw = summary(rows, "render_wall"), summary(rows, "filter_wall")
            kns = sorted({k for r in rows for k in r["kernels"]})
            ks = "  ".join(f"{k} {1e3 * statistics.median(r['kernels'].get(k, 0.0) for r in rows):.1f}" for k in kns)
            dev = statistics.median(sum(r["kernels"].values()) for r in rows)
            shares = [r["filter_cpu"] / r["render_cpu"] for r in rows]
            print(f"  {s:22s} {t} ({py}: clpt from {names.get(t, '?')})")
            print(f"    render CPU {rc[0]:.3f} [{rc[1]:.3f}, {rc[2]:.3f}]  wall {rw[0]:.3f} [{rw[1]:.3f}, {rw[2]:.3f}]")
            print(f"    filter CPU {1e3 * fc[0]:.1f} ms [{1e3 * fc[1]:.1f}, {1e3 * fc[2]:.1f}]  wall {1e3 * fw[0]:.1f} ms "
                  f"[{1e3 * fw[1]:.1f}, {1e3 * fw[2]:.1f}]  device (kernels) {1e3 * dev:.1f} ms: {ks}")
            print(f"    share of the render (CPU, medians' ratio) {100 * fc[0] / rc[0]:.2f}%  per-round ratios: median "
                  f"{100 * statistics.median(shares):.2f}% [{100 * min(shares):.2f}, {100 * max(shares):.2f}]; "
                  f"wall {100 * fw[0] / rw[0]:.2f}%")
            for r in rows:
                if "profile" in r:
                    print("\n".join("      " + x for x in r["profile"].splitlines()[:30] if x.strip()))
                    break
    return 0


if __name__ == "__main__":
    sys.exit(main())
