"""The render loop: hands out work, balances the workers, survives failures,
writes checkpoints and reports progress.

Each free worker gets the schedule's next item, a sample range sized from the
worker's own measured rate: about pass_seconds of work, and near the end at
most its share of what is left (by rate), so the workers finish together. A
worker that fails is dropped; its item, and every item whose samples only it
held, go back to the schedule and are done by the others. A checkpoint waits
until no work is out (so sums and schedule agree), then is written atomically.
"""

from __future__ import annotations

import math
import queue
import signal
import sys
import threading
import time
import warnings
from contextlib import contextmanager
import copy

import numpy as np

from ..adaptive import allocate_error, allocate_paper
from ..errors import WorkerFailure
from ..preview import RenderUpdate
from ..constants import dot_rows
from .accum import LUMA, Accumulator
from .checkpoint import write_checkpoint
from .job import RenderJob, WorkItem
from .runresult import RunResult
from .schedule import Schedule

MAX_RANGE = 1 << 16


def run_item(executor, job: RenderJob, item: WorkItem) -> RunResult:
    """Start the executor's workers on `job` and run one item on the first
    live one, waiting for it: a job's preliminary work (the photon pilot)."""
    executor.start(job, None)
    if not executor.slots:
        raise WorkerFailure("no worker to run the job on")
    box = queue.SimpleQueue()
    executor.submit(executor.slots[0], item, lambda slot, it, res, err: box.put((res, err)))
    res, err = box.get()
    if err is not None:
        raise err
    return res


def lane_group_max(n: np.ndarray, lanes: int) -> np.ndarray:
    """Each entry raised to the largest of its group of `lanes` consecutive entries."""
    pad = -len(n) % lanes
    g = np.concatenate([n, np.zeros(pad, dtype=n.dtype)]).reshape(-1, lanes)
    return np.repeat(g.max(axis=1), lanes)[:len(n)].astype(n.dtype)


class Driver:
    def __init__(self, job: RenderJob, executor, *, stats, lum_scale: float = 1.0, length_scale: float = 1.0,
                 lanes: int = 1,
                 schedule: Schedule | None = None, initial: Accumulator | None = None, empty=None,
                 pass_seconds: float = 0.25, time_limit: float | None = None, progress=None, preview=None,
                 on_update=None, update_interval: float = 1.0, checkpoint=None, checkpoint_every=None,
                 stop: threading.Event | None = None, elapsed_before: float = 0.0, describe: str = ""):
        self.job, self.ex, self.stats = job, executor, stats
        self.lum_scale, self.length_scale, self.lanes = lum_scale, length_scale, lanes
        self.schedule = schedule or Schedule(job)
        self.initial = initial
        self.empty = empty          # () -> an empty Accumulator of the job's layout
        self.pass_seconds, self.time_limit = pass_seconds, time_limit
        self.progress, self.preview = progress, preview
        self.on_update, self.update_interval = on_update, update_interval
        self.checkpoint, self.checkpoint_every = checkpoint, checkpoint_every
        self.stop_event = stop or threading.Event()
        self.elapsed_before = elapsed_before
        self.describe = describe
        self.events = queue.SimpleQueue()
        self.failures = []          # (worker label, error text)
        self.checkpoints = []       # (seconds to write, bytes)

    # --- helpers ------------------------------------------------------------------------
    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def _done(self, slot, item, res, err):
        self.events.put((slot, item, res, err))

    def _range_size(self, slot) -> int | None:
        """Samples per pixel for the worker's next range; None: stop (time is up)."""
        per = self.per_spp.get(slot)
        if per is None:
            return 1  # the probe: its time may include a lazy compile
        n = int(max(1, min(self.pass_seconds / max(per, 1e-9), MAX_RANGE)))
        live = self.ex.slots
        if len(live) > 1:
            rates = [1.0 / self.per_spp[s] for s in live if self.per_spp.get(s)]
            unknown = len(live) - len(rates)
            total = sum(rates) + unknown * (1.0 / per)
            share = math.ceil(self.schedule.uniform_left * (1.0 / per) / total)
            n = max(1, min(n, share))
        if self.time_limit is not None:
            left = self.time_limit - self.elapsed()
            if left < per * 0.5:
                return None
            n = max(1, min(n, int(left / per)))
        return n

    def _hand_out(self):
        for slot in self.ex.slots:
            if slot in self.in_flight:
                continue
            n = self._range_size(slot)
            if n is None:
                self.schedule.stop()
                return
            item = self.schedule.take(n)
            if item is None:
                return
            self.in_flight[slot] = (item, time.perf_counter())
            self.ex.submit(slot, item, self._done)

    def total(self) -> Accumulator:
        parts = [self.host]
        if self.ex.resident:
            s = self.ex.sums()
            if s is not None:
                parts.append(s)
        return Accumulator.merge(parts) if len(parts) > 1 else parts[0].copy()

    # --- events -----------------------------------------------------------------------
    def _handle(self, slot, item, res, err):
        _, t_sub = self.in_flight.pop(slot)
        label = self.ex.labels[slot]
        if err is not None:
            self.schedule.failed(item)
            tries = self.tries[id(item)] = self.tries.get(id(item), 0) + 1
            if tries <= getattr(self.ex, "retries", 0):  # the executor's own workers may be fine
                warnings.warn(f"{label}: {item.describe()} failed ({type(err).__name__}: {err}); trying again")
                return
            self.ex.drop(slot)
            self.failures.append((label, f"{type(err).__name__}: {err}"))
            warnings.warn(f"{label} failed ({type(err).__name__}: {err}); its work goes to the others")
            if self.ex.resident:
                self.schedule.requeue(self.done_items.pop(slot, []))
                if slot == self.first_slot and self.initial is not None:
                    self.host.add(self.initial)  # the sums it continued from
            if not self.ex.slots:
                raise WorkerFailure(f"every worker failed; the last: {label}: {err}") from err
            return
        self.schedule.done(item)
        self.fresh = True  # work done since the last checkpoint
        if res.sums is not None:
            self.host.add(res.sums)
        elif self.ex.resident:
            self.done_items.setdefault(slot, []).append(item)
        wall = time.perf_counter() - t_sub
        st = self.stats
        row = res.stats
        st.nonfinite += int(row[0])
        st.camera_rays += int(row[1])
        st.bounce_rays += int(row[2])
        st.shadow_rays += int(row[3])
        for k, v in res.launches.items():
            st.launches[k] = st.launches.get(k, 0) + v
        for k, v in res.kernel_seconds.items():
            st.kernel_seconds.setdefault(k, []).extend(v)
        st.photon_maps.extend(res.photon_maps)
        if item.kind == "samples":
            self.done_spp += item.n
            st.passes.append((res.label or label, item.s0, item.n, res.seconds))
            if res.first:
                st.first_launch_seconds += wall
            else:
                self.per_spp[slot] = wall / item.n
        elif item.kind == "pixels":
            self.round_samples += item.samples
            st.passes.append((res.label or label, -1, item.samples / self.job.n_pix, res.seconds))
        if item.kind == "samples" and self.progress is not None:
            e = self.elapsed()
            self.progress(self.done_spp, self.job.spp, e, self.done_spp * self.job.n_pix / max(e, 1e-9))
        self.passes += 1
        fset = self.job.filter
        if (self.preview is not None and fset is not None and fset.interval and len(self.ex.slots) == 1
                and self.passes % fset.interval == 0):
            self.preview(self._filtered(*self.total().images(self.job.width, self.job.height, self.lum_scale,
                                                             self.length_scale)))

    # --- adaptive rounds ----------------------------------------------------------------
    def _adaptive_round(self):
        """Add the next round's items, or end the adaptive phase."""
        job, aset, sch = self.job, self.job.adaptive, self.schedule
        if self.time_limit is not None and self.elapsed() >= self.time_limit:
            sch.adaptive_over = True
            return
        mean, var, count = self.total().stats(self.lum_scale)
        n_pix = job.n_pix
        budget = job.spp * n_pix
        used = int(count.sum())
        left = budget - used
        if left <= 0:
            sch.adaptive_over = True
            return
        shape = (job.height, job.width)
        lum = dot_rows(mean, LUMA).reshape(shape)
        if aset.scheme == "error":
            # A round spends at most an eighth of the budget, so later rounds
            # see what the earlier ones achieved.
            round_budget = min(left, max(budget // 8, n_pix))
            if self.time_limit is not None and used > 0:
                # Half the time left at the rate so far: the last rounds shrink
                # with it instead of running past the limit.
                rate = used / max(self.elapsed(), 1e-9)
                round_budget = min(round_budget, max(n_pix, int(rate * (self.time_limit - self.elapsed()) / 2)))
            n, _ = allocate_error(lum, var.reshape(shape), count.reshape(shape), aset, round_budget,
                                  mean_rgb=mean.reshape(shape + (3,)))
            depth = np.full(shape, job.max_depth)
        else:
            se = np.sqrt(var / np.maximum(count, 1.0)).reshape(shape)
            n, depth, _ = allocate_paper(lum, aset, job.max_depth, se)
            if n.sum() > left:  # the last round: scale down to the budget
                n = np.floor(n * (left / n.sum())).astype(np.int64)
        pixels = np.flatnonzero(n)
        if len(pixels) == 0:
            sch.adaptive_over = True
            return
        if aset.scheme == "error":
            # The pixels with the most samples first, by octaves of their counts and in
            # image order within one: a work-item's lanes then get alike counts (less
            # idling, fewer samples added to fill them) and the longest work-items start
            # first, so a launch does not end on one of them alone; yet its lanes trace
            # neighbouring pixels, whose paths run alike. (In image order, adaptive
            # samples cost 20-35% more CPU time than uniform ones on the caustics box;
            # sorted by count, 15-20%, then 10-14% on this machine; by octaves, 3-5%
            # less than by count. Uniform counts in a random order cost 7% more than
            # in image order.)
            octave = np.floor(np.log2(n.ravel()[pixels])).astype(np.int16)  # (a radix sort: small integers)
            pixels = pixels[np.argsort(-octave, kind="stable")]
        jobs = np.zeros((len(pixels), 4), dtype=np.uint32)
        jobs[:, 0] = n.ravel()[pixels]
        jobs[:, 1] = np.minimum(depth.ravel()[pixels], 2**31)
        jobs[:, 2] = count[pixels]  # each pixel continues its own sample sequence
        # Contiguous parts, one per worker, their samples in proportion to its
        # rate (neighbouring pixels with alike counts share a work-item: their
        # paths run alike in its lanes). Cut at whole work-items, so the lanes'
        # samples do not depend on how many parts.
        live = self.ex.slots
        rates = np.array([1.0 / self.per_spp[s] if self.per_spp.get(s) else 1.0 for s in live])
        groups = -(-len(pixels) // self.lanes)
        if aset.scheme == "error":
            # Each work-item's samples (its busiest lane's); cut where the
            # running sum's midpoints pass each worker's share.
            per_item = lane_group_max(jobs[:, 0].astype(np.int64), self.lanes)[::self.lanes]
            work = np.cumsum(per_item)
            cuts = np.searchsorted(work - per_item / 2, np.cumsum(rates)[:-1] / rates.sum() * work[-1]) * self.lanes
        else:
            cuts = np.round(np.cumsum(rates) / rates.sum() * groups).astype(int)[:-1] * self.lanes
        cuts = np.minimum(cuts, len(pixels))
        parts = [p for p in np.split(np.arange(len(pixels)), cuts)]
        # A work-item lasts as long as its busiest lane: each lane gets as many
        # samples as the busiest of its work-item's lanes, when the budget allows.
        more = [lane_group_max(jobs[idx, 0], self.lanes) for idx in parts]
        if sum(int(m.sum()) for m in more) <= left:
            for idx, m in zip(parts, more):
                jobs[idx, 0] = m
        # Progressive photons: a round gathers from as many fresh maps as its
        # samples fill at the uniform phase's rate (spp_per_map samples of
        # every pixel per map), each pixel's samples spread evenly over them.
        # With one map per round, a map served up to eight times the camera
        # samples of a uniform one: its photons' noise, shared by all those
        # samples, went unseen by the per-pixel error, and the radius shrank
        # eight times slower.
        items = []
        if job.spp_per_map:
            first = -(-job.uniform_spp // job.spp_per_map) + sch.maps
            k = int(max(1, min(round(int(jobs[:, 0].sum()) / (n_pix * job.spp_per_map)), int(jobs[:, 0].max()))))
            n = jobs[:, 0].astype(np.int64)
            lo = np.zeros_like(n)
            for j in range(k):
                hi = n * (j + 1) // k  # map j: samples [lo, hi) of each pixel's
                count_j = hi - lo
                for idx in parts:
                    idx = idx[count_j[idx] > 0]
                    if len(idx):
                        sl = np.take(jobs, idx, axis=0)  # (its samples, max depth, its first sample, 0)
                        sl[:, 0] = count_j[idx]
                        sl[:, 2] += lo[idx].astype(np.uint32)
                        items.append(WorkItem("pixels", pixels=pixels[idx], jobs=sl, iteration=first + j,
                                              round=sch.rounds))
                lo = hi
            sch.maps += k
        else:
            items = [WorkItem("pixels", pixels=pixels[idx], jobs=jobs[idx], iteration=0, round=sch.rounds)
                     for idx in parts if len(idx)]
        sch.add_round(items)
        self.round_open = True

    # --- checkpoints and updates ---------------------------------------------------------
    def write_checkpoint(self, sums: Accumulator | None = None, wait: bool = False):
        """Snapshot the sums and the schedule (no work is out) and write them,
        in a background thread unless `wait`: the workers go on meanwhile."""
        if self.checkpoint is None:
            return
        t = time.perf_counter()
        self.fresh = False
        self.last_checkpoint = t
        sums = sums if sums is not None else self.total()
        self.join_writer()
        if sums.samples == 0:
            return
        args = (self.checkpoint, self.job, sums, self.schedule.state())
        kw = dict(elapsed=self.elapsed_before + self.elapsed(), devices=self.ex.labels,
                  extra={"features": self.describe})
        stall = time.perf_counter() - t

        def write():
            t0 = time.perf_counter()
            size = write_checkpoint(*args, **kw)
            self.checkpoints.append((stall, time.perf_counter() - t0, size))

        if wait:
            write()
        else:
            self.writer = threading.Thread(target=write, name="clpt-checkpoint")
            self.writer.start()

    def join_writer(self):
        w = getattr(self, "writer", None)
        if w is not None:
            w.join()
            self.writer = None

    def _filtered(self, image, var, count, caustic, aux):
        fset = self.job.filter
        if fset is None or aux is None:
            return None
        return self.ex.denoise(image, var, count, aux, fset)

    def _update(self, final: bool, sums=None, filtered=None, res=None):
        """Hand on_update the render so far. Between items only copies of the
        sums are queued (on resident workers, without waiting for the item
        running there); the images are made from them when the update's
        fields are first read, in the reader's thread."""
        job = self.job
        w, h = job.width, job.height
        if res is not None:  # the final result, as the render returns it
            upd = RenderUpdate(spp_done=float(res.sample_count.mean()) if job.n_pix else 0.0, spp_total=job.spp,
                               elapsed=self.elapsed(), stats=self.stats, final=True, filtered=filtered,
                               image=res.image, sample_count=res.sample_count,
                               lum_var=res.lum_var.astype(np.float32), aux=res.aux)
        else:
            host = self.host.copy()
            taken = self.ex.snapshot() if self.ex.resident else None
            box = {}

            def sums_now():
                if "sums" not in box:
                    if sums is not None:
                        box["sums"] = sums
                    elif taken is None:
                        box["sums"] = host
                    else:
                        box["sums"] = Accumulator.merge([host] + taken())
                    box["images"] = box["sums"].images(w, h, self.lum_scale, self.length_scale)
                return box["images"]

            def load():
                image, var, count, _, _ = sums_now()
                return image, count.astype(np.uint32), var.astype(np.float32)

            upd = RenderUpdate(spp_done=self.done_spp if job.adaptive is None else self._spp_so_far(),
                               spp_total=job.spp, elapsed=self.elapsed(), stats=copy.copy(self.stats),
                               final=final, load=load, load_aux=lambda: sums_now()[4])
        self.on_update(upd)
        self.last_update = time.perf_counter()

    def _spp_so_far(self) -> float:
        return self.done_spp + self.round_samples / max(self.job.n_pix, 1)

    # --- the loop ---------------------------------------------------------------------------
    def run(self):
        """Render; returns (sums, interrupted)."""
        self.t0 = time.perf_counter()
        self.last_checkpoint = self.t0
        self.last_update = -math.inf  # the first item done is shown at once
        self.in_flight = {}
        self.per_spp = {}
        self.done_items = {}
        self.done_spp = self.schedule.next
        self.round_samples = 0
        self.passes = 0
        self.round_open = False
        self.fresh = False
        self.tries = {}
        self.ex.start(self.job, self.initial)
        self.first_slot = min(self.ex.slots) if self.ex.slots else 0
        self.host = self.empty()
        if not self.ex.resident and self.initial is not None:
            self.host.add(self.initial)
        interrupted = False
        draining = False
        while True:
            try:
                if self.stop_event.is_set() and not interrupted:
                    interrupted = True
                    self.schedule.stop()
                if (not interrupted and self.checkpoint_every and self.checkpoint is not None and self.fresh
                        and time.perf_counter() - self.last_checkpoint >= self.checkpoint_every):
                    draining = True
                if not interrupted and not draining:
                    self._hand_out()
                if not self.in_flight:
                    if interrupted:
                        break
                    if draining:
                        draining = False
                        self.write_checkpoint()
                        continue
                    if self.round_open and self.schedule.idle:
                        self.round_open = False
                        self.schedule.round_done()
                        self.stats.adaptive_rounds += 1
                        if self.progress is not None:
                            e = self.elapsed()
                            done = self.total().samples / self.job.n_pix
                            self.progress(min(done, self.job.spp), self.job.spp, e,
                                          done * self.job.n_pix / max(e, 1e-9))
                    if self.schedule.finished or self.schedule.stopped:
                        break
                    if self.schedule.idle:
                        self._adaptive_round()
                        continue
                try:
                    ev = self.events.get(timeout=0.05)
                except queue.Empty:
                    continue
                self._handle(*ev)
                if (self.on_update is not None and self.update_interval is not None
                        and time.perf_counter() - self.last_update >= self.update_interval):
                    self._update(False)
            except KeyboardInterrupt:
                interrupted = True
                self.schedule.stop()
        self.join_writer()
        return interrupted


@contextmanager
def interrupt_signals(stop: threading.Event, stream=sys.stderr):
    """SIGINT, SIGTERM and SIGHUP set `stop` (the render ends after the work in
    flight, with a checkpoint and the image so far) instead of killing the
    process; later ones only say that it is finishing. Yields a dict whose
    "signal" is the first signal's number (or None)."""
    got = {"signal": None}

    def handler(signum, frame):
        if got["signal"] is None:
            got["signal"] = signum
            stop.set()
            stream.write(f"\nclpt: {signal.Signals(signum).name}: finishing the work in flight, then writing "
                         f"the checkpoint and the image\n")
        else:
            stream.write("\nclpt: still writing the image and the checkpoint; they will be complete\n")
        stream.flush()

    sigs = [s for s in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)) if s is not None]
    old = {}
    if threading.current_thread() is threading.main_thread():
        for s in sigs:
            old[s] = signal.signal(s, handler)
    try:
        yield got
    finally:
        for s, h in old.items():
            # After a signal, later ones are ignored: the process is on its
            # way out with the first one's status, and must not die of a
            # second while it reports and exits (Python's own finalization
            # puts back the default action of signals it handles, not of
            # ignored ones).
            signal.signal(s, h if got["signal"] is None else signal.SIG_IGN)
