"""Per-device defaults: paths per work-item (lanes), work-group size and pass
length, predicted from device queries and the kernel's kind, or measured
on request (CLPT_TUNE=measure).

- GPU: 1 lane (the hardware runs work-items in lockstep), work-groups of
  LOCAL_SIZE_GPU.
- PoCL on a CPU: lanes = the native float vector width it reports (16 with
  AVX-512, 8 with AVX2). PoCL does not vectorize a path tracer's loop across
  work-items, but compiles the lanes' vector types straight to the ISA's
  registers, so the register width is the best width (measured on the
  AVX-512 machine: 11.4 Msamples/s at 16 lanes, 7.3 at 8, 4.0 at 4, 1.6 at 1,
  on the Cornell box).
- Intel's runtime: the register width, for every kernel. Intel's compiler
  vectorizes across work-items itself, so 1 lane is also vector code, but
  it gave up on the photon kernel at 1 lane (its vectorizer's cost model
  turned down the 16-wide version with the gather's 26 extra memory
  gathers), and explicit lanes tell it, by vec_type_hint (kernels/trace.cl),
  not to vectorize again across work-items (before, it did so to the photon
  kernel, 16 x 16 wide, and ran it at a third of the speed). Measured with
  Intel 2026.2 on the AVX-512 machine (Msamples per CPU second, 128x128,
  depth 64, medians of 3): the photon kernel on cornell_box_caustics merging
  0.73 at 1 lane, 2.1-2.4 at 16 (the six photon scenes: 0.67-0.88 against
  1.9-3.0); without photons the register width won on
  every shipped scene before (`python tests/bench_tune.py`: 1 lane / 16
  lanes 6.0-8.4 / 7.7-13.6, mesh_lights 1.2 / 1.7). A
  measurement costs both builds and trial renders (13-25 s on a photon
  scene, more than most renders), so it is not on the first render's path:
  CLPT_TUNE=measure measures (and caches the choice, which later renders
  then use). It builds both candidates (at once where the runtime takes it:
  program.builds_at_once) and times them in
  interleaved rounds on a 64x64 image, rendering the scene the default way;
  the faster best round is kept. Then, with those lanes, the work-group
  sizes LOCAL_CANDIDATES in the same way (no rebuild: the local size is a
  launch parameter); one replaces LOCAL_SIZE_CPU only when it is more than
  LOCAL_MARGIN faster, since on a shared machine the trial's best rounds
  differ by more than the sizes do (16 to 128 were within 3% on the Cornell
  box). Intel's kernel queries are no guide (it reports a preferred
  multiple of 128 for every build), and the size matters there: 1 lane
  with work-groups of 8 ran 0.6 Msamples/s against 3.0-3.1 with 16, 32 or
  64 on the Cornell box, because Intel's compiler vectorizes across 16
  work-items of a group.
- Local size on PoCL: LOCAL_SIZE_CPU, from the query. PoCL runs a group's
  work-items in a loop on one thread, so the size only sets the grain of
  the load balance; measured on the Cornell box at 16 lanes, 2 to 64 were
  within the noise of each other (medians 2.1-2.55 Msamples/s, ranges
  overlapping, 16 the best median).

Every choice changes speed only: images are bit-identical across lanes and
work-group sizes (tests/test_render.py). A measured choice is cached as JSON
beside the kernel build cache (program.cache_dir() / "tune"), keyed by the
device and driver identity, the kernel source and the build options, less
the lane count and the scene's primitive counts (so scenes with the same
kinds of shapes, lobes and lights share one measurement); ``clpt cache
--clear`` removes it. An explicit lanes or local_size
always wins. CLPT_TUNE=auto (the default) takes a cached measurement where
there is one, else the prediction; CLPT_TUNE=query always the prediction
(the test suite runs so); CLPT_TUNE=measure measures on every CPU, PoCL
included (to check the predictions), and caches what it finds.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass

import pyopencl as cl

from . import program
from .constants import LOCAL_SIZE_CPU, LOCAL_SIZE_GPU
from .program import cache_dir
from .runtimes import platform_short_name

LANE_WIDTHS = (1, 2, 4, 8, 16)
PASS_SECONDS = 0.25
TRIAL_SIZE = 64          # image side of an autotune trial
TRIAL_ROUNDS = 4
TRIAL_PASS_SECONDS = 0.08
LOCAL_CANDIDATES = (16, 32, 64, 128)  # work-group sizes a measurement tries (every kernel checks its range)
LOCAL_MARGIN = 1.10  # a measured local size replaces LOCAL_SIZE_CPU only when this much faster


@dataclass(frozen=True)
class Tuning:
    lanes: int
    local_size: int
    pass_seconds: float
    how: str   # "explicit", "query", "measured", "cached"
    why: str

    def describe(self) -> str:
        return (f"lanes {self.lanes}, local size {self.local_size}, pass {self.pass_seconds:g} s "
                f"({self.how}: {self.why})")


def register_width(device) -> int:
    """The widest supported lane count not above the device's native float width."""
    w = device.native_vector_width_float or device.preferred_vector_width_float or 4
    return max(x for x in LANE_WIDTHS if x <= max(w, 1))


def predict(device, photons: bool = False, cpu: bool | None = None) -> Tuning:
    """What a pyopencl Device's queries and the kernel's kind predict (see
    the module's docstring); photons: the kernel gathers caustic photons;
    cpu: whether to treat it as a CPU (default: its device type)."""
    if not (bool(device.type & cl.device_type.CPU) if cpu is None else cpu):
        local = min(LOCAL_SIZE_GPU, device.max_work_group_size)
        return Tuning(1, local, PASS_SECONDS, "query", "a GPU runs work-items in lockstep: 1 lane")
    w = register_width(device)
    runtime = platform_short_name(device.platform.name.strip())
    if runtime == "pocl":
        return Tuning(w, LOCAL_SIZE_CPU, PASS_SECONDS, "query",
                      f"PoCL compiles lane vectors to the ISA's registers: native float width "
                      f"{device.native_vector_width_float}")
    if runtime == "intel":
        return Tuning(w, LOCAL_SIZE_CPU, PASS_SECONDS, "query",
                      f"native float width {device.native_vector_width_float}: faster than 1 lane on the shipped "
                      f"scenes, with and without photons (CLPT_TUNE=measure measures)")
    return Tuning(w, LOCAL_SIZE_CPU, PASS_SECONDS, "query",
                  f"native float width {device.native_vector_width_float} (not measured; CLPT_TUNE=measure measures)")


def query_tuning(dctx, photons: bool = False) -> Tuning:
    """The choice device queries and the kernel's kind predict for a DeviceContext."""
    return predict(dctx.device, photons, dctx.is_cpu)


def tune_key(dctx, source: str, options) -> str:
    h = hashlib.sha256()
    kept = [o for o in options if not o.startswith(("-DCLPT_LANES=", "-DCLPT_NUM_"))]
    for part in (dctx.identity(), source, "\0".join(kept)):
        h.update(part.encode())
        h.update(b"\1")
    return h.hexdigest()[:32]


def _path(key: str):
    return cache_dir() / "tune" / f"{key}.json"


def load(key: str) -> Tuning | None:
    try:
        d = json.loads(_path(key).read_text())
        return Tuning(int(d["lanes"]), int(d["local_size"]), float(d["pass_seconds"]), "cached", d["why"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def save(key: str, t: Tuning, dctx, measured: dict):
    p = _path(key)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps({**asdict(t), "device": dctx.label, "identity": dctx.identity(),
                                   "measured": measured}, indent=1))
        os.replace(tmp, p)
    except OSError:
        pass  # an unwritable cache only costs the next run a measurement


def load_measured(kind: str, key: str) -> dict | None:
    """A measurement cached beside the tuning's (cache_dir() / kind), or None."""
    try:
        d = json.loads((cache_dir() / kind / f"{key}.json").read_text())
        return d if isinstance(d, dict) else None
    except (OSError, ValueError):
        return None


def save_measured(kind: str, key: str, data: dict):
    p = cache_dir() / kind / f"{key}.json"
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(data, indent=1))
        os.replace(tmp, p)
    except OSError:
        pass  # an unwritable cache only costs the next run a measurement


def cached_choices(dctx) -> list[dict]:
    """The measured choices cached for this device (for `clpt devices -v`)."""
    d = cache_dir() / "tune"
    out = []
    for p in sorted(d.glob("*.json")) if d.is_dir() else []:
        try:
            e = json.loads(p.read_text())
        except (OSError, ValueError):
            continue
        if e.get("identity") == dctx.identity():
            out.append(e)
    return out


def measure_candidates(states, trial) -> dict:
    """Samples/s of each state (a DeviceWorker of one lane width) rendering
    the scene's default way (photons included) on a small image, in
    interleaved rounds: {"msamples_per_s": {lanes: best round}, "launch_seconds":
    the fixed cost of an empty launch}. trial(st, spp, seed) renders and
    returns (samples/s of the timed passes, seconds per spp)."""
    per_spp = {}
    for st in states:
        trial(st, 1, 0)  # the lazy device compile
        per_spp[st.features.lanes] = trial(st, 2, 1)[1]
    rates = {st.features.lanes: [] for st in states}
    for r in range(TRIAL_ROUNDS):
        for st in states:
            n = max(1, int(TRIAL_PASS_SECONDS / max(per_spp[st.features.lanes], 1e-6)))
            rates[st.features.lanes].append(trial(st, n, 2 + r)[0] / 1e6)
    overhead = min(st.launch_seconds() for st in states for _ in range(3))
    # The best round: on a shared machine other load only ever slows a round down.
    return {"msamples_per_s": {k: max(v) for k, v in rates.items()}, "launch_seconds": overhead}


def measure_local_sizes(st, trial, candidates) -> dict:
    """Best-round Msamples/s of state st at each work-group size, in
    interleaved rounds as measure_candidates; st.local is left as it was."""
    keep = st.local
    rates = {c: [] for c in candidates}
    try:
        per_spp = {}
        for c in candidates:
            st.local = c
            trial(st, 1, 0)
            per_spp[c] = trial(st, 2, 1)[1]
        for r in range(TRIAL_ROUNDS):
            for c in candidates:
                st.local = c
                n = max(1, int(TRIAL_PASS_SECONDS / max(per_spp[c], 1e-6)))
                rates[c].append(trial(st, n, 2 + r)[0] / 1e6)
    finally:
        st.local = keep
    return {c: max(v) for c, v in rates.items()}


def choose(dctx, source: str, options, make_state, trial, *, lanes=None, local_size=None, use_cache=True):
    """(Tuning, the built DeviceWorker of the chosen width if choosing built
    one, else None). make_state(lanes) builds a DeviceWorker of that width;
    trial as for measure_candidates."""
    policy = os.environ.get("CLPT_TUNE", "auto").lower()
    if policy not in ("auto", "query", "measure"):
        raise ValueError(f"CLPT_TUNE must be auto, query or measure (got {policy!r})")
    photons = "-DCLPT_PHOTONS=1" in options
    state = base = None
    key = tune_key(dctx, source, options)
    if policy != "query" and dctx.is_cpu and lanes is None and use_cache:
        base = load(key)  # a measurement made earlier (CLPT_TUNE=measure)
    if base is None and not (policy == "measure" and dctx.is_cpu and lanes is None):
        base = query_tuning(dctx, photons)
    if base is None:
        t0 = time.perf_counter()
        widths = sorted({1, register_width(dctx.device)})
        if program.builds_at_once(dctx):  # the candidates build in parallel (the OpenCL compilers release the GIL)
            with ThreadPoolExecutor() as pool:
                states = list(pool.map(make_state, widths))
        else:  # a runtime not known to take concurrent builds
            states = [make_state(w) for w in widths]
        m = measure_candidates(states, trial)
        rates = m["msamples_per_s"]
        best = max(rates, key=rates.get)
        state = next(st for st in states if st.features.lanes == best)
        local = LOCAL_SIZE_CPU
        if local_size is None:
            sizes = [c for c in LOCAL_CANDIDATES if c <= dctx.device.max_work_group_size] or [local]
            m["local_msamples_per_s"] = lr = measure_local_sizes(state, trial, sizes)
            fastest = max(lr, key=lr.get)
            # Between sizes within noise of each other, the default: on Intel's runtime at
            # 256x256, 16 to 64 were within noise; only a clear win moves it.
            if local not in lr or lr[fastest] > LOCAL_MARGIN * lr[local]:
                local = fastest
        # A pass long enough that the fixed cost of a launch stays under 1%.
        pass_s = min(0.5, max(PASS_SECONDS, 100 * m["launch_seconds"]))
        why = (f"measured {', '.join(f'{k} lanes {v:.2f}' for k, v in sorted(rates.items()))} Msamples/s"
               + ("" if local_size is not None else
                  f"; with {best} lanes, local size {', '.join(f'{k} {v:.2f}' for k, v in sorted(lr.items()))}")
               + f" on {TRIAL_SIZE}x{TRIAL_SIZE}, launch cost {m['launch_seconds'] * 1e3:.1f} ms, "
               f"in {time.perf_counter() - t0:.1f} s")
        base = Tuning(best, local, pass_s, "measured", why)
        if use_cache and local_size is None:  # only a full measurement is cached
            save(key, base, dctx, m)
    if lanes is None and local_size is None:
        return base, state
    if lanes is not None and lanes != base.lanes:
        state = None
    given = ", ".join(f"{k} {v}" for k, v in (("lanes", lanes), ("local size", local_size)) if v is not None)
    return Tuning(lanes or base.lanes, local_size or base.local_size, base.pass_seconds, "explicit",
                  f"{given} given; otherwise {base.how}: {base.why}"), state
