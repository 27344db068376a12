"""`clpt bench`: throughput, per-kernel device times, memory and build times,
per scene, device and kernel variant; a table, CSV or JSON, and ratios
against an earlier run's JSON (--compare).

- variants: every combination of the lane widths, work-group sizes,
  precisions and kernel builds (specialized, generic) asked for, on every
  device asked for
  (``--device pocl,intel``). "auto" lanes or local size is the device's tuned
  default (clpt/tune.py), as a render without options gets it.
- steady state: after a warm-up render, every configuration renders in turn,
  round after round (so that a machine whose speed drifts affects them all
  alike). Samples/s are timed on the host around each pass (the kernel and
  its small stats read-back), after a one-sample probe pass; medians and
  ranges over the rounds. Rays/s count camera, bounce and shadow rays.
- kernels: device times of every kernel launch from OpenCL profiling events
  (path pass, photon pass, grid build, filter), the first launch of each
  (a lazy device compile on drivers that compile at a launch) left out;
  medians and ranges. The path
  pass (trace_paths) is given per sample per pixel of the timed passes.
- memory: device bytes per buffer after a render.
- cold build: in a fresh subprocess whose clpt and PoCL caches are empty
  folders (pyopencl's binary cache is not used at all), with the variant's
  resolved lanes and local size (no tuning measurement): the program build
  and the first launch apart (PoCL compiles its kernels into the build's
  binary, clpt/program.py, so its first launch compiles nothing; the
  photon program of a caustic scene builds in a child process, whose time
  is in the build's wall time).
- warm build: a second Renderer in this process, from the build cache.
- --mitsuba: Mitsuba 3 (its LLVM variant, if installed; never a
  dependency) renders its own cornell_box() at the same size and depth
  (its max_depth is clpt's plus one) in the same rounds.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from ..constants import LUMA


def _cold_build_child(scene: str, device, lanes, local_size, precision, kernel, nee, sampler="stratified") -> dict:
    from ..render import Renderer

    t0 = time.perf_counter()
    r = Renderer(scene, device=device, lanes=lanes, local_size=local_size, precision=precision, kernel=kernel,
                 nee=nee, sampler=sampler)
    t_build = time.perf_counter() - t0
    res = r.render(1, width=16, height=16)
    return {"build_seconds": t_build, "first_launch_seconds": res.stats.first_launch_seconds,
            "total_seconds": time.perf_counter() - t0}


def cold_build(scene: str, device: str, lanes, local_size, precision, kernel, nee,
               sampler: str = "stratified") -> dict | None:
    """Build and first launch in a fresh process with empty caches."""
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, CLPT_CACHE_DIR=os.path.join(tmp, "clpt"), POCL_CACHE_DIR=os.path.join(tmp, "pocl"),
                   PYOPENCL_NO_CACHE="1")
        args = ", ".join(repr(x) for x in (scene, device, lanes, local_size, precision, kernel, nee, sampler))
        code = f"import json; from clpt.tools.bench import _cold_build_child; print(json.dumps(_cold_build_child({args})))"
        p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
        if p.returncode != 0:
            print(f"clpt bench: cold build failed:\n{p.stderr.strip()}", file=sys.stderr)
            return None
        return json.loads(p.stdout.strip().splitlines()[-1])


def device_spec(dev) -> str:
    """The platform:device selection of a pyopencl Device."""
    import pyopencl as cl

    for pi, p in enumerate(cl.get_platforms()):
        for di, d in enumerate(p.get_devices()):
            if d == dev:
                return f"{pi}:{di}"
    raise ValueError(f"device {dev.name} not found")


def variant_label(v: dict) -> str:
    """A variant as asked for (auto choices unresolved), the key --compare matches on."""
    return f"lanes={v['lanes'] or 'auto'} local={v['local_size'] or 'auto'} {v['precision']} {v['kernel']}"


def _summary(values) -> dict:
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "n": len(values)}


def _kernel_summary(times: dict) -> dict:
    """Per kernel, ms per launch with the first launch left out (all if there is one)."""
    out = {}
    for name, v in times.items():
        v = [x for x in v if x == x]  # no profiling: nan
        if v:
            out[name] = {k: (x * 1e3 if k != "n" else x) for k, x in _summary(v[1:] or v).items()}
    return out


class _Mitsuba:
    """Mitsuba 3's cornell_box() at the bench's size and depth."""

    def __init__(self, width, height, max_depth):
        try:
            import mitsuba as mi
        except ImportError:
            raise SystemExit("clpt bench: --mitsuba needs Mitsuba 3 (pip install mitsuba); it is for measuring "
                             "only, never a dependency") from None
        variants = mi.variants()
        self.variant = next((v for v in ("llvm_ad_rgb", "llvm_rgb", "scalar_rgb") if v in variants), variants[0])
        mi.set_variant(self.variant)
        self.mi = mi
        box = mi.cornell_box()
        box["sensor"]["film"]["width"], box["sensor"]["film"]["height"] = width, height
        box["integrator"] = {"type": "path", "max_depth": max_depth + 1}
        self.scene = mi.load_dict(box)
        self.n_pix = width * height
        self.render(4)

    def render(self, spp: int) -> float:
        import drjit as dr

        t0 = time.perf_counter()
        img = self.mi.render(self.scene, spp=spp, seed=int(t0 * 1e3) & 0xFFFF)
        dr.eval(img)
        dr.sync_thread()
        return time.perf_counter() - t0


def measure(scenes, *, device=None, lanes=(None,), local_sizes=(None,), precisions=("float",),
            kernels=("specialized",), nee=True, sampler="stratified", width=256, height=256, max_depth=8, rounds=5,
            pass_seconds=0.3, cold=True, mitsuba=False, log=None) -> list[dict]:
    from ..device import select_devices
    from ..render import Renderer

    rows, runners = [], []
    combos = list(itertools.product(lanes, local_sizes, precisions, kernels))
    for dev, scene in itertools.product(select_devices(device), scenes):
        spec = device_spec(dev)
        for n_lanes, local, precision, kernel in combos:
            v = {"lanes": n_lanes, "local_size": local, "precision": precision, "kernel": kernel}
            r = Renderer(scene, device=dev, lanes=n_lanes, local_size=local, precision=precision, kernel=kernel,
                         nee=nee, sampler=sampler)
            st = r.states[0]
            row = {"scene": scene, "device": st.dctx.label, "platform": st.dctx.platform, "device_spec": spec,
                   "variant": variant_label(v), "resolution": f"{width}x{height}", "max_depth": max_depth,
                   **{k: x for k, x in v.items() if k not in ("lanes", "local_size")},
                   "lanes": st.features.lanes, "local_size": st.local, "tuning": st.tuning.describe(),
                   "features": r.features.describe()}
            if log:
                log(f"{scene} on {st.dctx.label}: {row['variant']} ({st.features.lanes} lanes, local {st.local})")
            if cold:
                c = cold_build(scene, spec, st.features.lanes, st.local, precision, kernel, nee, sampler)
                if c:
                    row["cold_build_seconds"] = c["build_seconds"]
                    row["cold_first_launch_seconds"] = c["first_launch_seconds"]
            first = r.render(1, width=width, height=height, max_depth=max_depth)  # warm-up: the lazy device compile
            warm = Renderer(scene, device=dev, lanes=st.features.lanes, local_size=st.local, precision=precision,
                            kernel=kernel, nee=nee, sampler=sampler)
            row["warm_build_seconds"] = warm.states[0].build.seconds
            row["warm_build_cache_hit"] = bool(warm.states[0].build.cache_hit)
            del warm
            # Pass size for about pass_seconds, from a timed 1-sample pass.
            probe = r.render(1, width=width, height=height, max_depth=max_depth)
            row["pass_spp"] = max(1, int(pass_seconds / max(probe.stats.render_seconds, 1e-6)))
            row["rates"], row["ray_rates"] = [], []
            # Their first launches (left out of the summary); the path pass per sample per pixel.
            row["_times"] = {k: list(x) for k, x in first.stats.kernel_seconds.items()}
            row["memory_bytes"] = st.buffer_bytes()
            rows.append(row)
            runners.append(r)
    mi = None
    if mitsuba:
        mi = _Mitsuba(width, height, max_depth)
        per = mi.render(1)
        mrow = {"scene": "cornell_box", "device": f"Mitsuba 3 ({mi.variant})", "platform": "Mitsuba 3",
                "variant": f"mitsuba {mi.variant} max_depth={max_depth + 1}", "resolution": f"{width}x{height}",
                "max_depth": max_depth, "pass_spp": max(1, int(pass_seconds / max(per, 1e-6))), "rates": [],
                "ray_rates": [], "_times": {}}
        rows.append(mrow)
        runners.append(mi)
    for i in range(rounds):
        for row, r in zip(rows, runners):
            if r is mi:
                row["rates"].append(row["pass_spp"] * mi.n_pix / mi.render(row["pass_spp"]) / 1e6)
                continue
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
            for k, x in res.stats.kernel_seconds.items():
                if k == "trace_paths":  # per sample per pixel
                    x = [t / p[2] for t, p in zip(x, res.stats.passes)]
                row["_times"].setdefault(k, []).extend(x)
    for row in rows:
        row["msamples_per_s"] = statistics.median(row["rates"])
        row["msamples_per_s_range"] = [min(row["rates"]), max(row["rates"])]
        rr = row.pop("ray_rates")
        if rr:
            row["mrays_per_s"] = statistics.median(rr)
        row["kernel_ms"] = _kernel_summary(row.pop("_times"))
    return rows


def _split(s, conv=str):
    if not s:
        return (None,)
    return tuple(None if x.strip() == "auto" else conv(x) for x in s.split(","))


def _short(device: str) -> str:
    return device.replace("(R)", "").replace("Processor ", "").replace("  ", " ")


def format_table(rows) -> str:
    head = ["scene", "device", "variant", "lanes", "local", "Msamples/s", "range", "Mrays/s", "path ms/spp",
            "cold build+launch s", "warm s", "device MiB"]
    lines = [head]
    for r in rows:
        lo, hi = r["msamples_per_s_range"]
        k = r.get("kernel_ms", {}).get("trace_paths")
        cold = (f"{r['cold_build_seconds']:.2f}+{r['cold_first_launch_seconds']:.2f}"
                if "cold_build_seconds" in r else "")
        mem = sum(r["memory_bytes"].values()) / 2**20 if r.get("memory_bytes") else None
        lines.append([r["scene"], _short(r["device"]), r["variant"], str(r.get("lanes", "")),
                      str(r.get("local_size", "")), f"{r['msamples_per_s']:.3f}", f"{lo:.2f}-{hi:.2f}",
                      f"{r['mrays_per_s']:.1f}" if "mrays_per_s" in r else "",
                      f"{k['median']:.2f}" if k else "", cold,
                      f"{r['warm_build_seconds']:.3f}" if "warm_build_seconds" in r else "",
                      f"{mem:.1f}" if mem is not None else ""])
    widths = [max(len(x[i]) for x in lines) for i in range(len(head))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in lines)


def format_kernels(rows) -> str:
    out = []
    for r in rows:
        if not r.get("kernel_ms"):
            continue
        out.append(f"{r['scene']} on {_short(r['device'])}, {r['variant']}:")
        for name, k in r["kernel_ms"].items():
            unit = "ms/spp" if name == "trace_paths" else "ms"
            out.append(f"  {name:16s} {k['median']:9.3f} {unit:6s} (range {k['min']:.3f}-{k['max']:.3f}, "
                       f"{k['n']} launches)")
    return "\n".join(out)


def format_memory(rows) -> str:
    out, seen = [], set()
    for r in rows:
        key = (r["scene"], r["device"], r.get("precision"))
        if not r.get("memory_bytes") or key in seen:
            continue
        seen.add(key)
        parts = ", ".join(f"{k} {v / 2**20:.2f}" for k, v in r["memory_bytes"].items())
        out.append(f"{r['scene']} on {_short(r['device'])} ({r.get('precision')}), MiB: {parts}")
    return "\n".join(out)


def to_csv(rows) -> str:
    kernels = sorted({k for r in rows for k in r.get("kernel_ms", {})})
    fields = ["scene", "device", "platform", "variant", "lanes", "local_size", "precision", "kernel",
              "msamples_per_s", "msamples_min", "msamples_max", "mrays_per_s", "cold_build_seconds",
              "cold_first_launch_seconds", "warm_build_seconds", "device_bytes"] + [f"{k}_ms" for k in kernels]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
    w.writeheader()
    for r in rows:
        flat = dict(r, msamples_min=r["msamples_per_s_range"][0], msamples_max=r["msamples_per_s_range"][1],
                    device_bytes=sum(r.get("memory_bytes", {}).values()) or "")
        for k in kernels:
            if k in r.get("kernel_ms", {}):
                flat[f"{k}_ms"] = r["kernel_ms"][k]["median"]
        w.writerow(flat)
    return buf.getvalue()


def compare(rows, old_rows) -> str:
    """Ratios new/old of samples/s and of each kernel's median time, per scene,
    device and variant found in both runs."""
    def key(r):  # rows of an older clpt bench (no variant): their resolved lanes and kernel
        v = r.get("variant") or variant_label({"lanes": r.get("lanes"), "local_size": None, "precision": "float",
                                                "kernel": r.get("kernel", "specialized")})
        return r["scene"], r["device"], v

    old = {key(r): r for r in old_rows}
    lines = [["scene", "device", "variant", "old Msamples/s", "new", "new/old", "kernels new/old (time)"]]
    missing = 0
    for r in rows:
        o = old.get((r["scene"], r["device"], r["variant"]))
        if o is None:
            missing += 1
            continue
        o.setdefault("kernel_ms", {})
        ks = ", ".join(f"{k} {r['kernel_ms'][k]['median'] / o['kernel_ms'][k]['median']:.2f}"
                       for k in r.get("kernel_ms", {}) if k in o.get("kernel_ms", {}) and o["kernel_ms"][k]["median"] > 0)
        lines.append([r["scene"], _short(r["device"]), r["variant"], f"{o['msamples_per_s']:.3f}",
                      f"{r['msamples_per_s']:.3f}", f"{r['msamples_per_s'] / o['msamples_per_s']:.2f}x", ks])
    widths = [max(len(x[i]) for x in lines) for i in range(len(lines[0]))]
    text = "\n".join("  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in lines)
    if missing:
        text += f"\n({missing} of {len(rows)} rows have no match in the old run)"
    return text


def run_bench(a) -> int:
    from ..resources import shipped_scenes

    scenes = shipped_scenes() if a.scene == ["all"] else a.scene
    old = None
    if a.compare:
        try:
            with open(a.compare) as f:
                old = json.load(f)
        except (OSError, ValueError) as e:
            raise SystemExit(f"clpt bench: cannot read {a.compare}: {e}") from None
    rows = measure(scenes, device=a.device, lanes=_split(a.lanes, int), local_sizes=_split(a.local_size, int),
                   precisions=tuple(a.precision.split(",")), kernels=_split(a.kernel),
                   nee=not a.no_nee, sampler=a.sampler or "stratified", width=a.width, height=a.height, max_depth=a.max_depth, rounds=a.rounds,
                   cold=not a.no_cold, mitsuba=a.mitsuba,
                   log=None if a.json or a.csv else (lambda m: print(m, file=sys.stderr)))
    if a.json:
        print(json.dumps(rows, indent=1))
    elif a.csv:
        print(to_csv(rows), end="")
    else:
        print(f"{len(rows)} configurations, {a.rounds} interleaved rounds each, medians (and ranges) of "
              f"samples/s at {a.width}x{a.height}, depth {a.max_depth}:")
        print(format_table(rows))
        print("\nkernel device times (profiling events, first launch left out):")
        print(format_kernels(rows))
        print("\ndevice memory per buffer:")
        print(format_memory(rows))
        tunings = {(r["device"], r.get("tuning")) for r in rows if r.get("tuning") and "lanes=auto" in r["variant"]}
        if tunings:
            print("\ntuned defaults:")
            for dev, t in sorted(tunings):
                print(f"  {_short(dev)}: {t}")
    if old is not None:
        print(("\n" if not (a.json or a.csv) else "") + f"against {a.compare}:",
              file=sys.stderr if a.json or a.csv else sys.stdout)
        print(compare(rows, old), file=sys.stderr if a.json or a.csv else sys.stdout)
    return 0


# --- photon mapping -------------------------------------------------------------------------


def measure_photon_builds(scene, counts, *, device=None, repeats=3) -> list[dict]:
    """Device times of the photon pass and of the grid build, per photon count
    (medians over `repeats` builds with different seeds)."""
    from ..photons import PhotonSettings
    from ..render import Renderer

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
    from ..photons import PhotonSettings
    from ..render import Renderer

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
    """A path-traced reference (no photon map made it) and the caustic
    region: the pixels where an offline caustic buffer (2 x 10^6 photons
    gathered at the first diffuse vertex) is at least 5% of its peak, that is
    the caustics themselves (under the glass, off the mirror), not the other
    pixels path tracing finds noisy (a small light's jittered edge). The
    reference is read from / saved to `reference` (an EXR)."""
    from ..photons import PhotonSettings
    from ..render import Renderer
    from .reference import reference_image

    img = reference_image(scene, width, height, ref_spp, reference or None, device, max_depth=max_depth,
                          seed=12345)
    buf = Renderer(scene, device=device).render(
        16, width=width, height=height, max_depth=max_depth,
        photons=PhotonSettings(mode="offline", pilot=False, count=2_000_000, offline_spp=16)).caustic_image
    lum = buf @ np.array([0.2126, 0.7152, 0.0722])
    return img, lum >= 0.05 * max(float(lum.max()), 1e-300)


def equal_time_methods() -> dict:
    """The methods caustic_equal_time compares: key -> (name, PhotonSettings,
    None for path tracing alone)."""
    from ..photons import PhotonSettings

    return {
        "path": ("path tracing", None),
        "default": ("merging (default: MIS, progressive, pilot)", PhotonSettings()),
        "trial": ("merging, pilot with its timed trial", PhotonSettings(pilot_trial=True)),
        "forced": ("merging, forced (no pilot)", PhotonSettings(pilot=False)),
        "first": ("merging, first vertex only", PhotonSettings(pilot=False, merge_vertices=1)),
        "online": ("owned map, online (10^6 photons)", PhotonSettings(mode="online")),
        "progressive": ("owned map, progressive", PhotonSettings(mode="online", progressive=True, count=100_000)),
        "offline": ("owned map, offline", PhotonSettings(mode="offline")),
    }


def cpu_cost_per_spp(render, spread: float, rounds: int = 3, max_spp: int = 1 << 20) -> tuple[float, float]:
    """(CPU seconds per spp, CPU seconds per render) of render(n), n spp,
    from the least of `rounds` timed renders at 16 spp and at n1 spp, n1
    grown from 48 fourfold until the two differ by at least `spread`
    seconds. A render's fixed cost jitters on a machine shared with other
    work: on a small image 32 more spp can cost less than that jitter, and
    a difference of zero or below would ask for an unbounded spp (a bench
    run once went on for hours so). Where no n1 up to max_spp tells them
    apart, the whole cost of the larger render counts per spp: an upper
    bound, so the budget is not overrun."""
    def least(n):
        best = math.inf
        for _ in range(rounds):
            c = time.process_time()
            render(n)
            best = min(best, time.process_time() - c)
        return best

    n0, n1 = 16, 48
    c0 = least(n0)
    c1 = least(n1)
    while c1 - c0 < spread and n1 < max_spp:
        n1 = min(4 * n1, max_spp)
        c1 = least(n1)
    per = (c1 - c0) / (n1 - n0) if c1 - c0 >= spread else max(c1, 1e-6) / n1
    return per, max(c0 - n0 * per, 0.0)


def caustic_equal_time(scene, *, device=None, width=128, height=128, seconds=(2.0, 4.0, 16.0), reference=None,
                       ref_spp=16384, max_depth=64, methods=None, cpu=False) -> dict:
    """relMSE against a path-traced reference (caustic_reference), in the
    caustic region and over the whole image, for path tracing alone and the
    photon methods (methods: keys of equal_time_methods, default all), each
    rendered for the same wall time (the pilot's time counted in), or with
    cpu, for the same CPU time of this process (each method's CPU time per
    spp calibrated on renders of 16 and 48 spp, then the spp that fills the
    budget, rendered again rescaled where it missed the budget by over 10%):
    on a machine shared with other work, CPU time is what the methods' costs
    can still be compared in. Besides relMSE over RGB, each run has the
    luminance relMSE less the reference's own noise (metrics.relmse_luma),
    where the reference has its noise per pixel: the caustic region of a
    path-traced reference is noisy enough to hide a good method's error."""
    from . import metrics
    from ..photons import PhotonSettings
    from ..render import Renderer

    ref, region = caustic_reference(scene, device=device, width=width, height=height, max_depth=max_depth,
                                    reference=reference, ref_spp=ref_spp)
    pm = Renderer(scene, device=device)
    pt = Renderer(scene, device=device, photons=False)
    methods = {name: ps for key, (name, ps) in equal_time_methods().items() if methods is None or key in methods}
    for r in (pt, pm):  # the lazy device compiles, not timed
        r.render(1, width=width, height=height, max_depth=max_depth)
    pm.render(4, width=width, height=height, max_depth=max_depth, photons=PhotonSettings(mode="offline", offline_spp=1))
    out = {"caustic_pixels": int(region.sum()), "budget": "cpu seconds" if cpu else "wall seconds", "runs": []}
    if ref.noise_map is not None:  # what the reference's own noise adds to a luminance relMSE
        out["reference_noise_luma"] = {
            "caustic": metrics.relmse_luma(ref[region], ref[region], -ref.noise_map[region]),
            "image": metrics.relmse_luma(ref, ref, -ref.noise_map)}
    per_spp = {}
    fixed = {}
    if cpu:
        # Each method's CPU seconds per spp and per render (its pilot, a build made on the first
        # render: a twin's), from a warm-up render and timed ones (cpu_cost_per_spp).
        for name, ps in methods.items():
            r = pt if ps is None else pm
            r.render(1, width=width, height=height, seed=1, photons=ps, max_depth=max_depth)
            per_spp[name], fixed[name] = cpu_cost_per_spp(
                lambda n: r.render(n, width=width, height=height, seed=1, photons=ps, max_depth=max_depth),
                0.2 * min(seconds))
    for t in seconds:
        for name, ps in methods.items():
            r = pt if ps is None else pm
            c = time.process_time()
            if cpu:
                spp = max(1, int((t - fixed[name]) / per_spp[name]))
                res = r.render(spp, width=width, height=height, seed=7, photons=ps, max_depth=max_depth)
                used = time.process_time() - c
                if abs(used - t) > 0.1 * t:
                    # The calibration's cost per spp (of short renders) missed by more than 10%: merging's
                    # gathers, for one, cost less as its radius shrinks. Once more, with the spp scaled
                    # by what this render's own cost says.
                    scale = (t - fixed[name]) / max(used - fixed[name], 1e-9)
                    spp = max(1, int(spp * min(max(scale, 0.25), 4.0)))  # (a render lost to jitter asks for no more)
                    c = time.process_time()
                    res = r.render(spp, width=width, height=height, seed=7, photons=ps, max_depth=max_depth)
            else:
                res = r.render(1 << 24, width=width, height=height, seed=7, time_limit=t, photons=ps,
                               max_depth=max_depth)
            img = res.image.astype(np.float64)
            out["runs"].append({"method": name, "seconds": round(res.stats.render_seconds, 2),
                                "cpu_seconds": round(time.process_time() - c, 2),
                                "spp": float(res.sample_count.mean()),
                                "relmse_caustic": metrics.relmse(img[region], ref[region]),
                                "relmse_image": metrics.relmse(img, ref),
                                **({} if ref.noise_map is None else {
                                    "relmse_caustic_luma": metrics.relmse_luma(img[region], ref[region],
                                                                               ref.noise_map[region]),
                                    "relmse_image_luma": metrics.relmse_luma(img, ref, ref.noise_map)}),
                                "choice": (res.stats.photon_pilot or {}).get("choice")})
    out["reference_noise_warning"] = reference_noise_warning(out)
    return out


def run_bench_photons(a) -> int:
    builds = measure_photon_builds(a.scene, a.counts, device=a.device)
    gather = measure_gather_cost(a.scene, device=a.device, width=a.width, height=a.height)
    result = {"builds": builds, "gather": gather}
    if a.equal_time:
        result["equal_time"] = caustic_equal_time(a.scene, device=a.device, width=a.width, height=a.height,
                                                  seconds=a.equal_time,
                                                  reference=a.reference, ref_spp=a.ref_spp, max_depth=a.max_depth,
                                                  cpu=a.cpu_time,
                                                  methods=a.methods.split(",") if a.methods else None)
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
        ref = (f"the reference {a.reference}" if a.reference and os.path.exists(a.reference)
               else f"a path-traced reference of {a.ref_spp} spp")  # (a given one may be made another way)
        print(f"equal-time relMSE against {ref} ({et['caustic_pixels']} caustic pixels):")
        base = {}
        for run in et["runs"]:
            if run["method"] == "path tracing":
                base = run
            gain = (f"  (vs path tracing: caustic {base['relmse_caustic'] / run['relmse_caustic']:.2f}x, "
                    f"image {base['relmse_image'] / run['relmse_image']:.2f}x)") if base else ""
            choice = f" [{run['choice']}]" if run.get("choice") else ""
            print(f"  {run['method']:44s} {run['seconds']:6.2f} s ({run['cpu_seconds']:6.2f} CPU s) {run['spp']:8.1f} spp  relMSE caustic "
                  f"{run['relmse_caustic']:.3e}, image {run['relmse_image']:.3e}{gain}{choice}")
            if "relmse_caustic_luma" in run:
                gain = (f"  (vs path tracing: caustic {base['relmse_caustic_luma'] / run['relmse_caustic_luma']:.2f}x, "
                        f"image {base['relmse_image_luma'] / run['relmse_image_luma']:.2f}x)") if base else ""
                print(f"  {'':44s} luminance, reference noise out: caustic {run['relmse_caustic_luma']:.3e}, "
                      f"image {run['relmse_image_luma']:.3e}{gain}")
        if "reference_noise_luma" in et:
            rn = et["reference_noise_luma"]
            print(f"  (the reference's own noise: luminance relMSE caustic {rn['caustic']:.3e}, image {rn['image']:.3e})")
            if et.get("reference_noise_warning"):
                print(f"  {et['reference_noise_warning']}")
    return 0


# The share of a method's caustic relMSE that the reference's own noise may
# be before the plain (RGB) ratios are no longer a fair measure of it.
REFERENCE_NOISE_SHARE = 0.2


def reference_noise_warning(et: dict) -> str | None:
    """A warning when the reference's own noise in the caustic region is more
    than REFERENCE_NOISE_SHARE of some run's caustic relMSE: every error
    against the reference is raised by that noise, so the plain ratios
    understate the better method's lead (at 60 s, a 32768-spp reference's
    noise was 80% of merging's relMSE on cornell_box_caustics, and the ratio
    read 3.6x; in a run against a 262144-spp reference it read 7.1x)."""
    noise = (et.get("reference_noise_luma") or {}).get("caustic")
    runs = [r for r in et.get("runs", []) if r.get("relmse_caustic_luma") is not None]
    if not noise or not runs:
        return None
    low = min(runs, key=lambda r: r["relmse_caustic"])
    share = noise / max(low["relmse_caustic"], 1e-300)
    if share <= REFERENCE_NOISE_SHARE:
        return None
    return (f"the reference's own noise is {100 * share:.0f}% of the caustic relMSE of {low['method']} at "
            f"{low['seconds']:.1f} s: its plain ratios understate the lead of the better method; read the "
            f"luminance lines, or give a reference of more samples (--ref-spp)")


# --- BVH and meshes --------------------------------------------------------------------------

def sphere_mesh(n_triangles: int, center=(0.0, -0.45, 0.0), radius=0.5, bumps=0.06):
    """(vertices, triangles, normals) of a bumpy latitude-longitude sphere of
    about n_triangles triangles (smooth normals of the bumpy surface)."""
    n_theta = max(3, int(round((n_triangles / 4) ** 0.5)))
    n_phi = max(4, int(round(n_triangles / (2 * n_theta))))
    th = np.linspace(0.0, np.pi, n_theta + 1)[1:-1]
    ph = np.linspace(0.0, 2 * np.pi, n_phi + 1)[:-1]
    t, p = np.meshgrid(th, ph, indexing="ij")
    r = radius * (1 + bumps * np.sin(7 * t) * np.cos(5 * p))
    pts = np.stack([r * np.sin(t) * np.cos(p), r * np.cos(t), r * np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    v = np.concatenate([[(0, radius, 0)], pts, [(0, -radius, 0)]]) + np.asarray(center, dtype=np.float64)
    ring = (1 + np.arange(n_theta - 1)[:, None] * n_phi + np.arange(n_phi)[None, :])
    nxt = np.roll(ring, -1, axis=1)
    south = len(v) - 1
    caps = [np.stack([np.zeros(n_phi, dtype=np.int64), nxt[0], ring[0]], 1),
            np.stack([np.full(n_phi, south), ring[-1], nxt[-1]], 1)]
    a, b, c, d = ring[:-1], nxt[:-1], nxt[1:], ring[1:]
    quads = [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    tris = np.concatenate(caps + quads)
    # Vertex normals: area-weighted face normals.
    fn = np.cross(v[tris[:, 1]] - v[tris[:, 0]], v[tris[:, 2]] - v[tris[:, 0]])
    vn = np.zeros_like(v)
    for k in range(3):
        np.add.at(vn, tris[:, k], fn)
    return v, tris, vn / np.linalg.norm(vn, axis=1, keepdims=True)


def mesh_box_scene(n_triangles: int, material="white"):
    """The Cornell box with a bumpy sphere mesh of about n_triangles."""
    from ..loading import load_scene
    from ..scene import Mesh

    s = load_scene("cornell_box")
    v, t, n = sphere_mesh(n_triangles)
    s.shapes = [sh for sh in s.shapes if not (sh.name or "").startswith(("small-box", "large-box"))] + [
        Mesh(vertices=v, triangles=t, normals=n, material=material, name="ball")]
    return s


def _bvh_bytes(packed) -> int:
    """Device bytes (float build) of the BVH nodes, items and vertex normals."""
    from ..pack import LIGHT_STRIDE, PLANE_STRIDE, MAT_STRIDE
    c = packed.counts
    head = MAT_STRIDE * c[0] + PLANE_STRIDE * c[4] + LIGHT_STRIDE * c[5] + c[6]
    return (len(packed.records) - head) * 16


def measure_bvh(counts, *, methods=("sah", "lbvh"), walks=("hybrid",), device=None, width=128, height=128,
                max_depth=8, rounds=3, pass_seconds=0.5) -> list[dict]:
    """Per triangle count and builder: build time, memory, SAH cost, depth,
    and path-tracing throughput of the mesh in the Cornell box (rounds
    interleaved over all configurations)."""
    from ..features import Experimental
    from ..render import Renderer

    rows, runners = [], []
    for n in counts:
        scene = mesh_box_scene(int(n))
        for method, walk in itertools.product(methods, walks):
            r = Renderer(scene, device=device, bvh="on", bvh_method=method, photons=False,
                         experimental=Experimental(bvh_walk=walk))
            tree = r.packed.bvh
            row = {"triangles": int(scene.shapes[-1].triangles.shape[0]), "method": method, "walk": walk,
                   "build_seconds": tree.seconds, "pack_seconds": r.pack_seconds,
                   "bytes_per_triangle": _bvh_bytes(r.packed) / scene.shapes[-1].triangles.shape[0],
                   "nodes": int(r.packed.count("nodes")), "depth": tree.depth(), "sah_cost": tree.sah_cost(),
                   "rates": [], "ray_rates": []}
            probe = r.render(1, width=width, height=height, max_depth=max_depth)
            probe = r.render(1, width=width, height=height, max_depth=max_depth)
            row["pass_spp"] = max(1, int(pass_seconds / max(probe.stats.render_seconds, 1e-6)))
            rows.append(row)
            runners.append(r)
    for i in range(rounds):
        for row, r in zip(rows, runners):
            res = r.render(row["pass_spp"], width=width, height=height, max_depth=max_depth, seed=i + 1,
                           pass_seconds=1e9)
            row["rates"].append(_pass_rate(res) / 1e6)
            row["ray_rates"].append(res.stats.rays / res.stats.render_seconds / 1e6)
    for row in rows:
        row["msamples_per_s"] = statistics.median(row["rates"])
        row["mrays_per_s"] = statistics.median(row["ray_rates"])
        row["mrays_per_s_range"] = [min(row["ray_rates"]), max(row["ray_rates"])]
    return rows


def measure_threshold(sizes=(0, 8, 24, 48, 96, 200), *, device=None, width=128, height=128, rounds=3,
                      pass_seconds=0.3) -> list[dict]:
    """Samples/s of the Cornell box (18 primitives) plus a mesh of k
    triangles, with the plain loops and with the BVH (interleaved rounds):
    where the BVH starts to pay."""
    from ..render import Renderer
    from ..loading import load_scene
    from ..scene import Mesh

    rows, runners = [], []
    for k in sizes:
        s = load_scene("cornell_box")
        if k:
            v, t, n = sphere_mesh(k, center=(0.4, -0.7, 0.3), radius=0.25)
            s.shapes.append(Mesh(vertices=v, triangles=t, normals=n, name="ball"))
        for mode in ("off", "on"):
            r = Renderer(s, device=device, bvh=mode, photons=False)
            probe = r.render(1, width=width, height=height)
            probe = r.render(1, width=width, height=height)
            rows.append({"primitives": r.packed.primitives, "bvh": mode, "rates": [],
                         "pass_spp": max(1, int(pass_seconds / max(probe.stats.render_seconds, 1e-6)))})
            runners.append(r)
    for i in range(rounds):
        for row, r in zip(rows, runners):
            row["rates"].append(_pass_rate(r.render(row["pass_spp"], width=width, height=height, seed=i + 1,
                                                    pass_seconds=1e9)) / 1e6)
    for row in rows:
        row["msamples_per_s"] = statistics.median(row["rates"])
    return rows


def _setup_child(path: str, device) -> dict:
    from ..render import Renderer
    from ..loading import load_scene

    t0 = time.perf_counter()
    scene = load_scene(path)
    t1 = time.perf_counter()
    r = Renderer(scene, device=device)
    t2 = time.perf_counter()
    res = r.render(1, width=16, height=16)
    t3 = time.perf_counter()
    return {"load_seconds": t1 - t0, "pack_seconds": r.pack_seconds, "bvh_seconds": r.packed.bvh.seconds,
            "build_seconds": r.build_seconds, "renderer_seconds": t2 - t1, "first_launch_seconds": t3 - t2,
            "total_seconds": t3 - t0, "cache_hit": bool(r.states[0].build.cache_hit)}


def measure_setup(n_triangles=100_000, *, device=None) -> dict:
    """Load (a PLY file through a TOML scene), BVH and kernel build, and the
    first 16x16 launch, in fresh processes: once with empty caches (cold)
    and once with the kernel cache just filled (warm)."""
    v, t, n = sphere_mesh(n_triangles)
    out = {"triangles": len(t)}
    with tempfile.TemporaryDirectory() as tmp:
        head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(v)}", "property float x",
                "property float y", "property float z", "property float nx", "property float ny", "property float nz",
                f"element face {len(t)}", "property list uchar int vertex_indices", "end_header"]
        faces = np.zeros(len(t), dtype=[("n", "u1"), ("i", "<i4", (3,))])
        faces["n"], faces["i"] = 3, t
        body = np.concatenate([v, n], axis=1).astype("<f4").tobytes() + faces.tobytes()
        with open(os.path.join(tmp, "ball.ply"), "wb") as f:
            f.write(("\n".join(head) + "\n").encode() + body)
        from ..resources import scene_path
        text = scene_path("cornell_box").read_text()
        text += '\n[[shapes]]\ntype = "mesh"\nfile = "ball.ply"\nmaterial = "white"\n'
        path = os.path.join(tmp, "scene.toml")
        with open(path, "w") as f:
            f.write(text)
        env = dict(os.environ, CLPT_CACHE_DIR=os.path.join(tmp, "clpt"), POCL_CACHE_DIR=os.path.join(tmp, "pocl"))
        code = f"import json; from clpt.tools.bench import _setup_child; print(json.dumps(_setup_child({path!r}, {device!r})))"
        for key in ("cold", "warm"):
            p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
            if p.returncode != 0:
                raise RuntimeError(f"setup measurement failed:\n{p.stderr.strip()}")
            out[key] = json.loads(p.stdout.strip().splitlines()[-1])
    return out


def run_bench_bvh(a) -> int:
    result = {}
    counts = a.triangles
    if counts:
        result["bvh"] = measure_bvh(counts, methods=tuple(a.methods.split(",")), walks=tuple(a.walks.split(",")),
                                    device=a.device, width=a.width,
                                    height=a.height, max_depth=a.max_depth, rounds=a.rounds)
    if a.threshold:
        result["threshold"] = measure_threshold(device=a.device, rounds=a.rounds)
    if a.setup:
        result["setup"] = measure_setup(int(float(a.setup)), device=a.device)
    if a.mitsuba:
        result["mitsuba"] = measure_vs_mitsuba(a.mitsuba, device=a.device, width=a.width, height=a.height,
                                               max_depth=a.max_depth, rounds=a.rounds)
    if a.json:
        print(json.dumps(result, indent=2))
        return 0
    if "bvh" in result:
        print(f"BVH over a bumpy sphere mesh in the Cornell box ({a.width}x{a.height}, depth {a.max_depth}, "
              f"medians of {a.rounds} interleaved rounds):")
        print(f"  {'triangles':>9} {'builder':7} {'walk':6} {'build s':>8} {'B/tri':>6} {'depth':>5} {'SAH cost':>8} "
              f"{'Msamples/s':>10} {'Mrays/s':>8} (range)")
        for r in result["bvh"]:
            lo, hi = r["mrays_per_s_range"]
            print(f"  {r['triangles']:>9} {r['method']:7} {r['walk']:6} {r['build_seconds']:8.3f} {r['bytes_per_triangle']:6.0f} "
                  f"{r['depth']:>5} {r['sah_cost']:8.1f} {r['msamples_per_s']:10.4f} {r['mrays_per_s']:8.3f} "
                  f"({lo:.3f}-{hi:.3f})")
    if "threshold" in result:
        print("plain loops vs BVH (Cornell box + a small mesh, Msamples/s):")
        for off, on in zip(result["threshold"][0::2], result["threshold"][1::2]):
            print(f"  {off['primitives']:>5} primitives: loops {off['msamples_per_s']:.4f}, BVH {on['msamples_per_s']:.4f}")
    if "setup" in result:
        s = result["setup"]
        print(f"scene setup for {s['triangles']} triangles (PLY through TOML, fresh processes):")
        for key in ("cold", "warm"):
            c = s[key]
            print(f"  {key}: load {c['load_seconds']:.3f} s, pack {c['pack_seconds']:.3f} s (BVH "
                  f"{c['bvh_seconds']:.3f} s), kernel build {c['build_seconds']:.3f} s"
                  f"{' (cache hit)' if c['cache_hit'] else ''}, first launch {c['first_launch_seconds']:.3f} s; "
                  f"total {c['total_seconds']:.3f} s")
    if "mitsuba" in result:
        m = result["mitsuba"]
        print(f"{a.mitsuba} ({m['triangles']} triangles) in the Cornell box, {m['width']}x{m['height']}, "
              f"{m['max_depth']} bounces, Msamples/s in {len(m['clpt'])} alternating rounds:")
        print(f"  clpt     {statistics.median(m['clpt']):.4f} (range {min(m['clpt']):.4f}-{max(m['clpt']):.4f}) "
              f"[{m['clpt_features']}]")
        print(f"  Mitsuba  {statistics.median(m['mitsuba']):.4f} (range {min(m['mitsuba']):.4f}-"
              f"{max(m['mitsuba']):.4f}) [llvm_ad_rgb, path, max_depth {m['max_depth'] + 1}]")
        print(f"  image means: clpt {m['clpt_image_mean']:.4f}, Mitsuba {m['mitsuba_image_mean']:.4f}")
    return 0


def bunny_box(path, *, mitsuba=False):
    """The Cornell box (Mitsuba's cornell_box()) with its two blocks replaced by
    the mesh at path (flat-shaded), scaled to 1.1 high and stood on the floor:
    a clpt Scene, or with mitsuba=True the same scene as a Mitsuba 3 dict."""
    from ..meshio import read_mesh
    from ..loading import load_scene
    from ..scene import Mesh

    v, _, _ = read_mesh(path)
    lo, hi = v.min(0), v.max(0)
    k = 1.1 / (hi[1] - lo[1])
    m = np.diag([k, k, k, 1.0])
    m[:3, 3] = [-k * 0.5 * (lo[0] + hi[0]), -1.0 - k * lo[1], -k * 0.5 * (lo[2] + hi[2])]
    if mitsuba:
        import mitsuba as mi
        d = mi.cornell_box()
        d.pop("small-box")
        d.pop("large-box")
        d["mesh"] = {"type": "ply", "filename": str(path), "face_normals": True, "to_world": mi.ScalarTransform4f(m),
                     "bsdf": {"type": "ref", "id": "white"}}
        return d
    s = load_scene("cornell_box")
    s.shapes = [sh for sh in s.shapes if not (sh.name or "").startswith(("small-box", "large-box"))]
    s.shapes.append(Mesh.from_file(path, transform=m, material="white", name="mesh"))
    return s


def measure_vs_mitsuba(path, *, device=None, width=256, height=256, max_depth=8, spp=16, rounds=3) -> dict:
    """Samples/s of clpt and of Mitsuba 3 (llvm_ad_rgb, path tracer with
    max_depth + 1: the same bounces) on bunny_box(path), in alternating
    rounds after a warm-up (kernel builds and Mitsuba's JIT left out)."""
    import mitsuba as mi

    from ..render import Renderer

    mi.set_variant("llvm_ad_rgb")
    d = bunny_box(path, mitsuba=True)
    d["integrator"] = {"type": "path", "max_depth": max_depth + 1}
    d["sensor"]["film"]["width"], d["sensor"]["film"]["height"] = width, height
    mscene = mi.load_dict(d)
    r = Renderer(bunny_box(path), device=device, photons=False)
    out = {"triangles": int(r.scene.shapes[-1].triangles.shape[0]), "clpt": [], "mitsuba": [],
           "clpt_features": r.features.describe(), "width": width, "height": height, "max_depth": max_depth}
    r.render(1, width=width, height=height, max_depth=max_depth)
    mi.render(mscene, spp=1).numpy()
    for i in range(rounds):
        res = r.render(spp, width=width, height=height, max_depth=max_depth, seed=i + 1, pass_seconds=1e9)
        out["clpt"].append(width * height * spp / res.stats.render_seconds / 1e6)
        t0 = time.perf_counter()
        mi.render(mscene, spp=spp, seed=i + 1).numpy()
        out["mitsuba"].append(width * height * spp / (time.perf_counter() - t0) / 1e6)
        out["clpt_image_mean"] = float(res.image.mean())
    out["mitsuba_image_mean"] = float(np.asarray(mi.render(mscene, spp=spp)).mean())
    return out


# --- cold and warm builds per runtime (clpt bench-builds) ---------------------------------------

def _builds_child(scene: str, device) -> dict:
    import clpt  # noqa: F401 - the import (runtime registration) is part of what a user waits for

    from ..render import Renderer

    t0 = time.perf_counter()
    r = Renderer(scene, device=device)
    t1 = time.perf_counter()
    r.render(1, width=16, height=16)
    t2 = time.perf_counter()
    st = r.states[0]
    return {"renderer_seconds": t1 - t0, "first_render_seconds": t2 - t1, "total_seconds": t2 - t0,
            "build_seconds": r.build_seconds, "lanes": st.features.lanes, "photons": st.features.photons, "device": st.dctx.label,
            "cache_hit": bool(st.build.cache_hit)}


def _fresh_env(tmp: str, devices_from: str | None) -> dict:
    """Empty clpt, PoCL and pyopencl caches in tmp; the device checks copied
    from devices_from (each device is checked once per installation, not
    per scene: bench-builds reports that apart)."""
    import shutil

    clpt_dir = os.path.join(tmp, "clpt")
    os.makedirs(clpt_dir, exist_ok=True)
    if devices_from and os.path.isdir(os.path.join(devices_from, "devices")):
        shutil.copytree(os.path.join(devices_from, "devices"), os.path.join(clpt_dir, "devices"), dirs_exist_ok=True)
    return dict(os.environ, CLPT_CACHE_DIR=clpt_dir, POCL_CACHE_DIR=os.path.join(tmp, "pocl"),
                PYOPENCL_NO_CACHE="1")


def _child_json(code: str, env: dict) -> dict:
    p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(p.stderr.strip().splitlines()[-1] if p.stderr.strip() else f"exit {p.returncode}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def measure_builds(scenes, devices) -> list[dict]:
    """For each device (a selector; None: the default) and scene: a fresh
    process with empty caches builds the scene's kernels as `clpt render`
    would (default lanes and tuning) and renders one 16x16 sample (cold),
    then another process does the same with the cache it left (warm). The
    device's check (clpt/probe.py) is timed once per device, apart."""
    rows = []
    with tempfile.TemporaryDirectory() as checks:
        for device in devices:
            env = _fresh_env(checks, None)
            # Every device checked first (as a machine that has rendered before has them): the
            # default for photon scenes would otherwise check a candidate in the background.
            code = ("import json, time; t = time.perf_counter(); import clpt.device as d; "
                    "[d.check_device(x) for _, _, _, x in d._all_devices() if not d.is_simulator(x)]; "
                    f"dev = d.select_devices({device!r})[0]; r = d.check_device(dev); "
                    "print(json.dumps({'ok': r.ok, 'seconds': r.seconds, 'label': d.device_label(dev), "
                    "'wall': time.perf_counter() - t}))")
            check = _child_json(code, env)
            for scene in scenes:
                row = {"device": device, "scene": scene, "check_seconds": check["seconds"]}
                with tempfile.TemporaryDirectory() as tmp:
                    env = _fresh_env(tmp, os.path.join(checks, "clpt"))
                    code = (f"import json; from clpt.tools.bench import _builds_child; "
                            f"print(json.dumps(_builds_child({scene!r}, {device!r})))")
                    try:
                        row["cold"] = _child_json(code, env)
                        row["warm"] = _child_json(code, env)
                    except RuntimeError as e:
                        row["error"] = str(e)
                rows.append(row)
    return rows


def run_bench_builds(a) -> int:
    from ..resources import shipped_scenes

    scenes = shipped_scenes() if a.scene == ["all"] else a.scene
    devices = [None if d in ("default", "") else d for d in a.device.split(",")]
    rows = measure_builds(scenes, devices)
    if a.json:
        print(json.dumps(rows, indent=2))
        return 0
    print("cold: a fresh process with empty kernel caches: the programs' build, and Renderer + a 1-sample 16x16 "
          "render in all (wall s); warm: the same with the cache filled")
    print(f"{'device':10} {'scene':34} {'lanes':>5} {'cold build':>10} {'cold all':>8} {'warm build':>10} "
          f"{'warm all':>8}  runtime")
    for r in rows:
        if "error" in r:
            print(f"{str(r['device'] or 'default'):10} {r['scene']:34} failed: {r['error']}")
            continue
        c, w = r["cold"], r["warm"]
        print(f"{str(r['device'] or 'default'):10} {r['scene']:34} {c['lanes']:>5} {c['build_seconds']:10.2f} "
              f"{c['total_seconds']:8.2f} {w['build_seconds']:10.3f} {w['total_seconds']:8.2f}  {c['device']}")
    seen = {}
    for r in rows:
        seen.setdefault(str(r["device"] or "default"), r["check_seconds"])
    print("device checks (once per device and driver): "
          + ", ".join(f"{k} {v:.1f} s" for k, v in seen.items()))
    return 0
