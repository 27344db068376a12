"""One OpenCL device running a job's work items into sums it keeps.

A DeviceWorker builds the kernels for a scene once; start(job) sizes its
buffers for an image and loads the sums to continue from; run(item) adds an
item's samples; sums() reads them back. The sums stay on the device between
items, so one device adds every pixel's samples in sample order whatever the
items were, and its image is bit-identical however the render was split.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pyopencl as cl

from .. import program
from ..constants import LOCAL_SIZE_CPU, LOCAL_SIZE_GPU, OFFSET_FLOOR
from ..denoise import ConeFilter
from ..device import DeviceContext, DeviceError
from ..features import Experimental, Features, scene_features
from ..pack import MAX_FLOAT_RECORDS, PackedScene, camera_frame
from ..photons import PM_OFF, PM_PREPASS, PhotonMap, PhotonSettings
from ..scene import SceneError
from .accum import Accumulator
from .job import DeviceOptions, RenderJob, WorkItem, kernel_photons, photon_plan
from .launch import RecordBuffer, fill_pixel_filter, fill_scene_info, trace_args, trace_record

PREPASS_SEED_SALT = 0x2545F491


def device_features(dctx: DeviceContext, packed: PackedScene, opts: DeviceOptions, lanes: int | None = None,
                    experimental: Experimental | None = None) -> Features:
    """The build of packed on dctx: the options' (and, for `clpt bench`, an
    Experimental variant's; renders and their jobs never carry one, as no
    variant changes an image)."""
    if (opts.precision == "double" or opts.accumulate == "double") and not dctx.fp64:
        raise DeviceError(f"{dctx.label} has no double precision (cl_khr_fp64); render with precision='float'")
    acc_double = dctx.fp64 if opts.accumulate == "auto" else opts.accumulate == "double"
    if not (lanes or opts.lanes):
        from .. import tune
        photons = packed.has_caustics and opts.photons is not False
        lanes = tune.query_tuning(dctx, photons).lanes  # no trial renders here
    return scene_features(packed, lanes=lanes or opts.lanes,
                          double=opts.precision == "double", accum_double=acc_double or opts.precision == "double",
                          mode=opts.kernel, nee=opts.nee, photons=packed.has_caustics and opts.photons is not False,
                          aux=opts.aux, bvh_walk=(experimental or Experimental()).bvh_walk)


def kernel_sources(packed: PackedScene | None, features: Features) -> list[str]:
    """The stitched programs a scene's build compiles: the path pass (and the
    filter), and for scenes with caustic photons the photon pass and grid
    build apart, so that the two build in parallel. (The source does not
    depend on the packed scene, which only the build options describe.)"""
    out = [program.stitch(["path.h", "trace.cl"] + (["filter.cl"] if features.aux else []))]
    if features.photons:
        out.append(program.stitch(["photons.cl", "grid.cl"]))
    return out


def kernel_source(packed: PackedScene | None, features: Features) -> str:
    return "\n".join(kernel_sources(packed, features))


class _Sums:
    """Per-pixel sums on a device (kernels/film.h's layout)."""

    def __init__(self, dctx, n_pix: int, accum_double: bool):
        self.dctx, self.n_pix, self.accum_double = dctx, n_pix, accum_double
        ctx = dctx.context
        self.pix_sum = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, n_pix * 32)
        self.pix_sq = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, n_pix * 8)
        self.zero()

    def zero(self):
        q = self.dctx.queue
        cl.enqueue_fill_buffer(q, self.pix_sum, np.float32(0), 0, self.n_pix * 32)
        cl.enqueue_fill_buffer(q, self.pix_sq, np.float32(0), 0, self.n_pix * 8)

    def read(self):
        """(pix_sum, pix_sq) as the device holds them (float64, or Kahan pairs of float32)."""
        raw, _ = self.read_async()
        self.dctx.queue.finish()
        return raw

    def read_async(self):
        """Queue copies of the sums into fresh host arrays: ((pix_sum, pix_sq), events)."""
        q = self.dctx.queue
        if self.accum_double:
            s, sq = np.empty((self.n_pix, 4), np.float64), np.empty(self.n_pix, np.float64)
        else:
            s, sq = np.empty((self.n_pix, 8), np.float32), np.empty((self.n_pix, 2), np.float32)
        return (s, sq), [cl.enqueue_copy(q, s, self.pix_sum, is_blocking=False),
                         cl.enqueue_copy(q, sq, self.pix_sq, is_blocking=False)]

    def write(self, s, sq):
        q = self.dctx.queue
        cl.enqueue_copy(q, self.pix_sum, s)
        cl.enqueue_copy(q, self.pix_sq, sq)
        q.finish()


class DeviceWorker:
    """Everything one device holds for one scene: programs, kernels, buffers, sums."""

    def __init__(self, dctx: DeviceContext, packed: PackedScene, features: Features, use_cache: bool = True):
        self.dctx = dctx
        self.label = dctx.label
        self.features = features
        self.packed = packed
        real = np.float64 if features.double else np.float32
        mf = cl.mem_flags
        if not features.double and len(packed.records) > MAX_FLOAT_RECORDS:
            raise SceneError(f"{len(packed.records)} scene records exceed what float kernels index exactly "
                             f"({MAX_FLOAT_RECORDS}); render with double=True or a smaller scene")
        recs = np.ascontiguousarray(packed.records, dtype=real)
        if recs.size == 0:
            recs = np.zeros((1, 4), dtype=real)
        self.scene_buf = cl.Buffer(dctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=recs)
        self.eps_abs = OFFSET_FLOOR['double' if features.double else 'float']  # kernels/scene.h
        self.real = real
        sources = kernel_sources(packed, features)
        t0 = time.perf_counter()

        def build(source):
            return program.build(dctx, source, features.options(), use_cache=use_cache)

        def build_photons(source):
            # Then a one-photon map: PoCL generates the photon kernels' machine code
            # at their first launch, here while the path pass is still compiling.
            prg, info = build(source)
            pmap = PhotonMap(dctx, prg, real)
            pmap.build(self.scene_buf, packed.counts, self.eps_abs, features.lanes, 0, PhotonSettings(count=1),
                       0.01 * max(packed.size, 1e-30))
            pmap.launches.clear()
            pmap.kernel_times.clear()
            return pmap, info

        if len(sources) == 1:
            built = [build(sources[0])]
            self.pmap = None
        elif not program.builds_at_once(dctx):  # a runtime not known to take two builds at once
            built = [build(sources[0]), build_photons(sources[1])]
            self.pmap = built[1][0]
        else:  # the OpenCL compilers release the GIL: the programs build at once
            with ThreadPoolExecutor(2) as pool:
                photon_side = pool.submit(build_photons, sources[1])
                built = [build(sources[0]), photon_side.result()]
            self.pmap = built[1][0]
        self.program = built[0][0]
        self.build = program.BuildInfo(time.perf_counter() - t0, all(b.cache_hit for _, b in built),
                                       "+".join(b.key for _, b in built), built[0][1].options)
        self.kernel = cl.Kernel(self.program, "trace_paths")
        self.launch = RecordBuffer(dctx, trace_record(features.double))
        self.local = LOCAL_SIZE_CPU if dctx.is_cpu else LOCAL_SIZE_GPU
        self.launched = False
        self.filter = ConeFilter(dctx, self.program) if features.aux else None
        self.aux = None
        self.launches = {}
        self.kernel_times = {}  # kernel name -> device seconds of each launch since start()
        self.job = None

    # --- a job's buffers ------------------------------------------------------------
    def _allocate(self, n_pix: int, caustic_buffer: bool):
        groups = -(-n_pix // self.features.lanes)
        self.global_size = -(-groups // self.local) * self.local
        need = n_pix * 40 * (2 if caustic_buffer else 1) + self.global_size * 16 + n_pix * 64 * self.features.aux
        dev = self.dctx.device
        if n_pix * 32 > dev.max_mem_alloc_size or need > dev.global_mem_size:
            raise DeviceError(f"{n_pix} pixels need {need / 2**20:.0f} MiB of accumulation buffers, more than "
                              f"{self.label} offers ({dev.global_mem_size / 2**20:.0f} MiB, at most "
                              f"{dev.max_mem_alloc_size / 2**20:.0f} MiB per buffer); render a smaller image")
        ctx, q, rw = self.dctx.context, self.dctx.queue, cl.mem_flags.READ_WRITE
        try:
            self.main = _Sums(self.dctx, n_pix, self.features.accum_double)
            self.caustic = _Sums(self.dctx, n_pix, self.features.accum_double) if caustic_buffer else None
            self.stats_buf = cl.Buffer(ctx, rw, self.global_size * 16)
            self.jobs_buf = cl.Buffer(ctx, rw, 16)  # adaptive passes replace it
            # The feature sums: four planes of n_pix float4 (kernels/film.h VisibleSurface).
            self.aux = cl.Buffer(ctx, rw, 4 * n_pix * 16) if self.features.aux else None
            self._zero_aux()
            q.finish()
        except cl.Error as e:
            raise DeviceError(f"cannot allocate {need / 2**20:.0f} MiB on {self.label} for "
                              f"{n_pix} pixels ({e}); render a smaller image") from None
        self.stats_host = np.empty((self.global_size, 4), dtype=np.uint32)
        self.n_pix = n_pix

    def _zero_aux(self):
        if self.aux is not None:
            cl.enqueue_fill_buffer(self.dctx.queue, self.aux, np.float32(0), 0, self.aux.size)

    def start(self, job: RenderJob, initial: Accumulator | None = None):
        """Get ready for a job: buffers for its image, zero sums (or `initial`)."""
        n_pix = job.n_pix
        self._allocate(n_pix, caustic_buffer=job.offline)
        frame = camera_frame(job.scene.camera, job.width, job.height, self.packed.length_scale)
        rec = trace_record(self.features.double)
        fill_scene_info(rec["scene"], self.packed.counts, self.eps_abs)
        rec["lum_scale"] = self.packed.lum_scale
        for k in ("origin", "corner", "dx", "dy"):
            rec["camera"][k] = (*getattr(frame, k), 0)
        rec["width"], rec["height"] = job.width, job.height
        rec["max_depth"], rec["rr_depth"] = min(job.max_depth, 2**31), min(job.rr_depth, 2**31)
        rec["aux_specular"] = int(job.aux_specular == "surface")
        fill_pixel_filter(rec["pixel_filter"], job.scene.camera.pixel_filter)
        self.record = rec
        self.job = job
        self.pm_iteration = None
        self.launches = {}
        self.kernel_times = {}
        if initial is not None:
            self.load(initial)

    # --- photon maps --------------------------------------------------------------------
    def build_photons(self, seed: int, settings: PhotonSettings, radius: float, mode: int):
        info = self.pmap.build(self.scene_buf, self.packed.counts, self.eps_abs, self.features.lanes, seed, settings,
                               radius)
        self.pm_settings = settings
        self.pm_mode = mode
        for k, v in self.pmap.launches.items():
            self.launches[k] = self.launches.get(k, 0) + v
        self.pmap.launches.clear()
        for k, v in self.pmap.kernel_times.items():
            self.kernel_times.setdefault(k, []).extend(v)
        self.pmap.kernel_times.clear()
        return {**info, "radius": radius, "seed": seed}

    def prepare_photons(self, iteration: int):
        """Build the photon map of `iteration` unless it is the one held; returns its info or None."""
        job = self.job
        if self.pmap is None or job.photons is None or self.pm_iteration == iteration:
            return None
        seed, radius = photon_plan(job, iteration, self.packed.size, self.packed.length_scale)
        info = self.build_photons(seed, kernel_photons(job.photons, self.packed.length_scale), radius,
                                  job.pm_mode)
        self.pm_iteration = iteration
        return {"device": self.label, "iteration": iteration, **info}

    # --- work ---------------------------------------------------------------------------
    def run(self, item: WorkItem) -> dict:
        """Add an item's samples to the sums. Returns {"seconds" (device time of
        the launch), "wall", "stats" (non-finite, camera, bounce, shadow),
        "photon_maps", "launches"}."""
        before = dict(self.launches)
        times_before = {k: len(v) for k, v in self.kernel_times.items()}
        pm = self.prepare_photons(item.iteration)
        prepass = item.kind == "prepass"
        rec = self.record.copy()
        rec["seed"] = (self.job.seed ^ PREPASS_SEED_SALT) if prepass else self.job.seed
        global_size = self.global_size
        if item.kind == "pixels":
            rec["n_list"] = n_list = len(item.pixels)
            global_size = -(-(-(-n_list // self.features.lanes)) // self.local) * self.local
            if global_size > len(self.stats_host):
                self.stats_buf = cl.Buffer(self.dctx.context, cl.mem_flags.READ_WRITE, global_size * 16)
                self.stats_host = np.empty((global_size, 4), dtype=np.uint32)
            mf = cl.mem_flags
            jobs = np.array(item.jobs, dtype=np.uint32).reshape(-1, 4)
            jobs[:, 3] = item.pixels  # (samples, max depth, first sample, pixel): kernels/film.h lane_jobs
            self.jobs_buf = cl.Buffer(self.dctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=jobs)
        else:
            rec["sample_begin"], rec["n_samples"] = item.s0, item.n
        sums = self.caustic if prepass else self.main
        buffers = {"scene": self.scene_buf, "pix_sum": sums.pix_sum, "pix_sq": sums.pix_sq, "stats": self.stats_buf,
                   "pix_jobs": self.jobs_buf, "aux": self.aux}
        if self.features.photons:
            pset = kernel_photons(self.job.photons, self.packed.length_scale) or PhotonSettings()
            self.pmap.lookup(rec["photons"], pset, PM_PREPASS if prepass else self.job.pm_mode)
            buffers.update(self.pmap.buffers())
        buffers["launch"] = self.launch.write(rec)
        self.kernel.set_args(*trace_args(buffers, self.features.aux, self.features.photons))
        q = self.dctx.queue
        t0 = time.perf_counter()
        ev = cl.enqueue_nd_range_kernel(q, self.kernel, (global_size,), (self.local,))
        stats = self.stats_host[:global_size]
        cl.enqueue_copy(q, stats, self.stats_buf)
        wall = time.perf_counter() - t0
        program.note_time(self.kernel_times, "trace_paths", ev)
        seconds = self.kernel_times["trace_paths"][-1]
        if not seconds == seconds:  # no profiling information: the host's time
            seconds = wall
        first = not self.launched
        self.launched = True
        self.launches["trace_paths"] = self.launches.get("trace_paths", 0) + 1
        delta = {k: v - before.get(k, 0) for k, v in self.launches.items() if v != before.get(k, 0)}
        if self.filter is not None and self.filter.kernel_times:
            for k, v in self.filter.kernel_times.items():
                self.kernel_times.setdefault(k, []).extend(v)
            self.filter.kernel_times = {}
        times = {k: v[times_before.get(k, 0):] for k, v in self.kernel_times.items() if len(v) > times_before.get(k, 0)}
        return {"seconds": seconds, "wall": wall, "first": first, "stats": stats.sum(axis=0, dtype=np.uint64),
                "photon_maps": [pm] if pm else [], "launches": delta, "kernel_seconds": times}

    def launch_seconds(self) -> float:
        """Host seconds of an empty launch (no samples): the fixed cost of a pass."""
        return self.run(WorkItem("samples", 0, 0))["wall"]

    def buffer_bytes(self) -> dict[str, int]:
        """Device memory per buffer this worker holds (after a render)."""
        out = {"scene records": self.scene_buf.size}
        for name, sums in (("pixel sums", getattr(self, "main", None)), ("caustic sums", getattr(self, "caustic", None))):
            if sums is not None:
                out[name] = sums.pix_sum.size + sums.pix_sq.size
        if hasattr(self, "stats_buf"):
            out["work-item stats"] = self.stats_buf.size
            out["adaptive lists"] = self.jobs_buf.size
        if self.aux is not None:
            out["feature buffers"] = self.aux.size
        if self.pmap is not None:
            out.update(self.pmap.buffer_bytes())
        return out

    # --- sums -----------------------------------------------------------------------------
    def sums(self) -> Accumulator:
        raw, _ = self.snapshot()
        self.dctx.queue.finish()
        return Accumulator.from_device(*raw)

    def snapshot(self):
        """Queue copies of the sums without waiting for them: ((main, caustic,
        aux) raw arrays for Accumulator.from_device, events). The queue is in
        order, so queued from any thread they see the sums between two items."""
        main, events = self.main.read_async()
        caustic = None
        if self.caustic is not None:
            caustic, ev = self.caustic.read_async()
            events += ev
        aux = None
        if self.aux is not None:
            aux = [np.empty((self.n_pix, 4), np.float32) for _ in range(4)]
            events += [cl.enqueue_copy(self.dctx.queue, h, self.aux, src_offset=k * h.nbytes, is_blocking=False)
                       for k, h in enumerate(aux)]
        self.dctx.queue.flush()
        return (main, caustic, aux), events

    def load(self, acc: Accumulator):
        """Replace the sums by acc's (in this device's layout)."""
        kahan = not self.features.accum_double
        self.main.write(*acc.to_device("", kahan))
        if self.caustic is not None:
            if "c_sum" in acc.planes:
                self.caustic.write(*acc.to_device("c_", kahan))
            else:
                self.caustic.zero()
        if self.aux is not None:
            if "aux" in acc.planes:
                for k, h in enumerate(acc.aux_to_device()):
                    h = np.ascontiguousarray(h, dtype=np.float32)
                    cl.enqueue_copy(self.dctx.queue, self.aux, h, dst_offset=k * h.nbytes)
            else:
                self._zero_aux()
        self.dctx.queue.finish()

    def zero(self):
        self.main.zero()
        if self.caustic is not None:
            self.caustic.zero()
        self._zero_aux()
        self.dctx.queue.finish()

    def empty_sums(self, job: RenderJob) -> Accumulator:
        return Accumulator(job.n_pix, kahan=not self.features.accum_double, aux=self.features.aux,
                           caustic=job.offline)
