"""clpt against Mitsuba 3 LLVM on the same scene file, in the same run: path
tracing's samples per CPU second, best of N, and the ratio.

    python tests/bench_mitsuba.py SCENE [SCENE ...] [--device intel] [--rounds 5]
        [--spp 16] [--max-depth D] [-D NAME=VALUE ...] [--lanes N] [--sampler independent]
        [--mitsuba-python /work/main/.venv/bin/python]

SCENE is a Mitsuba 3 XML file both renderers load (-D parameters go to
both), `gallery` (tests/realscene.py's hall, generated into its cache
folder if missing), `bunny` (tests/data/cbox_bunny.xml with the shared
bunny) or `cornell_box` (clpt's shipped scene against Mitsuba's own
cornell_box(), the same scene). --max-depth is clpt's (scattering events);
Mitsuba gets one more, the same bounces; without it the file's depth holds.

Mitsuba runs in a process of its own (its Python, variant llvm_ad_rgb),
which stays up and renders when told, so the two alternate round by round
(drift in the machine's load falls on both). Each render is timed in wall
seconds and in CPU seconds of its own process (every thread's: OpenCL's and
Dr.Jit's workers run in them); on a machine other jobs share, samples per CPU
second is the figure to compare. The first render of each (kernel build,
JIT) is left out. clpt path traces (photons=False), at the tuner's lanes
unless --lanes. Also printed: the whole-image means of both renderers with
their standard errors over the rounds, and their difference in sigmas.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

MITSUBA_PYTHON = "/work/main/.venv/bin/python"
LLVM = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"

CHILD = r"""
import json, sys, time
import drjit as dr
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
spec = json.loads(sys.argv[1])
if spec["scene"] == "cornell_box":
    d = mi.cornell_box()
    d["sensor"]["film"]["width"], d["sensor"]["film"]["height"] = spec["width"], spec["height"]
    scene = mi.load_dict(d)
else:
    scene = mi.load_file(spec["scene"], **spec["params"])
integ = mi.load_dict({"type": "path", "max_depth": spec["max_depth"] + 1}) if spec["max_depth"] is not None \
    else scene.integrator()
if spec["scene"] == "cornell_box" and spec["max_depth"] is None:
    integ = mi.load_dict({"type": "path", "max_depth": 9})
size = scene.sensors()[0].film().crop_size()
print(json.dumps({"pixels": int(size[0]) * int(size[1])}), flush=True)
for line in sys.stdin:
    seed, spp = map(int, line.split())
    c, w = time.process_time(), time.perf_counter()
    img = mi.render(scene, integrator=integ, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    cpu, wall = time.process_time() - c, time.perf_counter() - w
    mean = float(img.numpy().mean())
    print(json.dumps({"cpu": cpu, "wall": wall, "mean": mean}), flush=True)
"""


def resolve(scene: str, params: dict) -> tuple[str, dict]:
    """(a path or 'cornell_box', the parameters) for a SCENE argument."""
    if scene == "gallery":
        import realscene
        path = realscene.default_out() / "gallery.xml"
        if not path.is_file():
            realscene.generate(path.parent, log=lambda s: print(s, file=sys.stderr))
        return str(path), params
    if scene == "bunny":
        import realscene
        b = realscene.bunny_path()
        if b is None:
            raise SystemExit("bench_mitsuba: the bunny box needs /work/shared/meshes/bunny.ply or $CLPT_BUNNY")
        return str(HERE / "data" / "cbox_bunny.xml"), {"bunny": str(b), **params}
    return scene, params


class MitsubaProc:
    def __init__(self, python, spec):
        env = dict(os.environ, DRJIT_LIBLLVM_PATH=os.environ.get("DRJIT_LIBLLVM_PATH", LLVM))
        self.p = subprocess.Popen([python, "-c", CHILD, json.dumps(spec)], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True, env=env)
        self.pixels = self._read()["pixels"]

    def _read(self):
        line = self.p.stdout.readline()
        if not line:
            raise SystemExit(f"bench_mitsuba: Mitsuba's process ended (status {self.p.wait()})")
        return json.loads(line)

    def render(self, seed, spp):
        self.p.stdin.write(f"{seed} {spp}\n")
        self.p.stdin.flush()
        return self._read()

    def close(self):
        self.p.stdin.close()
        self.p.wait()


def bench(scene, *, device=None, rounds=5, spp=16, max_depth=None, params=None, lanes=None,
          mitsuba_python=MITSUBA_PYTHON, log=print, sampler="stratified") -> dict:
    import clpt

    path, params = resolve(scene, dict(params or {}))
    sc = clpt.load_scene(path if path != "cornell_box" else "cornell_box",
                         **({"params": params} if path.endswith(".xml") else {}))
    r = clpt.Renderer(sc, device=device, photons=False, lanes=lanes, sampler=sampler)
    kw = {} if max_depth is None else {"max_depth": max_depth}
    if path == "cornell_box" and max_depth is None:
        kw["max_depth"] = 8
    first = r.render(1, seed=0, **kw)  # the device's first launch
    h, w = first.image.shape[:2]
    spec = {"scene": path, "params": params, "max_depth": max_depth, "width": w, "height": h}
    out = {"scene": scene, "file": path, "width": w, "height": h, "spp": spp,
           "max_depth": kw.get("max_depth", r.scene.settings.max_depth) if hasattr(r.scene, "settings") else max_depth,
           "clpt_kernel": r.features.describe(), "clpt": [], "mitsuba": []}
    m = MitsubaProc(mitsuba_python, spec) if mitsuba_python else None
    if m:
        if m.pixels != w * h:
            raise SystemExit(f"bench_mitsuba: image sizes differ (clpt {w}x{h}, Mitsuba {m.pixels} pixels)")
        m.render(0, 1)  # JIT
    for i in range(rounds):
        c, t = time.process_time(), time.perf_counter()
        res = r.render(spp, seed=i + 1, pass_seconds=1e9, **kw)
        cpu, wall = time.process_time() - c, time.perf_counter() - t
        out["clpt"].append({"cpu": cpu, "wall": wall, "mean": float(res.image.mean())})
        if m:
            out["mitsuba"].append(m.render(i + 1, spp))
        log(f"  round {i + 1}: clpt {w * h * spp / cpu / 1e6:.3f} Msamples/CPU-s"
            + (f", Mitsuba {w * h * spp / out['mitsuba'][-1]['cpu'] / 1e6:.3f}" if m else ""))
    if m:
        m.close()
    for who in ("clpt", "mitsuba"):
        runs = out[who]
        if not runs:
            continue
        out[f"{who}_msamples_per_cpu_s"] = max(w * h * spp / x["cpu"] / 1e6 for x in runs)
        out[f"{who}_msamples_per_wall_s"] = max(w * h * spp / x["wall"] / 1e6 for x in runs)
        means = [x["mean"] for x in runs]
        out[f"{who}_mean"] = statistics.fmean(means)
        out[f"{who}_mean_se"] = statistics.stdev(means) / len(means) ** 0.5 if len(means) > 1 else float("nan")
    if m:
        out["ratio_cpu"] = out["clpt_msamples_per_cpu_s"] / out["mitsuba_msamples_per_cpu_s"]
        out["ratio_wall"] = out["clpt_msamples_per_wall_s"] / out["mitsuba_msamples_per_wall_s"]
        d = out["clpt_mean"] - out["mitsuba_mean"]
        out["mean_diff_sigma"] = d / float(np.hypot(out["clpt_mean_se"], out["mitsuba_mean_se"]))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--device", default=None)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--max-depth", type=int, default=None)
    ap.add_argument("--lanes", type=int, default=None)
    ap.add_argument("--sampler", default="stratified", help="clpt's (Mitsuba's is the scene's: independent in "
                                                            "cornell_box() and the files here)")
    ap.add_argument("-D", dest="defs", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--mitsuba-python", default=MITSUBA_PYTHON, help="'' to time clpt only")
    ap.add_argument("--json", default=None, help="write the results here")
    a = ap.parse_args()
    params = dict(d.split("=", 1) for d in a.defs)
    rows = []
    for s in a.scenes:
        print(f"{s}:", flush=True)
        o = bench(s, device=a.device, rounds=a.rounds, spp=a.spp, max_depth=a.max_depth, params=params,
                  lanes=a.lanes, mitsuba_python=a.mitsuba_python or None, sampler=a.sampler)
        rows.append(o)
        line = (f"{s} {o['width']}x{o['height']} {o['spp']} spp, {o['clpt_kernel']}\n"
                f"  clpt    {o['clpt_msamples_per_cpu_s']:.3f} Msamples/CPU-s ({o['clpt_msamples_per_wall_s']:.3f}/wall-s),"
                f" image mean {o['clpt_mean']:.5f} +- {o['clpt_mean_se']:.5f}")
        if "ratio_cpu" in o:
            line += (f"\n  Mitsuba {o['mitsuba_msamples_per_cpu_s']:.3f} Msamples/CPU-s "
                     f"({o['mitsuba_msamples_per_wall_s']:.3f}/wall-s), image mean {o['mitsuba_mean']:.5f} +- "
                     f"{o['mitsuba_mean_se']:.5f}\n  ratio {o['ratio_cpu']:.2f}x per CPU-s ({o['ratio_wall']:.2f}x "
                     f"per wall-s); means differ by {o['mean_diff_sigma']:+.1f} sigma")
        print(line, flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
