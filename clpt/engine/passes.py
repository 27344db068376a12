"""The device side of a render, as passes: each owns its kernels, the
buffers only it uses, and the profiling events of its launches.

    TracePass    trace_paths: its launch record, per-work-item statistics and adaptive pixel lists
    PhotonPass   the photon map: trace_photons and the hash-grid build (radix sort, buckets, occupancy)
    FilterPass   the cone filter (filter_firefly, filter_cone)

A pass counts its launches and their device seconds in its Counters, which
the worker takes after each item. The scene records and the pixel sums are
the worker's (device.py): every pass reads the scene, and trace_paths adds
into the sums.
"""

from __future__ import annotations

import math
import os
import re
import time
from dataclasses import dataclass, fields

import numpy as np
import pyopencl as cl

from ..constants import LOCAL_SIZE_CPU, LOCAL_SIZE_GPU, work_item_entries
from ..denoise import ALBEDO_FLOOR, FilterSettings, Planar
from ..errors import DeviceError
from ..photons import (GRID_CELL_RADII, MAX_TABLE_BITS, PM_MERGE, PM_OFFLINE, PM_OWNED, PM_PREPASS, RADIX_BITS,
                       PhotonSettings)
from ..program import event_seconds, filter_pixels, intel_cpu
from .job import AUX_SPECULAR
from .launch import (AUX_ARGS, PHOTON_ARGS, PHOTON_PASS_ARGS, TRACE_ARGS, RecordBuffer, fill_pixel_filter, fill_scene_info,
                     photon_record, trace_record)


class Counters:
    """Launches and device seconds of a pass's kernels, by kernel name, since last taken."""

    def __init__(self):
        self.launches: dict[str, int] = {}
        self.seconds: dict[str, list[float]] = {}
        self._pending: list = []

    def launched(self, name: str, event):
        """A launch queued; its time is read once it has finished (settle)."""
        self.launches[name] = self.launches.get(name, 0) + 1
        self._pending.append((name, event))

    def settle(self):
        """Note the device times of the launches queued so far (they must have finished)."""
        for name, ev in self._pending:
            self.seconds.setdefault(name, []).append(event_seconds(ev))
        self._pending = []

    def take(self) -> tuple[dict[str, int], dict[str, list[float]]]:
        """(launches, seconds) since the last take, and start counting afresh."""
        self.settle()
        out = self.launches, self.seconds
        self.launches, self.seconds = {}, {}
        return out

    def clear(self):
        self.launches, self.seconds, self._pending = {}, {}, []


def _ordered(args, names) -> list:
    missing = [n for n in names if getattr(args, n) is None]
    if missing:
        raise ValueError(f"{type(args).__name__}: no {', '.join(missing)}")
    return [getattr(args, n) for n in names]


@dataclass
class TraceArgs:
    """trace_paths' buffers by parameter name (kernels/trace.cl); the aux and
    photon ones only in builds with them."""

    scene: cl.Buffer
    launch: cl.Buffer
    pix_sum: cl.Buffer
    pix_sq: cl.Buffer
    stats: cl.Buffer
    pix_jobs: cl.Buffer
    aux: cl.Buffer | None = None
    ph_pos: cl.Buffer | None = None
    ph_dir: cl.Buffer | None = None
    ph_pow: cl.Buffer | None = None
    bucket_start: cl.Buffer | None = None
    ph_occ: cl.Buffer | None = None

    def ordered(self, aux: bool, photons: bool) -> list:
        """The kernel's arguments in order (ValueError if one the build takes is missing)."""
        return _ordered(self, TRACE_ARGS + (AUX_ARGS if aux else ()) + (PHOTON_ARGS if photons else ()))


@dataclass
class PhotonPassArgs:
    """trace_photons' buffers by parameter name (kernels/photons.cl)."""

    scene: cl.Buffer
    launch: cl.Buffer
    ph_pos: cl.Buffer
    ph_dir: cl.Buffer
    ph_pow: cl.Buffer
    n_stored: cl.Buffer

    def ordered(self) -> list:
        return _ordered(self, PHOTON_PASS_ARGS)


# Checked once, here: the records' fields are the kernels' parameter lists
# (which tests/test_engine.py checks against the kernel source).
for _record, _names in ((TraceArgs, TRACE_ARGS + AUX_ARGS + PHOTON_ARGS), (PhotonPassArgs, PHOTON_PASS_ARGS)):
    if tuple(f.name for f in fields(_record)) != _names:
        raise TypeError(f"{_record.__name__}'s fields are not the kernel's parameters {', '.join(_names)}")

# The TraceLaunch fields a launch sets for its item; start() sets the others.
ITEM_FIELDS = ("seed", "sample_begin", "n_samples", "n_list", "wi_entries", "photons")
IMAGE_FIELDS = ("scene", "camera", "lum_scale", "width", "height", "group_offset", "max_depth", "rr_depth",
                "aux_specular", "hide_emitters", "pixel_filter", "pull_runs")


FILTER_LOCAL_SIZE = 64  # the cone filter's work-groups (kernels/filter.cl)


def local_size(dctx) -> int:
    return LOCAL_SIZE_CPU if dctx.is_cpu else LOCAL_SIZE_GPU


def pocl_version(dctx) -> tuple[int, int]:
    """A PoCL device's driver version as (major, minor) ("3.1+debian": (3, 1);
    (0, 0) if it does not read as one)."""
    m = re.match(r"\s*(\d+)\.(\d+)", str(getattr(getattr(dctx, "device", None), "driver_version", "") or ""))
    return (int(m.group(1)), int(m.group(2))) if m else (0, 0)


def pulls_runs(dctx) -> bool:
    """Whether trace_paths' work-items pull their runs from a counter on this
    device (TracePass.pull): on the CPU runtimes where that was checked to
    give the same bits, Intel's and PoCL 3.1 and later. pyopencl's PoCL 3.0
    renders them wrong (`cornell_box`, 24x16 at 8 spp, one thread: a mean
    of 0.0980 against 0.0848, and a second Renderer another 0.0981)."""
    if not getattr(dctx, "is_cpu", False):
        return False
    if getattr(dctx, "is_pocl", False):
        return pocl_version(dctx) >= (3, 1)
    return intel_cpu(dctx)


NO_PIXEL = 0xFFFFFFFF  # kernels/film.h: an entry of no pixel
_ZERO4 = np.zeros(4, dtype=np.uint32)  # a pulled launch's counter before it starts


def _groups(n: int, entries: int, local: int) -> int:
    """The global size of a launch over n pixels' or entries' work, `entries`
    a work-item: whole work-groups."""
    return -(-(-(-n // entries)) // local) * local


class TracePass:
    """trace_paths on one device: the kernel, the launch record's buffer, each
    work-item's ray counts and the pixel lists of adaptive rounds."""

    def __init__(self, dctx, program, features):
        self.dctx = dctx
        self.features = features
        self.kernel = cl.Kernel(program, "trace_paths")
        self.launch_buf = RecordBuffer(dctx, trace_record(features.double))
        self.local = local_size(dctx)
        # Entries per work-item: at most lanes x LANE_PIXELS; fewer in launches too small to keep
        # every compute unit busy (work_item_entries).
        self.units = max(1, int(getattr(dctx.device, "max_compute_units", 1) or 1))
        self.entries = work_item_entries(features.lanes)
        self.wi_entries = self.entries  # this image's launches' (allocate)
        self.counters = Counters()
        self.launched = False    # the first launch may include a lazy device compile
        # On CPUs the work-items pull their runs of pixels or list entries from a counter, in
        # order, one after another (kernels/film.h lane_pull): the device's threads end a launch
        # together however the runtime handed them the work-groups, and a work-item's lanes go on
        # to the next run instead of idling until its last path ends. A GPU's work-items keep
        # their own runs (coherent work-groups). CLPT_PULL_RUNS=1 or 0 overrides (any device).
        self.pull = {"1": True, "0": False}.get(os.environ.get("CLPT_PULL_RUNS", ""), pulls_runs(dctx))
        self.counter_buf = None  # the runs' counter of launches over the image
        self.record = None
        self.stats_buf = self.jobs_buf = None
        self.stats_host = np.empty((0, 4), np.uint32)

    def entries_for(self, n: int) -> int:
        """Entries a work-item takes in a launch over n pixels or list entries."""
        return work_item_entries(self.features.lanes, n, self.units, self.local)

    def buffer_bytes_for(self, n_pix: int) -> int:
        return _groups(n_pix, self.entries_for(n_pix), self.local) * 16

    def allocate(self, n_pix: int):
        """Buffers for launches over n_pix pixels (DeviceError if they do not fit)."""
        self.wi_entries = self.entries_for(n_pix)
        self.global_size = _groups(n_pix, self.wi_entries, self.local)
        ctx, rw = self.dctx.context, cl.mem_flags.READ_WRITE
        try:
            self.stats_buf = cl.Buffer(ctx, rw, self.global_size * 16)
            self.counter_buf = self.jobs_buf = cl.Buffer(ctx, rw, 16)  # pixel lists replace it
        except cl.Error as e:
            raise DeviceError(f"cannot allocate the work-item statistics of {n_pix} pixels on {self.dctx.label} "
                              f"({e}); render a smaller image") from None
        self.stats_host = np.empty((self.global_size, 4), dtype=np.uint32)

    def set_image(self, job, packed, frame, eps_abs: float):
        """The launch record's image part: the scene, camera and job settings every launch shares."""
        rec = trace_record(self.features.double)
        fill_scene_info(rec["scene"], packed.counts, eps_abs)
        for k in ("origin", "corner", "dx", "dy"):
            rec["camera"][k] = (*getattr(frame, k), 0)
        values = {"lum_scale": packed.lum_scale, "width": job.width, "height": job.height,
                  "group_offset": 0,  # a launch covers the image from its first pixel
                  "max_depth": min(job.max_depth, 2**31), "rr_depth": min(job.rr_depth, 2**31),
                  "aux_specular": AUX_SPECULAR.index(job.aux_specular), "hide_emitters": int(job.hide_emitters),
                  "pull_runs": int(self.pull)}
        for k, v in values.items():
            rec[k] = v
        fill_pixel_filter(rec["pixel_filter"], job.scene.camera.pixel_filter)
        self.record = rec

    def item_record(self, seed: int, item, lookup=None) -> tuple[np.ndarray, int]:
        """(the launch record of an item, its global size). lookup(rec) fills
        the record's photon part (builds with photons)."""
        rec = self.record.copy()
        rec["seed"] = seed
        if item.kind == "pixels":
            entries = self.entries_for(len(item.pixels))
            n_list, global_size = self._pixel_list(item, entries)
            rec["sample_begin"], rec["n_samples"], rec["n_list"] = 0, 0, n_list
            rec["wi_entries"] = entries
        else:
            self.jobs_buf = self.counter_buf
            rec["sample_begin"], rec["n_samples"], rec["n_list"] = item.s0, item.n, 0
            rec["wi_entries"] = self.wi_entries
            global_size = self.global_size
        if lookup is not None:
            lookup(rec["photons"])
        return rec, global_size

    def _pixel_list(self, item, entries: int) -> tuple[int, int]:
        """Upload an adaptive item's list, `entries` a work-item; returns (the
        list's length as uploaded, the launch's global size). The list keeps
        the order Driver._adaptive_round gives it (heaviest first); its last
        run is padded with entries of no samples, which lanes skip, and the
        runs' counter follows it (0: kernels/film.h lane_pull)."""
        jobs = np.array(item.jobs, dtype=np.uint32).reshape(-1, 4)
        jobs[:, 3] = item.pixels  # (samples, max depth, first sample, pixel): kernels/film.h lane_jobs
        runs = -(-len(jobs) // entries)
        global_size = -(-runs // self.local) * self.local
        up = np.zeros((runs * entries + 1, 4), dtype=np.uint32)
        up[len(jobs):runs * entries, 3] = NO_PIXEL
        up[:len(jobs)] = jobs
        if global_size > len(self.stats_host):
            self.stats_buf = cl.Buffer(self.dctx.context, cl.mem_flags.READ_WRITE, global_size * 16)
            self.stats_host = np.empty((global_size, 4), dtype=np.uint32)
        mf = cl.mem_flags
        self.jobs_buf = cl.Buffer(self.dctx.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=up)
        return runs * entries, global_size

    def run(self, rec: np.ndarray, global_size: int, args: TraceArgs) -> tuple[float, float, bool, np.ndarray]:
        """Launch over global_size work-items and wait: (device seconds (the
        host's where the queue has no profiling), host seconds, whether it
        was the first launch, ray counts summed over the work-items)."""
        args.launch = self.launch_buf.write(rec)
        args.stats, args.pix_jobs = self.stats_buf, self.jobs_buf
        self.kernel.set_args(*args.ordered(self.features.aux, self.features.photons))
        q = self.dctx.queue
        t0 = time.perf_counter()
        if rec["pull_runs"] and rec["n_list"] == 0:
            cl.enqueue_copy(q, self.counter_buf, _ZERO4, is_blocking=False)
        ev = cl.enqueue_nd_range_kernel(q, self.kernel, (global_size,), (self.local,))
        stats = self.stats_host[:global_size]
        cl.enqueue_copy(q, stats, self.stats_buf)
        wall = time.perf_counter() - t0
        self.counters.launched("trace_paths", ev)
        self.counters.settle()
        seconds = self.counters.seconds["trace_paths"][-1]
        if not seconds == seconds:  # no profiling information: the host's time
            seconds = wall
        first = not self.launched
        self.launched = True
        return seconds, wall, first, stats.sum(axis=0, dtype=np.uint64)

    def buffer_bytes(self) -> dict[str, int]:
        if self.stats_buf is None:
            return {}
        return {"work-item stats": self.stats_buf.size, "adaptive lists": self.jobs_buf.size}


class PhotonPass:
    """The photon buffers and grid of one device, rebuilt by build()."""

    def __init__(self, dctx, program, real):
        self.dctx = dctx
        self.real = real
        self.k_trace = cl.Kernel(program, "trace_photons")
        self.k_keys = cl.Kernel(program, "photon_keys")
        self.k_hist = cl.Kernel(program, "radix_histogram")
        self.k_offsets = cl.Kernel(program, "radix_offsets")
        self.k_scatter = cl.Kernel(program, "radix_scatter")
        self.k_permute = cl.Kernel(program, "photon_permute")
        self.k_starts = cl.Kernel(program, "bucket_starts")
        self.k_occ = cl.Kernel(program, "photon_occupancy")
        self.capacity = -1
        self.launch = None  # the photon pass's launch record buffer
        self.n_chunks = 64 if dctx.is_cpu else 1024  # a multiple of the local size: every chunk work-item exists
        self.counters = Counters()
        self.n_stored = 0
        self.n_emitted = 0
        self.radius = 0.0
        self.inv_cell = 1.0
        self.sorted_keys = None
        self.held = None  # the key of the map built last (DeviceWorker: its iteration)
        self._queued = (None, None, None, None)  # the last build's info until complete()

    def _alloc(self, n: int):
        ctx = self.dctx.context
        rw = cl.mem_flags.READ_WRITE
        m = max(n, 1)
        self.table_bits = max(10, min(MAX_TABLE_BITS, (2 * m - 1).bit_length()))  # about 2 buckets a photon
        self.mask = (1 << self.table_bits) - 1
        try:
            self.raw = [cl.Buffer(ctx, rw, 16 * m) for _ in range(3)]     # pos, dir, pow as traced
            self.sorted = [cl.Buffer(ctx, rw, 16 * m) for _ in range(3)]  # in key order
            self.keys = [cl.Buffer(ctx, rw, 4 * m) for _ in range(2)]
            self.vals = [cl.Buffer(ctx, rw, 4 * m) for _ in range(2)]
            self.bucket_start = cl.Buffer(ctx, rw, 4 * ((1 << self.table_bits) + 1))
            self.hist = cl.Buffer(ctx, rw, 4 * 256 * self.n_chunks)
            self.counter = cl.Buffer(ctx, rw, 4)
            # Occupancy bits: about 128 a photon (27 set each), 2^16 to 2^26.
            self.occ_bits = 1 << max(16, min(26, (128 * m - 1).bit_length()))
            self.occ = cl.Buffer(ctx, rw, self.occ_bits // 8)
        except cl.Error as e:
            raise DeviceError(f"cannot allocate a photon map of {n} photons on {self.dctx.label} ({e}); "
                              f"use fewer photons") from None
        self.capacity = n

    def buffer_bytes(self) -> dict[str, int]:
        """Device memory per buffer of the photon map (none before the first build)."""
        if self.capacity < 0:
            return {}
        return {"photons as traced": sum(b.size for b in self.raw), "photons sorted": sum(b.size for b in self.sorted),
                "photon sort keys": sum(b.size for b in self.keys + self.vals),
                "photon grid": self.bucket_start.size + self.hist.size + self.counter.size + self.occ.size}

    def _launch(self, name, kernel, global_size, *args):
        # A fixed local size (the kernels check their range): PoCL compiles a
        # kernel anew for each local size, and its own choice for large global
        # sizes overflowed the work-item stacks of the double-precision build.
        local = local_size(self.dctx)
        kernel.set_args(*args)
        ev = cl.enqueue_nd_range_kernel(self.dctx.queue, kernel, (-(-max(1, global_size) // local) * local,), (local,))
        self.counters.launched(name, ev)
        return ev

    def build(self, scene_buf, counts, eps_abs, lanes: int, seed: int, settings: PhotonSettings, radius: float,
              wait: bool = True):
        """Trace settings.count photons and build the grid for `radius`
        (counts: the packed scene's; eps_abs: the ray-origin offset's floor).
        Returns {"stored", "trace_seconds", "grid_seconds", "host_seconds"}
        (device times from profiling events). With wait False the build is
        only queued (host_seconds: the time that took): a launch queued after
        it runs once it is done, with no return to the host in between, and
        complete(info) fills in the rest once the queue has finished."""
        n = int(settings.count)
        if n != self.capacity:
            self._alloc(n)
        q = self.dctx.queue
        t_host = time.perf_counter()
        cl.enqueue_fill_buffer(q, self.counter, np.uint32(0), 0, 4)
        events = []
        if n > 0:
            rec = photon_record(self.real == np.float64)
            fill_scene_info(rec["scene"], counts, eps_abs)
            rec["seed"], rec["n_emit"], rec["aim"] = seed, n, 0 if settings.aim == "solid_angle" else 1
            if self.launch is None:
                self.launch = RecordBuffer(self.dctx, rec)
            args = PhotonPassArgs(scene_buf, self.launch.write(rec), *self.raw, self.counter)
            events.append(self._launch("trace_photons", self.k_trace, -(-n // lanes), *args.ordered()))
        stored = np.zeros(1, dtype=np.uint32)
        cl.enqueue_copy(q, stored, self.counter, is_blocking=False)  # read once the queue has finished
        grid_events = self.build_grid(n, radius, wait=wait)
        self.n_emitted = n
        info = {"host_seconds": time.perf_counter() - t_host}
        self._queued = (info, stored, events, grid_events)
        if wait:
            self.complete(info)
        return info

    def complete(self, info: dict):
        """Fill in the info of the build queued last (build(wait=False)),
        once the queue has finished: the photons stored, the device times."""
        queued, stored, events, grid_events = self._queued
        if queued is not info:
            if "stored" in info:
                return  # (completed already: a build that waited)
            raise RuntimeError("a photon map's info is completed after the build that returned it, and no later")
        self.n_stored = int(stored[0])
        info.update(stored=self.n_stored, trace_seconds=_device_seconds(events),
                    grid_seconds=_device_seconds(grid_events))
        self._queued = (None, None, None, None)

    def load(self, pos, dirs, power, radius: float):
        """Use the given photons (arrays of n x 3) instead of traced ones, and
        build the grid: for tests and for measuring the build alone."""
        n = len(pos)
        if n != self.capacity:
            self._alloc(n)
        if n:
            for buf, a, w in ((self.raw[0], pos, 1.0), (self.raw[1], dirs, 0.0), (self.raw[2], power, 0.0)):
                h = np.zeros((n, 4), dtype=np.float32)
                h[:, :3] = a
                h[:, 3] = w
                cl.enqueue_copy(self.dctx.queue, buf, h)
        self.n_stored = n
        self.n_emitted = n
        events = self.build_grid(n, radius)
        self.counters.settle()
        return {"stored": n, "grid_seconds": _device_seconds(events)}

    def build_grid(self, n: int, radius: float, wait: bool = True):
        """Sort the n photon slots by bucket and fill bucket_start; returns the
        events (with wait, once the queue has finished)."""
        q = self.dctx.queue
        self.radius = radius
        self.inv_cell = 1.0 / (GRID_CELL_RADII * radius)
        table = 1 << self.table_bits
        cl.enqueue_fill_buffer(q, self.bucket_start, np.uint32(0), 0, 4 * (table + 1))
        cl.enqueue_fill_buffer(q, self.occ, np.uint32(0), 0, self.occ_bits // 8)
        events = []
        if n > 0:
            events.append(self._launch("photon_keys", self.k_keys, n, self.raw[0], np.uint32(n),
                                       self.real(self.inv_cell), np.uint32(self.mask), self.keys[0], self.vals[0]))
            chunk = np.uint32(-(-n // self.n_chunks))
            src = 0
            for shift in range(0, self.table_bits + 1, RADIX_BITS):
                events.append(self._launch("radix_histogram", self.k_hist, self.n_chunks, self.keys[src],
                                           np.uint32(n), np.uint32(shift), chunk, self.hist))
                events.append(self._launch("radix_offsets", self.k_offsets, 1, self.hist, np.uint32(self.n_chunks)))
                events.append(self._launch("radix_scatter", self.k_scatter, self.n_chunks, self.keys[src],
                                           self.vals[src], np.uint32(n), np.uint32(shift), chunk, self.hist,
                                           self.keys[1 - src], self.vals[1 - src]))
                src = 1 - src
            events.append(self._launch("photon_permute", self.k_permute, n, self.vals[src], np.uint32(n),
                                       *self.raw, *self.sorted))
            events.append(self._launch("bucket_starts", self.k_starts, n + 1, self.keys[src], np.uint32(n),
                                       np.uint32(self.mask), self.bucket_start))
            self.sorted_keys = self.keys[src]
            events.append(self._launch("photon_occupancy", self.k_occ, n, self.raw[0], np.uint32(n),
                                       self.real(self.inv_cell), np.uint32(self.occ_bits - 1), self.occ))
        if wait:
            q.finish()
        return events

    def stored_power(self) -> list[float]:
        """The power the stored photons carry, per RGB channel (float64 sums)."""
        n = self.capacity
        power = np.zeros((max(n, 1), 4), np.float32)
        if n > 0:
            cl.enqueue_copy(self.dctx.queue, power, self.sorted[2])
        return [float(x) for x in power[:, :3].sum(axis=0, dtype=np.float64)]

    def lookup(self, rec, settings: PhotonSettings, mode: int, moments: bool = False):
        """Fill rec, a PhotonLookup record (clpt/layout.py), for a trace_paths
        launch over this map in mode PM_*: the map's grid, the gather's
        settings, and what the launch does with them (kernels/path.h);
        moments: merges also estimate path tracing's second moment (the
        pilot's trial, kernels/photon_grid.h)."""
        # The merge's pdf is pf cos pi r^2 N (kernels/path.h, photon merging).
        p = float(settings.merge_probability)
        rec["mask"], rec["occ_mask"] = self.mask, self.occ_bits - 1
        rec["max_photons"] = settings.max_photons if settings.max_photons > 0 else 0xFFFFFFFF
        # The offline pre-pass gathers only a few times per pixel: subsampling
        # noise would not average out there, so it visits every photon.
        rec["budget"] = 0xFFFFFFFF if mode == PM_PREPASS else settings.budget
        rec["radius"], rec["inv_cell"], rec["cone_k"] = self.radius, self.inv_cell, settings.cone_k
        rec["mis_k"] = math.pi * self.radius ** 2 * max(self.n_emitted, 1) * p
        rec["merge_p"] = p
        rec["merge_vertices"] = min(settings.merge_vertices, 2 ** 31)
        rec["aim"] = 0 if settings.aim == "solid_angle" else 1
        rec["merge"] = mode == PM_MERGE
        rec["gather"] = mode in (PM_OWNED, PM_PREPASS)
        rec["owns"] = mode in (PM_OWNED, PM_OFFLINE, PM_PREPASS)
        rec["stop_at_x"] = mode == PM_PREPASS
        rec["moments"] = moments and mode == PM_MERGE

    def fill(self, args: TraceArgs):
        """Put the map's buffers into trace_paths' arguments."""
        args.ph_pos, args.ph_dir, args.ph_pow = self.sorted
        args.bucket_start, args.ph_occ = self.bucket_start, self.occ


def _device_seconds(events) -> float:
    try:
        return sum(e.profile.end - e.profile.start for e in events) * 1e-9
    except cl.Error:
        return float("nan")


class FilterPass:
    """The cone filter's kernels on one device (clpt/denoise.py: settings and
    the numpy twin; kernels/filter.cl)."""

    # the host's images filter_load reads, and their floats per pixel
    INPUTS = (("color", 3), ("var", 1), ("normal", 3), ("albedo", 3), ("depth", 1), ("emitter", 1))

    def __init__(self, dctx, program, pixels: int | None = None):
        self.dctx = dctx
        self.load = cl.Kernel(program, "filter_load")
        self.store = cl.Kernel(program, "filter_store")
        self.firefly = cl.Kernel(program, "filter_firefly")
        self.luma = cl.Kernel(program, "filter_luma")
        self.kernel = cl.Kernel(program, "filter_cone")
        self.counters = Counters()
        # a work-item's pixels, as the program was built (device_options; or as the caller built it)
        self.pixels = filter_pixels(dctx) if pixels is None else pixels
        self._kept = None  # (layout key, [colour, colour], guides, inputs, output): kept for the next image of that size

    def _buffers(self, lay: Planar):
        """The two colour buffers (6 planes) and the guides' (8), the host
        images' (INPUTS) and the output's, made once per image layout (making
        them costs more than the filter's passes). The planes' margins are
        zeroed here and never written again; within a call, every plane is
        written by a kernel (padding included) before it is read."""
        key = (lay.width, lay.height, lay.pitch, lay.margin, lay.plane)
        if self._kept is None or self._kept[0] != key:
            self._kept = None  # the old ones go before the new are made
            ctx, q, mf, nb = self.dctx.context, self.dctx.queue, cl.mem_flags, 4 * lay.plane
            c = [cl.Buffer(ctx, mf.READ_WRITE, 6 * nb), cl.Buffer(ctx, mf.READ_WRITE, 6 * nb)]
            gb = cl.Buffer(ctx, mf.READ_WRITE, 8 * nb)
            zeros = np.zeros(8 * lay.plane, np.float32)
            for buf, n in ((c[0], 6), (c[1], 6), (gb, 8)):
                cl.enqueue_copy(q, buf, zeros[:n * lay.plane])
            pixels = lay.width * lay.height
            inputs = {k: cl.Buffer(ctx, mf.READ_ONLY, 4 * n * pixels) for k, n in self.INPUTS}
            out = cl.Buffer(ctx, mf.WRITE_ONLY, 4 * 3 * pixels)
            self._kept = (key, c, gb, inputs, out)
        return self._kept[1:]

    def __call__(self, color, var, normal, albedo, depth, settings: FilterSettings, emitter=None):
        """Filtered colour (H x W x 3 float32) from the guides (H x W arrays);
        var is each pixel mean's luminance variance, emitter the fraction of
        its samples that see a light."""
        h, w = color.shape[:2]
        if settings.width == 0:
            return color.astype(np.float32).copy()
        q = self.dctx.queue
        passes = settings.passes(w, h)
        radius = min(int(settings.width), max(w, h))
        lay = Planar(w, h, radius, 1 << (passes - 1))
        c, gb, inputs, out = self._buffers(lay)
        host = {"color": color, "var": var, "normal": normal, "albedo": albedo, "depth": depth, "emitter": emitter}
        for k, _ in self.INPUTS:
            if host[k] is not None:
                cl.enqueue_copy(q, inputs[k], np.ascontiguousarray(host[k], np.float32), is_blocking=False)
        dims = (np.uint32(w), np.uint32(h), np.uint32(lay.pitch), np.uint32(lay.plane), np.uint32(lay.margin))
        floor = np.float32(ALBEDO_FLOOR)

        def grid(items, local):
            return (-(-items // local) * local,), (local,)

        def plane_grid(columns):  # one work-item per pixel, rows of FILTER_LOCAL_SIZE
            return (-(-columns // FILTER_LOCAL_SIZE) * FILTER_LOCAL_SIZE, h), (FILTER_LOCAL_SIZE, 1)

        self.counters.launched("filter_load", self.load(
            q, *plane_grid(lay.pitch), inputs["color"], inputs["var"], inputs["normal"],
            inputs["albedo"], inputs["depth"], None if emitter is None else inputs["emitter"], *dims, floor, c[0], gb))
        src = 0
        # the passes: one item per `pixels` pixels of a row, the same pixels per work-group whatever their number
        gsize, local = grid(h * lay.pitch // self.pixels, FILTER_LOCAL_SIZE * 8 // self.pixels)
        if settings.firefly_k > 0:
            # NaN variances (the host's) take the median's slow path
            any_nan = np.int32(np.isnan(var).any())
            self.counters.launched("filter_firefly", self.firefly(q, gsize, local, c[0], *dims,
                                                                  np.float32(settings.firefly_k),
                                                                  np.float32(settings.confirm_k), any_nan, c[1]))
            src = 1
        for it in range(passes):
            fit = bool(settings.fit_last) and it == passes - 1  # the last pass fits a plane
            sigma_l, floor_g = ((settings.fit_sigma_luminance, settings.fit_guide_floor) if fit
                                else (settings.sigma_luminance, settings.guide_floor))
            self.counters.launched("filter_luma", self.luma(q, gsize, local, c[src], *dims))
            self.counters.launched("filter_cone", self.kernel(
                q, gsize, local, c[src], gb, *dims, np.int32(radius), np.int32(1 << it),
                np.int32(settings.sigma_normal), np.float32(settings.sigma_depth), np.float32(settings.sigma_albedo),
                np.float32(sigma_l), np.float32(floor_g), np.int32(fit), c[1 - src]))
            src = 1 - src
        self.counters.launched("filter_store", self.store(q, *plane_grid(w), c[src], gb, *dims,
                                                          floor, out))
        result = np.empty((h, w, 3), np.float32)
        cl.enqueue_copy(q, result, out)
        q.finish()
        self.counters.settle()
        return result
