"""Executors run work items on workers and report each one when it ends.

- LocalExecutor: workers in this process (DeviceWorker, or anything with its
  start/run/sums methods), one thread each. Sums stay with the workers
  (`resident`): the driver reads them when it needs them.
- DaskExecutor: tasks on a Dask cluster. Each worker process opens its own
  device, builds the job's kernels and photon maps once, and returns the raw
  sums of each item, which the driver adds up. A task whose worker dies is
  rerun by Dask on another.

Both call done(slot, item, result, error) from another thread when an item ends.
"""

from __future__ import annotations

import queue
import socket
import threading

import pyopencl as cl

from ..denoise import apply_denoiser
from ..device import DeviceContext, select_devices
from .accum import Accumulator
from .device import DeviceWorker, device_features


class LocalExecutor:
    resident = True

    def __init__(self, workers):
        self.workers = list(workers)
        self.labels = [w.label for w in self.workers]
        self.live = set(range(len(self.workers)))
        self._queues = []
        self._threads = []
        for i in range(len(self.workers)):
            q = queue.SimpleQueue()
            t = threading.Thread(target=self._loop, args=(i, q), daemon=True, name=f"clpt-worker-{i}")
            t.start()
            self._queues.append(q)
            self._threads.append(t)

    def _loop(self, i, q):
        while True:
            task = q.get()
            if task is None:
                return
            fn, done = task
            try:
                res = fn()
            except BaseException as e:  # noqa: BLE001 - reported to the driver
                done(e, None)
            else:
                done(None, res)

    def _call(self, i, fn):
        """Run fn on worker i's thread (after what it is doing) and wait for it."""
        box = {}
        ev = threading.Event()

        def done(err, res):
            box["err"], box["res"] = err, res
            ev.set()

        self._queues[i].put((fn, done))
        ev.wait()
        if box["err"] is not None:
            raise box["err"]
        return box["res"]

    @property
    def slots(self) -> list[int]:
        return sorted(self.live)

    def start(self, job, initial: Accumulator | None):
        """Every worker ready for the job; the first continues from `initial`."""
        for i in sorted(self.live):
            self._call(i, lambda w=self.workers[i], first=i == min(self.live): w.start(job, initial if first
                                                                                       else None))

    def submit(self, slot, item, done):
        w = self.workers[slot]
        self._queues[slot].put((lambda: w.run(item), lambda err, res: done(slot, item, res, err)))

    def sums(self) -> Accumulator | None:
        """The live workers' sums, added in worker order."""
        parts = [self._call(i, self.workers[i].sums) for i in sorted(self.live)]
        return Accumulator.merge(parts) if parts else None

    def snapshot(self):
        """Queue copies of the live workers' sums now, from this thread (each
        device's queue orders them after the item it is running); returns
        wait() -> their Accumulators in worker order."""
        taken = [self.workers[i].snapshot() for i in sorted(self.live)]

        def wait():
            out = []
            for raw, events in taken:
                cl.wait_for_events(events)
                out.append(Accumulator.from_device(*raw))
            return out

        return wait

    def drop(self, slot):
        self.live.discard(slot)

    def denoise(self, *args):
        """apply_denoiser(*args) with a live worker's cone filter, on its thread."""
        i = min(self.live) if self.live else 0
        w = self.workers[i]
        return self._call(i, lambda: apply_denoiser(w.filter, *args))

    def close(self):
        for q in self._queues:
            q.put(None)


# --- Dask -----------------------------------------------------------------------------

_WORKER_CACHE: dict = {}
_WORKER_LOCK = threading.Lock()


def _worker_device(job, device):
    """This process's DeviceWorker for the job's scene and options (built once)."""
    key = (job.scene_key(), job.options, device)
    w = _WORKER_CACHE.get(key)
    if w is None:
        _WORKER_CACHE.clear()
        packed = job.options.pack(job.scene)
        # Without a device named: the default for this kind of kernel, as the client's own would be.
        photons = packed.has_caustics and job.options.photons is not False
        dctx = DeviceContext(select_devices(device, photons=photons)[0])
        w = DeviceWorker(dctx, packed, device_features(dctx, packed, job.options), job.options.use_cache)
        w.started = None
        _WORKER_CACHE[key] = w
    if w.started != job.key:
        w.start(job)
        w.started = job.key
    return w


def dask_run_item(job, item, device=None):
    """A Dask task: the raw sums of one work item, rendered from zero."""
    with _WORKER_LOCK:  # one device per process: its items run one at a time
        w = _worker_device(job, device)
        w.zero()
        res = w.run(item)
        res.sums = w.sums()
        res.host = socket.gethostname()
        res.label = w.label
        return res


def dask_denoise(job, args, device=None):
    with _WORKER_LOCK:
        w = _worker_device(job, device)
        return apply_denoiser(w.filter, *args)


class DaskExecutor:
    """Work items as tasks on a Dask cluster (a distributed.Client)."""

    resident = False
    retries = 3  # a failed task is the task's, not the slot's: it is tried again this often

    def __init__(self, client, device=None, slots: int | None = None, depth: int = 2):
        self.client = client
        self.device = device
        if slots is None:
            # `depth` items in flight per worker thread: the next one is queued
            # there while the last one's sums travel back.
            info = client.scheduler_info()
            slots = depth * (sum(w.get("nthreads", 1) for w in info.get("workers", {}).values()) or 1)
        self.labels = [f"dask slot {i}" for i in range(slots)]
        self.live = set(range(slots))
        self.futures = set()
        self.job = None

    @property
    def slots(self) -> list[int]:
        return sorted(self.live)

    def start(self, job, initial):
        # The job travels with each task (a few kB): scattered data dies with
        # the worker that holds it, and takes its dependent tasks along.
        self.job = job

    def submit(self, slot, item, done):
        fut = self.client.submit(dask_run_item, self.job, item, self.device, pure=False)
        self.futures.add(fut)

        def cb(f):
            self.futures.discard(f)
            try:
                res = f.result()
            except BaseException as e:  # noqa: BLE001
                done(slot, item, None, e)
            else:
                done(slot, item, res, None)

        fut.add_done_callback(cb)

    def sums(self):
        return None

    def drop(self, slot):
        self.live.discard(slot)

    def denoise(self, *args):
        return self.client.submit(dask_denoise, self.job, args, self.device, pure=False).result()

    def close(self):
        """Nothing to release: the Client belongs to the caller, who closes it."""
