"""`clpt bench`: throughput and kernel build times, per device and build.

- cold build: in a fresh subprocess whose clpt and PoCL caches are empty
  folders; the program build and the first launch are reported apart (PoCL
  generates machine code lazily at a kernel's first launch).
- warm build: in this process, from the build cache.
- steady state: after a warm-up launch, every configuration renders in turn,
  round after round (so that a machine whose speed drifts affects them all
  alike); each round times one pass on the host around the kernel and its
  small stats read-back. Medians and ranges over the rounds are reported, in
  samples/s and rays/s (camera, bounce and shadow rays, counted by the kernel).
"""

from __future__ import annotations

import itertools
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from .constants import LUMA


def _cold_build_child(scene: str, device, lanes, precision, kernel, nee) -> dict:
    from .render import Renderer

    t0 = time.perf_counter()
    r = Renderer(scene, device=device, lanes=lanes, precision=precision, kernel=kernel, nee=nee)
    t_build = time.perf_counter() - t0
    res = r.render(1, width=16, height=16)
    return {"build_seconds": t_build, "first_launch_seconds": res.stats.first_launch_seconds}


def cold_build(scene: str, device, lanes, precision, kernel, nee) -> dict | None:
    """Build and first launch in a fresh process with empty caches."""
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, CLPT_CACHE_DIR=os.path.join(tmp, "clpt"), POCL_CACHE_DIR=os.path.join(tmp, "pocl"))
        code = ("import json; from clpt.bench import _cold_build_child; "
                f"print(json.dumps(_cold_build_child({scene!r}, {device!r}, {lanes!r}, {precision!r}, "
                f"{kernel!r}, {nee!r})))")
        p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
        if p.returncode != 0:
            print(f"clpt bench: cold build failed:\n{p.stderr.strip()}", file=sys.stderr)
            return None
        return json.loads(p.stdout.strip().splitlines()[-1])


def measure(scenes, *, device=None, lanes=(None,), kernels=("specialized",), precision="float", nee=True,
            width=256, height=256, max_depth=8, rounds=5, pass_seconds=0.3, cold=True) -> list[dict]:
    from .device import select_devices
    from .render import Renderer

    rows, runners = [], []
    for dev, scene, n_lanes, kernel in itertools.product(select_devices(device), scenes, lanes, kernels):
        row = {"scene": scene, "kernel": kernel, "resolution": f"{width}x{height}", "max_depth": max_depth}
        if cold:
            c = cold_build(scene, device, n_lanes, precision, kernel, nee)
            if c:
                row["cold_build_seconds"] = c["build_seconds"]
                row["cold_first_launch_seconds"] = c["first_launch_seconds"]
        r = Renderer(scene, device=dev, lanes=n_lanes, precision=precision, kernel=kernel, nee=nee)
        r.render(1, width=width, height=height, max_depth=max_depth)  # warm-up: the lazy device compile
        warm = Renderer(scene, device=dev, lanes=n_lanes, precision=precision, kernel=kernel, nee=nee)
        row["warm_build_seconds"] = warm.states[0].build.seconds
        row["warm_build_cache_hit"] = bool(warm.states[0].build.cache_hit)
        # Pass size for about pass_seconds, from a timed 1-sample pass.
        probe = r.render(1, width=width, height=height, max_depth=max_depth)
        spp = max(1, int(pass_seconds / max(probe.stats.render_seconds, 1e-6)))
        row.update(device=r.states[0].dctx.label, features=r.features.describe(), lanes=r.features.lanes,
                   pass_spp=spp, rates=[], ray_rates=[])
        rows.append(row)
        runners.append(r)
    for i in range(rounds):
        for row, r in zip(rows, runners):
            res = r.render(row["pass_spp"], width=width, height=height, max_depth=max_depth, seed=i + 1,
                           pass_seconds=1e9)
            passes = res.stats.passes[1:] or res.stats.passes  # after the 1-sample probe pass
            secs = sum(p[3] for p in passes)
            samples = sum(p[2] for p in passes) * width * height
            row["rates"].append(samples / secs / 1e6)
            row["ray_rates"].append(res.stats.rays / res.stats.render_seconds / 1e6)
            row["rays_per_sample"] = res.stats.rays / max(res.samples, 1)
            row["camera_rays"], row["bounce_rays"], row["shadow_rays"] = (
                res.stats.camera_rays, res.stats.bounce_rays, res.stats.shadow_rays)
            row["nonfinite"] = res.stats.nonfinite
    for row in rows:
        row["msamples_per_s"] = statistics.median(row["rates"])
        row["msamples_per_s_range"] = [min(row["rates"]), max(row["rates"])]
        row["mrays_per_s"] = statistics.median(row.pop("ray_rates"))
    return rows


def _split(s, conv=str):
    return tuple(conv(x) for x in s.split(",")) if s else (None,)


def run_bench(a) -> int:
    from .resources import shipped_scenes

    scenes = shipped_scenes() if a.scene == ["all"] else a.scene
    rows = measure(scenes, device=a.device, lanes=_split(a.lanes, int), kernels=_split(a.kernel),
                   precision=a.precision, nee=not a.no_nee, width=a.width, height=a.height,
                   max_depth=a.max_depth, rounds=a.rounds, cold=not a.no_cold)
    if a.json:
        print(json.dumps(rows, indent=2))
        return 0
    for r in rows:
        lo, hi = r["msamples_per_s_range"]
        print(f"{r['scene']} on {r['device']}")
        print(f"  kernel      {r['features']}")
        print(f"  throughput  {r['msamples_per_s']:.3f} Msamples/s (range {lo:.3f}-{hi:.3f} over {a.rounds} rounds), "
              f"{r['mrays_per_s']:.2f} Mrays/s")
        print(f"  rays        {r['rays_per_sample']:.2f} per sample: camera {r['camera_rays']}, bounce "
              f"{r['bounce_rays']}, shadow {r['shadow_rays']} (last round)")
        if "cold_build_seconds" in r:
            print(f"  cold build  {r['cold_build_seconds']:.3f} s program + {r['cold_first_launch_seconds']:.3f} s "
                  f"first launch (device code generation)")
        print(f"  warm build  {r['warm_build_seconds']:.3f} s "
              f"({'cache hit' if r['warm_build_cache_hit'] else 'cache miss'})")
        if r["nonfinite"]:
            print(f"  non-finite  {r['nonfinite']} samples dropped")
    return 0


# --- photon mapping -------------------------------------------------------------------------


def measure_photon_builds(scene, counts, *, device=None, repeats=3) -> list[dict]:
    """Device times of the photon pass and of the grid build, per photon count
    (medians over `repeats` builds with different seeds)."""
    from .photons import PhotonSettings
    from .render import Renderer

    r = Renderer(scene, device=device)
    if not r.features.photons:
        raise ValueError(f"{scene}: no caustic casters, so no photon map to measure")
    st = r.states[0]
    rows = []
    for n in counts:
        s = PhotonSettings(count=int(n))
        infos = [st.build_photons(seed, s, s.radius_for(r.packed.size), 1) for seed in range(repeats + 1)][1:]
        rows.append({"photons": int(n), "stored": infos[-1]["stored"],
                     "trace_ms": statistics.median(i["trace_seconds"] for i in infos) * 1e3,
                     "grid_ms": statistics.median(i["grid_seconds"] for i in infos) * 1e3})
    return rows


def _pass_rate(res) -> float:
    """Samples per second of a render's passes (the 1-sample probe pass left out)."""
    passes = res.stats.passes[1:] or res.stats.passes
    return sum(p[2] for p in passes) * res.image.shape[0] * res.image.shape[1] / sum(p[3] for p in passes)


def measure_gather_cost(scene, *, device=None, width=128, height=128, spp=64, rounds=3) -> dict:
    """Per-sample time of path tracing alone and with the photon gather in
    every sample (online), in interleaved rounds; the difference is the gather."""
    from .photons import PhotonSettings
    from .render import Renderer

    pt = Renderer(scene, device=device, photons=False)
    pm = Renderer(scene, device=device)
    for r in (pt, pm):
        r.render(1, width=width, height=height)
    t_pt, t_pm = [], []
    for i in range(rounds):
        t_pt.append(1 / _pass_rate(pt.render(spp, width=width, height=height, seed=i, pass_seconds=1e9)))
        t_pm.append(1 / _pass_rate(pm.render(spp, width=width, height=height, seed=i, pass_seconds=1e9,
                                             photons=PhotonSettings(mode="online"))))
    a, b = statistics.median(t_pt), statistics.median(t_pm)
    return {"path_tracing_us_per_sample": a * 1e6, "with_gather_us_per_sample": b * 1e6,
            "gather_us_per_sample": (b - a) * 1e6}


def caustic_reference(scene, *, device=None, width=128, height=128, max_depth=64, reference=None, ref_spp=16384):
    """A path-traced reference (no photon map made it) and its caustic
    region: the 3% of pixels where plain path tracing is noisiest (relative
    per-sample variance). Read from / saved to `reference` (an EXR holding
    the image and, as a fourth channel, the per-sample luminance variance)."""
    from pathlib import Path

    from .image import load_image, save_image
    from .render import Renderer

    ref_path = Path(reference) if reference else None
    if ref_path is not None and ref_path.exists():
        data = load_image(ref_path).astype(np.float64)
        img, var = data[..., :3], data[..., 3]
    else:
        res = Renderer(scene, device=device, photons=False).render(ref_spp, width=width, height=height, seed=12345,
                                                                   max_depth=max_depth)
        img, var = res.image.astype(np.float64), res.lum_var.astype(np.float64)
        if ref_path is not None:
            save_image(ref_path, np.dstack([img, var]).astype(np.float32),
                       metadata={"clpt:reference_spp": ref_spp, "clpt:max_depth": max_depth})
    lum = img @ LUMA
    rel = var / np.maximum(lum, 1e-3) ** 2
    return img, rel >= np.quantile(rel, 0.97)


def caustic_equal_time(scene, *, device=None, width=128, height=128, seconds=(2.0, 4.0, 16.0), reference=None,
                       ref_spp=16384, max_depth=64, methods=None) -> dict:
    """relMSE against a path-traced reference (caustic_reference), in the
    caustic region and over the whole image, for path tracing alone and the
    photon methods, each rendered for the same wall time (the pilot's time
    counted in)."""
    from . import metrics
    from .photons import PhotonSettings
    from .render import Renderer

    ref, region = caustic_reference(scene, device=device, width=width, height=height, max_depth=max_depth,
                                    reference=reference, ref_spp=ref_spp)
    pm = Renderer(scene, device=device)
    pt = Renderer(scene, device=device, photons=False)
    methods = methods or {
        "path tracing": None,
        "merging (default: MIS, progressive, pilot)": PhotonSettings(),
        "merging, forced (no pilot)": PhotonSettings(pilot=False),
        "merging, first vertex only": PhotonSettings(pilot=False, merge_vertices=1),
        "owned map, online (10^6 photons)": PhotonSettings(mode="online"),
        "owned map, progressive": PhotonSettings(mode="online", progressive=True, count=100_000),
        "owned map, offline": PhotonSettings(mode="offline"),
    }
    for r in (pt, pm):  # the lazy device compiles, not timed
        r.render(1, width=width, height=height, max_depth=max_depth)
    pm.render(4, width=width, height=height, max_depth=max_depth, photons=PhotonSettings(mode="offline", offline_spp=1))
    out = {"caustic_pixels": int(region.sum()), "runs": []}
    for t in seconds:
        for name, ps in methods.items():
            r = pt if ps is None else pm
            res = r.render(1 << 24, width=width, height=height, seed=7, time_limit=t, photons=ps,
                           max_depth=max_depth)
            img = res.image.astype(np.float64)
            out["runs"].append({"method": name, "seconds": round(res.stats.render_seconds, 2),
                                "spp": float(res.sample_count.mean()),
                                "relmse_caustic": metrics.relmse(img[region], ref[region]),
                                "relmse_image": metrics.relmse(img, ref),
                                "choice": (res.stats.photon_pilot or {}).get("choice")})
    return out


def run_bench_photons(a) -> int:
    counts = [int(float(c)) for c in a.counts.split(",")]
    builds = measure_photon_builds(a.scene, counts, device=a.device)
    gather = measure_gather_cost(a.scene, device=a.device, width=a.width, height=a.height)
    result = {"builds": builds, "gather": gather}
    if a.equal_time:
        result["equal_time"] = caustic_equal_time(a.scene, device=a.device, width=a.width, height=a.height,
                                                  seconds=[float(s) for s in a.equal_time.split(",")],
                                                  reference=a.reference, ref_spp=a.ref_spp, max_depth=a.max_depth)
    if a.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"photon maps of {a.scene} (device times, medians of 3 builds):")
    for b in builds:
        print(f"  {b['photons']:>10} photons: {b['stored']:>10} stored, photon pass {b['trace_ms']:8.1f} ms, "
              f"grid build {b['grid_ms']:7.1f} ms")
    print(f"gather ({a.width}x{a.height}, online, default settings): path tracing "
          f"{gather['path_tracing_us_per_sample']:.3f} us/sample, with gather {gather['with_gather_us_per_sample']:.3f}"
          f" us/sample: the gather costs {gather['gather_us_per_sample']:.3f} us/sample")
    if a.equal_time:
        et = result["equal_time"]
        print(f"equal-time relMSE against the path-traced reference ({et['caustic_pixels']} caustic pixels):")
        base = {}
        for run in et["runs"]:
            key = run["seconds"] if run["method"] == "path tracing" else None
            if key is not None:
                base = run
            gain = (f"  (vs path tracing: caustic {base['relmse_caustic'] / run['relmse_caustic']:.2f}x, "
                    f"image {base['relmse_image'] / run['relmse_image']:.2f}x)") if base else ""
            print(f"  {run['method']:44s} {run['seconds']:6.2f} s {run['spp']:8.1f} spp  relMSE caustic "
                  f"{run['relmse_caustic']:.3e}, image {run['relmse_image']:.3e}{gain}")
    return 0
