"""Measurements of the render engine (not part of the test suite).

    python tests/bench_engine.py kill 20         # SIGKILL/resume cycles through the CLI
    python tests/bench_engine.py checkpoint      # checkpoint cost and size
    python tests/bench_engine.py devices         # one vs two PoCL devices, and two processes
    python tests/bench_engine.py dask            # Dask overhead per range, 1 vs 2 workers

Each prints one JSON object. Timings are medians (and ranges) of interleaved rounds.
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))


def med(xs):
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs), "n": len(xs)}


def bench_kill(cycles: int):
    import numpy as np

    import clpt
    from test_checkpoint import clpt_cmd, kill_resume_cycles

    render = ["--spp", "500", "--width", "256", "--height", "192", "--seed", "5"]
    d = Path(tempfile.mkdtemp(prefix="clpt-kill-"))
    ref = d / "ref.exr"
    subprocess.run(clpt_cmd(*render, "-o", str(ref), "-q"), check=True)
    out = d / "k.exr"
    rows = []
    kills, resumes, seen, mid = kill_resume_cycles(out, cycles, seed=int(time.time()), log=rows.append,
                                                   render=render, every="0.01")
    same = bool(np.array_equal(clpt.load_image(out), clpt.load_image(ref)))
    return {"render": " ".join(render), "cycles": cycles, "kills": kills, "resumes": resumes,
            "checkpoints_read": seen, "kills_during_a_checkpoint_write": mid, "bit_identical": same, "log": rows}


def bench_checkpoint(rounds=3, size=512, seconds=8.0):
    import clpt

    r = clpt.Renderer("cornell_box")
    r.render(1, width=size, height=size)
    d = Path(tempfile.mkdtemp(prefix="clpt-ck-"))
    with_ck, without, stall, write, sizes = [], [], [], [], []
    for i in range(rounds):
        for mode in ("none", "ck"):
            kw = {"checkpoint": d / "c.ckpt", "checkpoint_every": 1.0} if mode == "ck" else {}
            res = r.render(1 << 20, width=size, height=size, time_limit=seconds, seed=i, **kw)
            rate = res.samples / res.stats.render_seconds
            (with_ck if mode == "ck" else without).append(rate)
            if mode == "ck":
                stall.append(100 * sum(c[0] for c in res.stats.checkpoints) / res.stats.render_seconds)
                write.append(1e3 * statistics.median(c[1] for c in res.stats.checkpoints))
                sizes.append(res.stats.checkpoints[-1][2] / (size * size / 1e6) / 1e6)
    return {"image": f"{size}x{size}", "checkpoint_every_s": 1.0, "samples_per_s_without": med(without),
            "samples_per_s_with": med(with_ck), "render_waits_percent": med(stall),
            "background_write_ms_each": med(write),
            "overhead_percent_from_rates": 100 * (1 - statistics.median(with_ck) / statistics.median(without)),
            "megabytes_per_megapixel": med(sizes)}


DEVICE_RUN = r"""
import json, sys, time, clpt
dev = sys.argv[1]
if dev in ("pocl", "pocl-all"):  # PoCL's first device, or all of them (whatever else is registered)
    devs = [d for d in clpt.device.select_devices("all") if "portable" in d.platform.name.lower()]
    dev = devs if dev == "pocl-all" else devs[0]
elif "#" in dev:  # one part of a split device: "intel/2#0"
    spec, k = dev.split("#")
    dev = clpt.device.select_devices(spec)[int(k)]
ex = sys.argv[3] if len(sys.argv) > 3 and sys.argv[3] != "-" else None
r = clpt.Renderer("cornell_box", device=dev)
r.render(2, width=256, height=256, executor=ex)
rates = []
for i in range(int(sys.argv[2])):
    t0 = time.perf_counter()
    res = r.render(384, width=256, height=256, seed=i, executor=ex)
    rates.append(res.samples / (time.perf_counter() - t0))
print(json.dumps({"devices": len(r.states), "rates": rates}))
"""


def bench_devices(rounds=3):
    out = {}
    split = {"POCL_DEVICES": "pthread pthread", "POCL_MAX_PTHREAD_COUNT": "1"}
    configs = {"one device, 1 thread": ({"POCL_MAX_PTHREAD_COUNT": "1"}, "pocl", "-"),
               "two devices, 1 thread each, one process": (split, "pocl-all", "-"),
               "two devices, 1 thread each, a process each": (split, "pocl-all", "processes"),
               "one device, 2 threads": ({"POCL_MAX_PTHREAD_COUNT": "2"}, "pocl", "-")}
    if os.environ.get("OCL_ICD_VENDORS"):  # Intel's CPU runtime registered: its device split in two by fission
        configs.update({"intel: one half (1 core)": ({}, "intel/2#0", "-"),
                        "intel: both halves, one process": ({}, "intel/2", "-"),
                        "intel: whole device": ({}, "intel", "-")})
    for _ in range(rounds):  # interleaved
        for name, (env, dev, ex) in configs.items():
            e = dict(os.environ, **env)
            e.pop("PYOPENCL_CTX", None)
            p = subprocess.run([sys.executable, "-c", DEVICE_RUN, dev, "2", ex], env=e, capture_output=True,
                               text=True)
            res = json.loads(p.stdout.strip().splitlines()[-1])
            out.setdefault(name, []).extend(res["rates"])
    res = {k: med(v) for k, v in out.items()}
    one = res["one device, 1 thread"]["median"]
    out = {"samples_per_s": res, "speedup_over_one_device": {k: v["median"] / one for k, v in res.items()
                                                              if not k.startswith("intel")}}
    if "intel: one half (1 core)" in res:
        half = res["intel: one half (1 core)"]["median"]
        out["intel_speedup_over_one_half"] = {k: v["median"] / half for k, v in res.items() if k.startswith("intel")}
    return out


def bench_dask(rounds=3):
    os.environ["POCL_MAX_PTHREAD_COUNT"] = "1"
    import distributed

    import clpt

    r = clpt.Renderer("cornell_box")
    r.render(2, width=128, height=128)
    out = {"in-process": [], "dask 1 worker": [], "dask 2 workers": []}
    over = []
    clusters = {n: distributed.Client(distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                                               dashboard_address=":0")) for n in (1, 2)}
    for c in clusters.values():
        r.render(4, width=128, height=128, executor=c)  # kernels built on the workers
    for i in range(rounds):
        res = r.render(1024, width=128, height=128, seed=i, pass_seconds=0.5)
        out["in-process"].append(res.samples / res.stats.render_seconds)
        for n, c in clusters.items():
            t0 = time.perf_counter()
            res = r.render(1024, width=128, height=128, seed=i, executor=c, pass_seconds=0.5)
            wall = time.perf_counter() - t0
            out[f"dask {n} worker{'s' if n > 1 else ''}"].append(res.samples / wall)
            if n == 1:  # one worker: the driver's wall time minus the device's, per range (start-up included)
                dev = sum(p[3] for p in res.stats.passes)
                over.append((wall - dev) / len(res.stats.passes) * 1e3)
    for c in clusters.values():
        c.close()
    rates = {k: med(v) for k, v in out.items()}
    return {"samples_per_s": rates, "overhead_ms_per_range_1_worker": med(over),
            "scaling_2_vs_1": statistics.median(out["dask 2 workers"]) / statistics.median(out["dask 1 worker"])}


if __name__ == "__main__":
    what = sys.argv[1]
    if what == "kill":
        print(json.dumps(bench_kill(int(sys.argv[2]) if len(sys.argv) > 2 else 10), indent=1))
    elif what == "checkpoint":
        print(json.dumps(bench_checkpoint(), indent=1))
    elif what == "devices":
        print(json.dumps(bench_devices(), indent=1))
    elif what == "dask":
        print(json.dumps(bench_dask(), indent=1))
    else:
        sys.exit(__doc__)
