"""Kernel source assembly, builds, and the on-disk build cache.

Sources are stitched on the host in a fixed order, each file preceded by a
``#line`` marker, so the text that is built is exactly the text that is
cached, dumped (``CLPT_DUMP_KERNELS=dir``) and named in build errors; there
are no include paths. Built program binaries are cached on disk, keyed by the
stitched source, the sorted build options and the device/driver identity:
``$CLPT_CACHE_DIR``, else ``$XDG_CACHE_HOME/clpt``, else ``~/.cache/clpt``.
``clpt cache --clear`` empties it (and the tuned settings beside it).
pyopencl's own binary cache is not used: it would make a build that misses
ours (after ``clpt cache --clear``, or a cold build in ``clpt bench``) warm.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import pyopencl as cl

from .constants import kernel_defines
from .resources import kernel_dir

# Device libraries in dependency order; entry files (*.cl) come after them.
LIBRARY_FILES = ("features.h", "simd.h", "rng.h", "sampling.h", "scene.h", "bvh.h", "lights.h", "photon_aim.h",
                 "camera.h", "accum.h", "bsdf.h", "photon_grid.h")


class KernelBuildError(RuntimeError):
    """The OpenCL compiler rejected a kernel build."""


def cache_dir() -> Path:
    env = os.environ.get("CLPT_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "clpt"


def clear_cache() -> int:
    """Remove every cached kernel binary and the tuned settings; returns how
    many kernel binaries there were."""
    d = cache_dir() / "kernels"
    n = len(list(d.glob("*.bin"))) if d.is_dir() else 0
    for sub in ("kernels", "tune"):
        shutil.rmtree(cache_dir() / sub, ignore_errors=True)
    return n


def stitch(entry_files, generated: dict[str, str] | None = None, after: str = "simd.h") -> str:
    """The shared constants, library files, then entry files, with #line
    markers. `generated` maps a pseudo file name to text inserted right after
    the library file `after`; the record layout (clpt/layout.py) always comes
    right after simd.h."""
    from .layout import c_source
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


def build(dctx, source: str, options, use_cache: bool = True):
    """Build `source` for one DeviceContext; returns (cl.Program, BuildInfo)."""
    # -w: compilers' remarks (PoCL's on wide-vector ABIs, printed to stderr at
    # its lazy device compile) are not the user's business; errors still show.
    options = list(options) + ["-w"]
    key = _key(source, options, dctx.identity())
    if os.environ.get("CLPT_DUMP_KERNELS"):
        _dump(source, options, key)
    path = cache_dir() / "kernels" / f"{key}.bin"
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        # Compiler remarks (e.g. PoCL's notes on wide vector ABIs) are not the user's business.
        warnings.simplefilter("ignore", cl.CompilerWarning)
        if use_cache and path.is_file():
            try:
                prg = cl.Program(dctx.context, [dctx.device], [path.read_bytes()]).build(options=options)
                return prg, BuildInfo(time.perf_counter() - t0, True, key, options)
            except (cl.Error, OSError):
                path.unlink(missing_ok=True)  # stale or damaged entry: rebuild below
        try:
            prg = cl.Program(dctx.context, source).build(options=options, devices=[dctx.device],
                                                         cache_dir=False)
        except cl.RuntimeError as e:
            dumped = _dump(source, options, key)
            raise KernelBuildError(f"kernel build failed on {dctx.label} with options {' '.join(options)}; "
                                   f"the source is in {dumped}\n{e}") from None
    seconds = time.perf_counter() - t0
    if use_cache:
        try:
            binaries = prg.get_info(cl.program_info.BINARIES)
            if binaries and binaries[0]:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(f".{os.getpid()}.tmp")
                tmp.write_bytes(binaries[0])
                os.replace(tmp, path)  # atomic: concurrent renders never read half a file
        except (cl.Error, OSError):
            pass  # a cache that cannot be written only costs the next build
    return prg, BuildInfo(seconds, False, key, options)


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
