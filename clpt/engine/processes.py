"""ProcessExecutor: each device in a process of its own on this machine.

Several OpenCL devices in one process do not always run at once. PoCL's CPU
driver keeps one scheduler and one thread pool for every pthread device of
the process, so PoCL split into two one-core devices (POCL_DEVICES="pthread
pthread", POCL_MAX_PTHREAD_COUNT=1) renders no faster in one process than
one of them (measured: 0.81x). In processes of their own, each device has
its own runtime and threads.

Each process opens its device by platform:device index, builds the job's
kernels once (from the kernel cache: the parent built them already), and
returns the raw sums of each item, which the driver adds up in float64 (as
with Dask): the image equals the one-process image to float rounding, not
bit for bit. A process that dies takes only its items in flight, which go to
the others.
"""

from __future__ import annotations

import os
import pickle
import struct
import subprocess
import sys
import threading
import warnings

from ..denoise import apply_denoiser
from ..device import DeviceContext, _all_devices, select_devices
from .executors import _worker_device

_JOB = {}  # in a worker process: the job being rendered, by key


def device_spec(device) -> str:
    """The "platform:device" index selector of a pyopencl Device (as clpt.device lists them)."""
    for pi, di, _, d in _all_devices():
        if d == device:
            return f"{pi}:{di}"
    raise ValueError(f"{device.name} is not among this process's OpenCL devices")


# --- the wire: length-prefixed pickles over a pipe pair --------------------------------

def _send(f, obj):
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    f.write(struct.pack("<Q", len(data)) + data)
    f.flush()


def _recv(f):
    head = f.read(8)
    if len(head) < 8:
        raise EOFError("the worker process ended")
    (n,) = struct.unpack("<Q", head)
    data = f.read(n)
    if len(data) < n:
        raise EOFError("the worker process ended mid-message")
    return pickle.loads(data)


# --- in the worker process ---------------------------------------------------------------

def _start(job, device: str) -> str:
    _JOB.clear()
    _JOB[job.key] = job
    return _worker_device(job, device).label


def _run(key: str, item, device: str) -> dict:
    w = _worker_device(_JOB[key], device)
    w.zero()
    res = w.run(item)
    res.sums = w.sums()
    return res


def _denoise(key: str, args, device: str):
    return apply_denoiser(_worker_device(_JOB[key], device).filter, *args)


_CALLS = {"start": _start, "run": _run, "denoise": _denoise}


def _serve(fd_in: int, fd_out: int):
    """The worker process's loop: (call, args) in, ("ok", result) or ("error", exception) out."""
    fin, fout = os.fdopen(fd_in, "rb"), os.fdopen(fd_out, "wb")
    while True:
        try:
            name, args = _recv(fin)
        except EOFError:
            return
        try:
            out = ("ok", _CALLS[name](*args))
        except BaseException as e:  # noqa: BLE001 - sent back to the driver
            try:
                pickle.dumps(e)
            except Exception:  # noqa: BLE001
                e = RuntimeError(f"{type(e).__name__}: {e}")
            out = ("error", e)
        _send(fout, out)


class _Child:
    """One worker process: calls run one at a time, in order, on its thread."""

    def __init__(self, env: dict):
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        self.proc = subprocess.Popen(
            [sys.executable, "-c", f"from clpt.engine.processes import _serve; _serve({to_child_r}, {from_child_w})"],
            pass_fds=(to_child_r, from_child_w), env={**os.environ, **env}, stdin=subprocess.DEVNULL)
        os.close(to_child_r)
        os.close(from_child_w)
        self.fout, self.fin = os.fdopen(to_child_w, "wb"), os.fdopen(from_child_r, "rb")
        self.lock = threading.Lock()

    def call(self, name: str, *args):
        with self.lock:
            _send(self.fout, (name, args))
            status, value = _recv(self.fin)
        if status == "error":
            raise value
        return value

    def close(self):
        for f in (self.fout, self.fin):
            try:
                f.close()
            except OSError:
                pass
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()


class ProcessExecutor:
    """One worker process per device (pyopencl Devices or selectors)."""

    resident = False
    retries = 0

    def __init__(self, devices, env: dict | None = None):
        devs = select_devices(list(devices) if isinstance(devices, (list, tuple)) else devices)
        self.specs = [device_spec(d) for d in devs]
        self.labels = [f"{DeviceContext(d).label} [process {i}]" for i, d in enumerate(devs)]
        self.env = dict(env or {})
        self.children = [_Child(self.env) for _ in devs]
        self.live = set(range(len(devs)))
        self.key = None

    @property
    def slots(self) -> list[int]:
        return sorted(self.live)

    def start(self, job, initial):
        """Every process builds the job's worker (in parallel)."""
        self.key = job.key
        errors = {}
        for i in sorted(self.live):
            if self.children[i].proc.poll() is not None:  # died in an earlier render: a fresh one
                self.children[i].close()
                self.children[i] = _Child(self.env)

        def start(i):
            try:
                self.children[i].call("start", job, self.specs[i])
            except Exception as e:  # noqa: BLE001 - a device that cannot start is left out
                errors[i] = e

        threads = [threading.Thread(target=start, args=(i,)) for i in sorted(self.live)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for i, e in sorted(errors.items()):
            warnings.warn(f"{self.labels[i]} could not start ({type(e).__name__}: {e}); rendering without it")
            self.live.discard(i)
        if not self.live:
            raise RuntimeError("no device process could start the render")

    def submit(self, slot, item, done):
        def work():
            try:
                res = self.children[slot].call("run", self.key, item, self.specs[slot])
                res.label = self.labels[slot]
            except BaseException as e:  # noqa: BLE001 - reported to the driver
                done(slot, item, None, e)
            else:
                done(slot, item, res, None)

        threading.Thread(target=work, daemon=True, name=f"clpt-process-{slot}").start()

    def sums(self):
        return None

    def drop(self, slot):
        self.live.discard(slot)

    def denoise(self, *args):
        i = min(self.live)
        return self.children[i].call("denoise", self.key, args, self.specs[i])

    def close(self):
        for c in self.children:
            c.close()
