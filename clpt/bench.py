"""`clpt bench`: throughput and kernel build times, per device.

- cold build: in a fresh subprocess whose clpt and PoCL caches are empty
  folders; it reports the program build and the first launch separately
  (PoCL generates machine code lazily at a kernel's first launch).
- warm build: in this process, from the build cache.
- steady state: a render of the scene after a warm-up launch, timed pass by
  pass on the host around each kernel and its small stats read-back; reports
  samples/s and rays/s (camera, bounce and shadow rays, counted by the kernel).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time


def _cold_build_child(scene: str, device, lanes, precision, kernel, nee) -> dict:
    from .render import Renderer

    t0 = time.perf_counter()
    r = Renderer(scene, device=device, lanes=lanes, precision=precision, kernel=kernel, nee=nee)
    t_build = time.perf_counter() - t0
    res = r.render(1, width=16, height=16)
    return {"build_seconds": t_build, "first_launch_seconds": res.stats.first_launch_seconds}


def cold_build(scene: str, device, lanes, precision, kernel, nee) -> dict | None:
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, CLPT_CACHE_DIR=os.path.join(tmp, "clpt"), POCL_CACHE_DIR=os.path.join(tmp, "pocl"))
        code = ("import json, sys; from clpt.bench import _cold_build_child; "
                f"print(json.dumps(_cold_build_child({scene!r}, {device!r}, {lanes!r}, {precision!r}, "
                f"{kernel!r}, {nee!r})))")
        p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
        if p.returncode != 0:
            print(f"clpt bench: cold build failed:\n{p.stderr.strip()}", file=sys.stderr)
            return None
        return json.loads(p.stdout.strip().splitlines()[-1])


def measure(scene, *, device=None, lanes=None, precision="float", kernel="specialized", nee=True,
            width=256, height=256, max_depth=8, seconds=3.0, cold=True) -> list[dict]:
    from .device import select_devices
    from .render import Renderer
    from .scene import load_scene

    sc = load_scene(scene) if isinstance(scene, str) else scene
    results = []
    for dev in select_devices(device):
        row = {}
        if cold and isinstance(scene, str):
            c = cold_build(scene, dev.name if device is None else device, lanes, precision, kernel, nee)
            if c:
                row["cold_build_seconds"] = c["build_seconds"]
                row["cold_first_launch_seconds"] = c["first_launch_seconds"]
        r = Renderer(sc, device=dev, lanes=lanes, precision=precision, kernel=kernel, nee=nee)
        r.render(1, width=width, height=height, max_depth=max_depth)  # warm-up: the lazy device compile
        t0 = time.perf_counter()
        r2 = Renderer(sc, device=dev, lanes=lanes, precision=precision, kernel=kernel, nee=nee)
        row["warm_build_seconds"] = time.perf_counter() - t0
        row["warm_build_cache_hit"] = bool(r2.states[0].build.cache_hit)
        res = r.render(1 << 20, width=width, height=height, max_depth=max_depth, time_limit=seconds)
        st = res.stats
        passes = st.passes[1:] or st.passes  # the first pass is a one-sample pass-size probe
        secs = sum(p[3] for p in passes)
        samples = sum(p[2] for p in passes) * width * height
        row.update({
            "device": r.states[0].dctx.label,
            "kernel": r.features.describe(),
            "resolution": f"{width}x{height}",
            "max_depth": max_depth,
            "spp": res.spp,
            "msamples_per_s": samples / secs / 1e6,
            "mrays_per_s": st.rays / st.render_seconds / 1e6,
            "camera_rays": st.camera_rays, "bounce_rays": st.bounce_rays, "shadow_rays": st.shadow_rays,
            "rays_per_sample": st.rays / max(res.samples, 1),
            "nonfinite": st.nonfinite,
        })
        results.append(row)
    return results


def run_bench(a) -> int:
    rows = measure(a.scene, device=a.device, lanes=a.lanes, precision=a.precision, kernel=a.kernel,
                   nee=not a.no_nee, width=a.width, height=a.height, max_depth=a.max_depth, seconds=a.seconds,
                   cold=not a.no_cold)
    if a.json:
        print(json.dumps(rows, indent=2))
        return 0
    for r in rows:
        print(f"device        {r['device']}")
        print(f"kernel        {r['kernel']}")
        print(f"scene         {a.scene} {r['resolution']}, max depth {r['max_depth']}, {r['spp']} spp measured")
        print(f"throughput    {r['msamples_per_s']:.3f} Msamples/s, {r['mrays_per_s']:.3f} Mrays/s "
              f"({r['rays_per_sample']:.2f} rays/sample: camera {r['camera_rays']}, bounce {r['bounce_rays']}, "
              f"shadow {r['shadow_rays']})")
        if "cold_build_seconds" in r:
            print(f"cold build    {r['cold_build_seconds']:.3f} s program + {r['cold_first_launch_seconds']:.3f} s "
                  f"first launch (device code generation)")
        print(f"warm build    {r['warm_build_seconds']:.3f} s "
              f"({'cache hit' if r['warm_build_cache_hit'] else 'cache miss'})")
        if r["nonfinite"]:
            print(f"non-finite    {r['nonfinite']} samples dropped")
        print()
    return 0
