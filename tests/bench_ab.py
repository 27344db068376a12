"""A/B speed of two clpt trees on a shared, noisy machine: the same renders
from each tree's own environment in turn, many times, and medians of all.

    python tests/bench_ab.py --a /tmp/base/.venv/bin/python --b .venv/bin/python \\
        --device intel --runs 12 all

Each run starts one process per tree (the order alternating run by run, AB
BA AB ..., so drift in the machine's load falls on both alike), which
renders every scene asked for once to warm up and then `--reps` times,
each render timed in wall seconds and in this process's CPU seconds (every
thread's: the OpenCL runtime's workers run in it). Samples per CPU second
is the figure to compare on a machine other jobs share: waiting for a core
another process holds costs wall time, not CPU time. Renders are `clpt
bench`'s: 256x256, depth 8, the device's predicted default lanes
(CLPT_TUNE=query: no measured tuning, which could choose different widths
for the two trees), photon mapping as the scene has it; each tree builds
into a build cache of its own. Prints per scene the medians of both trees
with their ranges, the ratio of medians, and the median of the per-run
ratios (pairs a few seconds apart).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

CHILD = r"""
import json, os, sys, time, warnings
warnings.simplefilter("ignore")
import clpt
from clpt.resources import shipped_scenes
device, reps, width, height, depth = sys.argv[1], int(sys.argv[2]), 256, 256, 8
spp = json.loads(sys.argv[3])
scenes = shipped_scenes() if sys.argv[4:] == ["all"] else sys.argv[4:]
renderers = {s: clpt.Renderer(s, device=device) for s in scenes}
for s, r in renderers.items():
    r.render(1, width=width, height=height, max_depth=depth, seed=1)  # first launches, photon kernels
out = {s: {"lanes": r.features.lanes, "spp": spp.get(s, 4), "wall": [], "cpu": []} for s, r in renderers.items()}
for rep in range(reps):
    for s, r in renderers.items():
        c0, w0 = time.process_time(), time.perf_counter()
        r.render(out[s]["spp"], width=width, height=height, max_depth=depth, seed=rep + 2)
        out[s]["cpu"].append(time.process_time() - c0)
        out[s]["wall"].append(time.perf_counter() - w0)
print(json.dumps(out))
"""


def child(python: str, scenes, device: str, reps: int, spp: dict, cache: str) -> dict:
    env = dict(os.environ, CLPT_TUNE="query", CLPT_CACHE_DIR=cache)
    cmd = [python, "-c", CHILD, device, str(reps), json.dumps(spp), *scenes]
    # From a neutral folder: python -c puts the working directory first on sys.path, and a
    # checkout there would be imported by both trees.
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=tempfile.gettempdir())
    if p.returncode != 0:
        sys.exit(f"{python} failed:\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def _fmt(v):
    return f"{statistics.median(v):7.3f} ({min(v):.3f}-{max(v):.3f})"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--a", required=True, help="the A tree's python (before)")
    ap.add_argument("--b", required=True, help="the B tree's python (after)")
    ap.add_argument("--device", default="intel")
    ap.add_argument("--runs", type=int, default=12)
    ap.add_argument("--reps", type=int, default=2, help="timed renders per scene and run")
    ap.add_argument("--seconds", type=float, default=0.6, help="CPU seconds a timed render should take")
    ap.add_argument("--json", default=None, help="write every render's times here")
    a = ap.parse_args(argv)
    caches = {k: tempfile.mkdtemp(prefix=f"clpt-ab-{k}-") for k in "ab"}
    # Samples per render: from one render of each scene with tree A.
    probe = child(a.a, a.scenes, a.device, 1, {}, caches["a"])
    spp = {s: max(1, round(4 * a.seconds / v["cpu"][0])) for s, v in probe.items()}
    rates = {}   # (scene, tree, "cpu"|"wall") -> [Msamples per second of every render]
    pairs = {}   # (scene, metric) -> [per-run ratio B/A of the medians]
    lanes = {}
    for run in range(a.runs):
        order = "ab" if run % 2 == 0 else "ba"
        got = {k: child(getattr(a, k), a.scenes, a.device, a.reps, spp, caches[k]) for k in order}
        for scene, v in got["a"].items():
            n = spp[scene] * 256 * 256 / 1e6
            for metric in ("cpu", "wall"):
                run_rates = {}
                for k in "ab":
                    r = [n / t for t in got[k][scene][metric]]
                    rates.setdefault((scene, k, metric), []).extend(r)
                    run_rates[k] = statistics.median(r)
                pairs.setdefault((scene, metric), []).append(run_rates["b"] / run_rates["a"])
            lanes[scene] = (v["lanes"], got["b"][scene]["lanes"])
        print(f"run {run + 1}/{a.runs} done ({order})", file=sys.stderr, flush=True)
    for metric, unit in (("cpu", "Msamples per CPU second"), ("wall", "Msamples per wall second")):
        print(f"\n{a.device}: {a.runs} runs x {a.reps} renders per tree and scene; {unit}, medians (ranges)")
        print(f"{'scene':34s} {'lanes':>5s} {'spp':>4s} {'A (before)':>22s} {'B (after)':>22s} {'B/A':>6s} "
              f"{'per-run B/A':>18s}")
        for scene in lanes:
            ra, rb = rates[(scene, "a", metric)], rates[(scene, "b", metric)]
            pr = pairs[(scene, metric)]
            la, lb = lanes[scene]
            print(f"{scene:34s} {lb if la == lb else f'{la}/{lb}':>5} {spp[scene]:4d} {_fmt(ra)} {_fmt(rb)} "
                  f"{statistics.median(rb) / statistics.median(ra):6.3f} "
                  f"{statistics.median(pr):.3f} ({min(pr):.2f}-{max(pr):.2f})")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"device": a.device, "spp": spp,
                       "rates": {"|".join(k): v for k, v in rates.items()},
                       "pairs": {"|".join(k): v for k, v in pairs.items()}}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
