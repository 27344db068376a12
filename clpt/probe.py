"""Whether a device can render: a check before its first render, cached.

A runtime that lists a device may still be unable to compile clpt's kernels
for it: the PoCL in pyopencl's wheels (LLVM 14) aborts, crashes or hangs on
CPUs newer than its LLVM, and only on kernels as large as clpt's (a small
test kernel builds). So the check is the real thing: a child process builds
the Cornell box's path-tracing kernel at the lane width the device would
render with, renders it at 16x16 and 32 samples per pixel, and the image
must be finite with a mean near the scene's (0.148 at 4096 spp; the 32-spp
mean's spread over seeds is 0.009, so 0.098-0.198 is over 5 sigma). A
compiler that aborts or crashes takes only the child with it, and its last
line of output becomes the reason. A check that does not finish in
CHECK_SECONDS fails too (on this project's AVX-512 machine the wheel's PoCL
aborted after 1.4-35 s, crashed after 100 s, or ran past 60 s).

Results are cached in ``<cache>/devices`` by the device and driver identity,
the lane width, clpt's version and its kernel sources, so each device is
checked once per installation and again when a driver or the kernels change;
``clpt cache --clear`` removes them. Simulators (Oclgrind) are not checked:
they are chosen only by name, for debugging, and a check would take minutes
there. ``CLPT_DEVICE_CHECK=0`` turns checking off.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from .program import cache_dir
from .resources import kernel_dir
from .version import __version__

CHECK_SECONDS = 30.0  # a healthy CPU runtime builds and renders it in 1-6 s
CHECK_SIZE, CHECK_SPP, CHECK_SEED = 16, 32, 1
CHECK_MEAN = (0.098, 0.198)


@dataclass(frozen=True)
class CheckResult:
    ok: bool
    lanes: int
    reason: str        # why it failed ("" when ok)
    seconds: float     # how long the check took (when it ran)
    mean: float = float("nan")
    cached: bool = False

    def line(self) -> str:
        if self.ok:
            return f"renders ({self.lanes} lanes; checked in {self.seconds:.1f} s)"
        return f"cannot render at {self.lanes} lanes: {self.reason}"


def enabled() -> bool:
    return os.environ.get("CLPT_DEVICE_CHECK", "1") != "0"


def _sources_hash() -> str:
    h = hashlib.sha256(__version__.encode())
    for p in sorted(kernel_dir().iterdir()):
        if p.suffix in (".h", ".cl"):
            h.update(p.name.encode())
            h.update(p.read_bytes())
    return h.hexdigest()


_memo: dict[str, CheckResult] = {}


def _key(identity: str, lanes: int) -> str:
    return hashlib.sha256(f"{identity}\1{lanes}\1{_sources_hash()}".encode()).hexdigest()[:32]


def _path(key: str) -> Path:
    return cache_dir() / "devices" / f"{key}.json"


def cached(identity: str, lanes: int) -> CheckResult | None:
    key = _key(identity, lanes)
    if key in _memo:
        return _memo[key]
    try:
        d = json.loads(_path(key).read_text())
        r = CheckResult(bool(d["ok"]), int(d["lanes"]), str(d["reason"]), float(d["seconds"]),
                        float(d.get("mean", "nan")), cached=True)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    _memo[key] = r
    return r


def _save(identity: str, label: str, r: CheckResult):
    key = _key(identity, r.lanes)
    _memo[key] = r
    p = _path(key)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps({**asdict(r), "cached": False, "device": label, "identity": identity}, indent=1))
        os.replace(tmp, p)
    except OSError:
        pass  # an unwritable cache only costs the next process a check


def _reason(proc: subprocess.CompletedProcess) -> str:
    """One line: the child's last meaningful line of output, and how it ended."""
    lines = [ln.strip() for ln in (proc.stderr + "\n" + proc.stdout).splitlines() if ln.strip()]
    skip = ("warning", "prg.build", "Traceback", "File ", "^", "still have references")
    useful = [ln for ln in lines if not ln.startswith(skip) and "CompilerWarning" not in ln]
    last = useful[-1] if useful else ""
    if proc.returncode < 0:
        try:
            sig = signal.Signals(-proc.returncode).name
        except ValueError:
            sig = f"signal {-proc.returncode}"
        how = f"the kernel build crashed ({sig})"
        return f"{how}: {last}" if last else how
    return last or f"the check exited with status {proc.returncode}"


def _command() -> list[str]:
    return [sys.executable, "-m", "clpt.probe_check"]


def check(device, identity: str, label: str, lanes: int, where: tuple[int, int]) -> CheckResult:
    """The device's check at `lanes`, from the cache or run now in a child
    process. where: (platform index, device index) in cl.get_platforms()."""
    hit = cached(identity, lanes)
    if hit is not None:
        return hit
    job = {"platform": where[0], "device": where[1], "identity": identity, "lanes": lanes}
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(_command(), input=json.dumps(job), text=True,
                              capture_output=True, timeout=CHECK_SECONDS, env=dict(os.environ))
    except subprocess.TimeoutExpired:
        # Saved like any failure (`clpt cache --clear` checks again): the PoCL of pyopencl's
        # wheel sometimes spends minutes before it crashes, and every process would wait for it.
        r = CheckResult(False, lanes, f"building and rendering a 16x16 Cornell box took over {CHECK_SECONDS:g} s",
                        time.perf_counter() - t0)
        _save(identity, label, r)
        return r
    except OSError as e:
        return CheckResult(False, lanes, f"could not start the check ({e})", 0.0)
    secs = time.perf_counter() - t0
    try:
        out = json.loads(proc.stdout.strip().splitlines()[-1]) if proc.returncode == 0 else None
    except (ValueError, IndexError):
        out = None
    if out is None:
        r = CheckResult(False, lanes, _reason(proc), secs)
    elif not out["finite"]:
        r = CheckResult(False, lanes, "the test render has NaN or infinite pixels", secs, out["mean"])
    elif not CHECK_MEAN[0] <= out["mean"] <= CHECK_MEAN[1]:
        r = CheckResult(False, lanes, f"the test render's mean is {out['mean']:.4f}, not "
                                      f"{CHECK_MEAN[0]}-{CHECK_MEAN[1]}: the device computes wrong results", secs,
                        out["mean"])
    else:
        r = CheckResult(True, lanes, "", secs, out["mean"])
    _save(identity, label, r)
    return r


def check_in_background(identity: str, label: str, lanes: int, where: tuple[int, int]) -> bool:
    """Start the check in a detached process that caches its result (the
    render goes on meanwhile); False if it is cached, running already
    (another process started it less than BACKGROUND_STALE seconds ago) or
    cannot start."""
    if cached(identity, lanes) is not None:
        return False
    marker = _path(_key(identity, lanes)).with_suffix(".checking")
    try:
        marker.parent.mkdir(parents=True, exist_ok=True)
        if marker.exists() and time.time() - marker.stat().st_mtime < BACKGROUND_STALE:
            return False
        marker.write_text(str(os.getpid()))
        job = {"platform": where[0], "device": where[1], "identity": identity, "lanes": lanes, "label": label,
               "marker": str(marker)}
        # A process that forks the check off and exits at once: the check is nobody's child
        # to wait for, and outlives this process if it must.
        subprocess.run([sys.executable, "-c", _DETACH, json.dumps(job)], stdin=subprocess.DEVNULL,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=dict(os.environ), timeout=30)
        return True
    except (OSError, subprocess.SubprocessError):
        return False


_DETACH = """
import os, sys
if os.fork():
    os._exit(0)
os.setsid()
from clpt.probe import _check_main
_check_main(sys.argv[1])
"""
BACKGROUND_STALE = 2 * CHECK_SECONDS + 30


def _check_main(text: str):
    """Run a check and cache it (a background check; the job as JSON)."""
    job = json.loads(text)
    try:
        check(None, job["identity"], job["label"], job["lanes"], (job["platform"], job["device"]))
    finally:
        Path(job["marker"]).unlink(missing_ok=True)

