"""Kernel source assembly, builds, and the on-disk build cache.

Sources are stitched on the host in a fixed order, each file preceded by a
``#line`` marker, so the text that is built is exactly the text that is
cached, dumped (``CLPT_DUMP_KERNELS=dir``) and named in build errors; there
are no include paths. Built program binaries are cached on disk, keyed by the
stitched source, the sorted build options and the device/driver identity:
``$CLPT_CACHE_DIR``, else ``$XDG_CACHE_HOME/clpt``, else ``~/.cache/clpt``.
``clpt cache --clear`` empties it (and the tuned settings beside it). Its
binaries are bounded: after each new one is written, the least recently used
(a cache hit renews a binary's time) are removed while they total more than
``$CLPT_CACHE_MB`` (MiB, default 1024; a binary is 0.1-1 MB).
pyopencl's own binary cache is not used: it would make a build that misses
ours (after ``clpt cache --clear``, or a cold build in ``clpt bench``) warm.

PoCL compiles machine code per kernel lazily: once for the program binary
(a work-group function for any local size, which our cache stores) and, by
default, again at a kernel's first launch for that launch's local size,
global offset and grid size. clpt sets POCL_WORK_GROUP_SPECIALIZATION=0 (unless
it is set already) before its first PoCL build, so that PoCL compiles each
kernel once, into the binary: a cold build then costs the front end and one
compile per kernel instead of two, and no launch compiles anything (measured
on the AVX-512 machine: cornell_box 3.2 s -> 2.1 s program plus first launch,
the caustic scenes 7-8 s -> 4-5 s; the generic work-group loop renders
within noise of the specialized one, and the images are bit-identical).

PoCL also compiles one program at a time per process (one lock around its
LLVM work), so the two programs of a caustic scene, built from two threads,
took as long as one after the other. When PoCL builds overlap in this
process, the largest compiles here and the others each in a child process
(a bare Python with pyopencl, the same source, options, device and
environment), which writes the binary for this process to load; a failed
child only means the build happens here after all. The binary is the same
as an in-process build's. CLPT_BUILD_PROCESSES=0 turns this off.

Builds overlap only where the runtime is known to take concurrent
clBuildProgram calls (builds_at_once: PoCL, Intel's CPU runtime); for any
other runtime build() takes one process-wide lock, and the callers that
would build several programs at once (the caustic scenes' two programs,
the tuner's lane candidates) build them one after another instead.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import pyopencl as cl

from .constants import kernel_defines
from .errors import KernelBuildError, SettingsError
from .layout import c_source
from .resources import cache_dir, kernel_dir
from .runtimes import SIMULATORS

# Device libraries in dependency order; entry files (*.cl) come after them.
LIBRARY_FILES = ("features.h", "simd.h", "rng.h", "sampler.h", "sampling.h", "scene.h", "bvh.h", "texture.h",
                 "lights.h", "photon_aim.h", "camera.h", "film.h", "microfacet.h", "bsdf.h",
                 "photon_grid.h")


def clear_cache() -> int:
    """Remove every cached kernel binary, the tuned settings and the device
    checks; returns how many kernel binaries there were."""
    d = cache_dir() / "kernels"
    n = len(list(d.glob("*.bin"))) if d.is_dir() else 0
    for sub in ("kernels", "tune", "devices"):
        shutil.rmtree(cache_dir() / sub, ignore_errors=True)
    return n


def cache_limit_bytes() -> int:
    """The kernel binaries' bound in bytes ($CLPT_CACHE_MB MiB, default 1024)."""
    raw = os.environ.get("CLPT_CACHE_MB", "1024")
    try:
        mb = float(raw)
    except ValueError:
        raise SettingsError(f"CLPT_CACHE_MB must be a number of megabytes, not {raw!r}") from None
    if not mb >= 0 or mb == float("inf"):
        raise SettingsError(f"CLPT_CACHE_MB must be a finite number of megabytes >= 0, not {raw!r}")
    return int(mb * 2 ** 20)


def prune_cache(folder: Path, keep: Path | None = None, limit: int | None = None) -> int:
    """Remove the least recently used binaries in `folder` (by modification
    time, which a cache hit renews) while they total more than `limit` bytes
    (cache_limit_bytes()); `keep` (the binary just written) stays. Files that
    vanish meanwhile (another process pruning) are skipped. Returns how many
    were removed."""
    limit = cache_limit_bytes() if limit is None else limit
    entries = []
    with contextlib.suppress(OSError):
        for e in os.scandir(folder):
            if e.name.endswith(".bin"):
                with contextlib.suppress(OSError):
                    st = e.stat()
                    entries.append((st.st_mtime, st.st_size, e.path))
    total = sum(size for _, size, _ in entries)
    removed = 0
    for _, size, name in sorted(entries):
        if total <= limit:
            break
        if keep is not None and Path(name) == keep:
            continue
        with contextlib.suppress(OSError):
            os.unlink(name)
            removed += 1
        total -= size
    return removed


def stitch(entry_files, generated: dict[str, str] | None = None, after: str = "simd.h") -> str:
    """The shared constants, library files, then entry files, with #line
    markers. `generated` maps a pseudo file name to text inserted right after
    the library file `after`; the record layout (clpt/layout.py) always comes
    right after simd.h."""
    kd = kernel_dir()
    parts = [f'#line 1 "<constants>"\n{kernel_defines()}']
    for name in list(LIBRARY_FILES) + list(entry_files):
        path = Path(name) if os.path.isabs(name) else kd / name
        parts.append(f'#line 1 "kernels/{path.name}"\n{path.read_text()}')
        if name == "simd.h":
            parts.append(f'#line 1 "<clpt/layout.py>"\n{c_source()}')
        if name == after and generated:
            for gname, text in generated.items():
                parts.append(f'#line 1 "{gname}"\n{text}')
    return "\n".join(parts)


@dataclass
class BuildInfo:
    seconds: float
    cache_hit: bool
    key: str
    options: list


def _key(source: str, options, dev_identity: str) -> str:
    h = hashlib.sha256()
    for part in (source, "\0".join(options), dev_identity, cl.VERSION_TEXT):
        h.update(part.encode())
        h.update(b"\1")
    return h.hexdigest()[:32]


def _dump(source: str, options, key: str) -> Path:
    d = os.environ.get("CLPT_DUMP_KERNELS")
    out = Path(d) if d else Path(tempfile.gettempdir()) / "clpt-kernels"
    out.mkdir(parents=True, exist_ok=True)
    p = out / f"{key}.cl"
    p.write_text(f"// options: {' '.join(options)}\n{source}")
    return p


POCL_GENERIC_WG = ("POCL_WORK_GROUP_SPECIALIZATION", "0")


def pocl_defaults(dctx):
    """On PoCL, compile each kernel once, for any local size (see above). PoCL
    reads the variable at every kernel compile and launch, so it is set in
    this process's environment; a value set beforehand wins."""
    if dctx.is_pocl:
        os.environ.setdefault(*POCL_GENERIC_WG)


# A child build: the device by platform and device index, checked against
# its identity; the program source and options from stdin, the binary to argv[1].
_CHILD = r"""
import json, os, sys, warnings
import pyopencl as cl
job = json.loads(sys.stdin.read())
p = cl.get_platforms()[job["platform"]]
d = p.get_devices()[job["device"]]
ident = "|".join([p.name.strip(), p.version, d.name.strip(), d.vendor, d.version, d.driver_version])
if ident != job["identity"]:
    sys.exit("device mismatch: " + ident)
warnings.simplefilter("ignore")
prg = cl.Program(cl.Context([d]), job["source"]).build(options=job["options"], cache_dir=False)
b = prg.get_info(cl.program_info.BINARIES)[0]
tmp = sys.argv[1] + ".%d.tmp" % os.getpid()
with open(tmp, "wb") as f:
    f.write(b)
os.replace(tmp, sys.argv[1])
"""

_overlap_lock = threading.Lock()
_overlapping = []      # [size, sequence number] of PoCL source builds deciding or running here
_seq = iter(range(1 << 62))
OVERLAP_WINDOW = 0.03  # seconds a PoCL source build waits for builds started with it


def _device_index(dev):
    for pi, p in enumerate(cl.get_platforms()):
        for di, d in enumerate(p.get_devices()):
            if d == dev:
                return pi, di
    return None


def _child_build(dctx, source: str, options, out: Path) -> bool:
    """Build in a child process, the binary written to `out`; False if that failed."""
    where = _device_index(dctx.device)
    if where is None:
        return False
    job = {"platform": where[0], "device": where[1], "identity": dctx.identity(), "source": source,
           "options": list(options)}
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        p = subprocess.run([sys.executable, "-c", _CHILD, str(out)], input=json.dumps(job), text=True,
                           capture_output=True, env=dict(os.environ), timeout=600)
    except (OSError, subprocess.SubprocessError):
        return False
    return p.returncode == 0 and out.is_file()


def _elsewhere(me) -> bool:
    """Whether this PoCL build should go to a child: another build overlaps it
    and is larger (or as large and older)."""
    time.sleep(OVERLAP_WINDOW)
    with _overlap_lock:
        return any(o is not me and (o[0], -o[1]) > (me[0], -me[1]) for o in _overlapping)


def builds_at_once(dctx) -> bool:
    """Whether programs for this device may build at the same time, from
    several threads of this process. Only where the runtime is known to take
    it: PoCL (it compiles behind one lock of its own, and build() sends
    overlapping builds to child processes) and Intel's CPU runtime (eight
    builds of the caustic scene's programs at once from threads, three rounds,
    all fine). Elsewhere one after another: Oclgrind 21.10 segfaults when two
    clBuildProgram calls overlap, and a runtime not tried is not trusted with
    them (a GPU driver's build is mostly one thread anyway)."""
    if dctx.is_pocl:
        return True
    return intel_cpu(dctx)


def intel_cpu(dctx) -> bool:
    """Whether a device is Intel's CPU runtime: the CPU device of an Intel
    platform (its GPU and FPGA-emulator runtimes are other device types)."""
    return "intel" in dctx.platform.lower() and dctx.device.type == cl.device_type.CPU


# Held around every build (source or cached binary) for a device whose
# runtime does not take concurrent builds (builds_at_once).
_one_build = threading.Lock()


def _parallel_builds() -> bool:
    return os.environ.get("CLPT_BUILD_PROCESSES", "1") != "0" and (os.cpu_count() or 1) > 1


def filter_pixels(dctx) -> int:
    """Pixels per work-item of the cone filter's kernels (kernels/filter.cl
    CLPT_FILTER_PIXELS): 16 on CPU devices, whose compilers run one float16
    work-item faster than two float8 ones (the cone pass 1.3-1.8x on Intel's
    runtime and PoCL), 8 elsewhere (a GPU's work-item would spill registers)."""
    return 16 if getattr(dctx, "is_cpu", False) else 8


def filter_options(dctx) -> list:
    """The build option that sets filter_pixels where it is not the kernels' default of 8."""
    return [] if filter_pixels(dctx) == 8 else [f"-DCLPT_FILTER_PIXELS={filter_pixels(dctx)}"]


def device_options(dctx) -> list:
    """Build options that follow the device: CLPT_PREFETCH on PoCL's CPU
    devices and Intel's CPU runtime, which compile with clang, whose
    __builtin_prefetch becomes a prefetch instruction (kernels/scene.h
    scene_prefetch). Not elsewhere: Oclgrind, which reports every device
    type, cannot run the intrinsic, and GPU compilers are not known to take
    the builtin. The environment variable CLPT_PREFETCH=0 leaves it out;
    images are the same either way. On simulators (Oclgrind), which cannot
    run LLVM's bitreverse intrinsic either, CLPT_BITREVERSE_TABLE: the
    sampler reverses bits by a table (kernels/sampler.h bits_reversed)."""
    if any(s in f"{dctx.platform} {getattr(dctx, 'name', '')}".lower() for s in SIMULATORS):
        return ["-DCLPT_BITREVERSE_TABLE=1"]
    if os.environ.get("CLPT_PREFETCH", "1") == "0" or not getattr(dctx, "is_cpu", False):
        return []
    if getattr(dctx, "is_pocl", False) or intel_cpu(dctx):
        return ["-DCLPT_PREFETCH=1"]
    return []


def build(dctx, source: str, options, use_cache: bool = True):
    """Build `source` for one DeviceContext; returns (cl.Program, BuildInfo)."""
    pocl_defaults(dctx)
    # -w: compilers' remarks (PoCL's on wide-vector ABIs, printed to stderr at
    # its lazy device compile) are not the user's business; errors still show.
    options = list(options) + ["-w"] + device_options(dctx) + filter_options(dctx)
    key = _key(source, options, dctx.identity())
    limit = cache_limit_bytes() if use_cache else None  # (a bad CLPT_CACHE_MB is said before compiling)
    if os.environ.get("CLPT_DUMP_KERNELS"):
        _dump(source, options, key)
    path = cache_dir() / "kernels" / f"{key}.bin"
    t0 = time.perf_counter()
    with (contextlib.nullcontext() if builds_at_once(dctx) else _one_build):
        return _build(dctx, source, options, key, path, use_cache, t0, limit)


def _build(dctx, source, options, key, path, use_cache, t0, limit=None):
    """build()'s work, from the cache or the source (under _one_build where that is held)."""
    with warnings.catch_warnings():
        # Compiler remarks (e.g. PoCL's notes on wide vector ABIs) are not the user's business.
        warnings.simplefilter("ignore", cl.CompilerWarning)
        if use_cache and path.is_file():
            try:
                prg = cl.Program(dctx.context, [dctx.device], [path.read_bytes()]).build(options=options)
                with contextlib.suppress(OSError):
                    os.utime(path)  # recently used (the bound below removes the least recently used first)
                return prg, BuildInfo(time.perf_counter() - t0, True, key, options)
            except (cl.Error, OSError):
                path.unlink(missing_ok=True)  # stale or damaged entry: rebuild below
        me = None
        if dctx.is_pocl and _parallel_builds():
            me = [len(source), next(_seq)]
            with _overlap_lock:
                _overlapping.append(me)
        try:
            if me is not None and _elsewhere(me):
                prg = _built_elsewhere(dctx, source, options, path if use_cache else None)
                if prg is not None:
                    return prg, BuildInfo(time.perf_counter() - t0, False, key, options)
            prg = cl.Program(dctx.context, source).build(options=options, devices=[dctx.device],
                                                         cache_dir=False)
        except cl.RuntimeError as e:
            dumped = _dump(source, options, key)
            raise KernelBuildError(f"kernel build failed on {dctx.label} with options {' '.join(options)}; "
                                   f"the source is in {dumped}\n{e}") from None
        finally:
            if me is not None:
                with _overlap_lock:
                    _overlapping.remove(me)
    if use_cache:
        try:
            binaries = prg.get_info(cl.program_info.BINARIES)
            if binaries and binaries[0]:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(f".{os.getpid()}.tmp")
                tmp.write_bytes(binaries[0])
                os.replace(tmp, path)  # atomic: concurrent renders never read half a file
                prune_cache(path.parent, keep=path, limit=limit)
        except (cl.Error, OSError):
            pass  # a cache that cannot be written only costs the next build
    # (On PoCL, fetching the binary is where the kernels compile: it is counted.)
    return prg, BuildInfo(time.perf_counter() - t0, False, key, options)


def _built_elsewhere(dctx, source, options, path):
    """The program built in a child process and loaded here; None if that failed."""
    with tempfile.TemporaryDirectory(prefix="clpt-build-") as tmp:
        out = path or Path(tmp) / "program.bin"
        if not _child_build(dctx, source, options, out):
            return None
        try:
            return cl.Program(dctx.context, [dctx.device], [out.read_bytes()]).build(options=options)
        except (cl.Error, OSError):
            return None


def event_seconds(event) -> float:
    """Device time of a finished kernel launch, from its profiling event (nan if
    the queue has no profiling)."""
    try:
        return (event.profile.end - event.profile.start) * 1e-9
    except cl.Error:
        return float("nan")


def note_time(times: dict, name: str, event):
    """Append a finished launch's device time to times[name]."""
    times.setdefault(name, []).append(event_seconds(event))
