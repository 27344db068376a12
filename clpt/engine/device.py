"""One OpenCL device running a job's work items into sums it keeps.

A DeviceWorker builds the kernels for a scene once; start(job) sizes its
buffers for an image and loads the sums to continue from; run(item) adds an
item's samples; sums() reads them back. The sums stay on the device between
items, so one device adds every pixel's samples in sample order whatever the
items were, and its image is bit-identical however the render was split.

The worker composes: the scene's records (every pass reads them), a job's
sums (film.py) and the passes (passes.py) that own the kernels, the buffers
only they use and their launches' timings: the trace pass, the photon pass
(scenes with caustic casters) and the filter pass (builds with feature
buffers).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import numpy as np
import pyopencl as cl

from .. import program, tune
from ..constants import OFFSET_FLOOR
from ..device import DeviceContext
from ..errors import DeviceError, SceneError
from ..features import Experimental, Features, scene_features
from ..pack import MAX_FLOAT_RECORDS, PackedScene, camera_frame
from ..photons import PM_PREPASS, PhotonSettings
from .accum import Accumulator
from .film import Film
from .job import DeviceOptions, RenderJob, WorkItem, kernel_photons, photon_plan
from .passes import FilterPass, PhotonPass, TraceArgs, TracePass
from .runresult import RunResult

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
        photons = packed.has_caustics and opts.photons is not False
        lanes = tune.query_tuning(dctx, photons).lanes  # no trial renders here
    return scene_features(packed, lanes=lanes or opts.lanes,
                          double=opts.precision == "double", accum_double=acc_double or opts.precision == "double",
                          mode=opts.kernel, nee=opts.nee, photons=packed.has_caustics and opts.photons is not False,
                          aux=opts.aux, bvh_walk=(experimental or Experimental()).bvh_walk, sampler=opts.sampler)


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


def build_programs(dctx: DeviceContext, packed: PackedScene, features: Features, scene_buf, eps_abs: float,
                   use_cache: bool = True) -> tuple[cl.Program, PhotonPass | None, program.BuildInfo]:
    """Build a scene's programs on dctx: (the path pass's program, the photon
    pass or None, what the build took). The photon program builds beside the
    path pass's where the runtime takes two builds at once, and its kernels
    then run a one-photon map: PoCL generates their machine code at the first
    launch, here while the path pass is still compiling."""
    real = np.float64 if features.double else np.float32
    sources = kernel_sources(packed, features)
    t0 = time.perf_counter()

    def build(source):
        return program.build(dctx, source, features.options(), use_cache=use_cache)

    def build_photon_pass(source):
        prg, info = build(source)
        photon = PhotonPass(dctx, prg, real)
        photon.build(scene_buf, packed.counts, eps_abs, features.lanes, 0, PhotonSettings(count=1),
                     0.01 * max(packed.size, 1e-30))
        photon.counters.clear()
        return photon, info

    if len(sources) == 1:
        built = [build(sources[0])]
    elif not program.builds_at_once(dctx):  # a runtime not known to take two builds at once
        built = [build(sources[0]), build_photon_pass(sources[1])]
    else:  # the OpenCL compilers release the GIL: the programs build at once
        with ThreadPoolExecutor(2) as pool:
            photon_side = pool.submit(build_photon_pass, sources[1])
            built = [build(sources[0]), photon_side.result()]
    info = program.BuildInfo(time.perf_counter() - t0, all(b.cache_hit for _, b in built),
                             "+".join(b.key for _, b in built), built[0][1].options)
    return built[0][0], (built[1][0] if len(built) > 1 else None), info


class DeviceWorker:
    """One device's passes for one scene, the scene's records and a job's sums."""

    def __init__(self, dctx: DeviceContext, packed: PackedScene, features: Features, use_cache: bool = True):
        self.dctx = dctx
        self.label = dctx.label
        self.features = features
        self.packed = packed
        real = np.float64 if features.double else np.float32
        if not features.double and packed.indexed_rows > MAX_FLOAT_RECORDS:  # texels are indexed by integers
            raise SceneError(f"{packed.indexed_rows} scene records exceed what float kernels index exactly "
                             f"({MAX_FLOAT_RECORDS}); render with double=True or a smaller scene")
        recs = np.ascontiguousarray(packed.records, dtype=real)
        if recs.size == 0:
            recs = np.zeros((1, 4), dtype=real)
        mf = cl.mem_flags
        self.scene_buf = cl.Buffer(dctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=recs)
        self.eps_abs = OFFSET_FLOOR['double' if features.double else 'float']  # kernels/scene.h
        self.program, self.photon, self.build = build_programs(dctx, packed, features, self.scene_buf,
                                                               self.eps_abs, use_cache)
        self.trace = TracePass(dctx, self.program, features)
        self.filter = FilterPass(dctx, self.program) if features.aux else None
        self.passes = [p for p in (self.photon, self.trace, self.filter) if p is not None]
        self.film = None
        self.launches = {}      # kernel name -> launches since start()
        self.kernel_times = {}  # kernel name -> device seconds of each launch since start()
        self.job = None

    # The photon map (tests and benchmarks read its buffers), the feature
    # sums, and the trace pass's work-group size.
    @property
    def pmap(self) -> PhotonPass | None:
        return self.photon

    @property
    def aux(self):
        return self.film.aux if self.film is not None else None

    @property
    def local(self) -> int:
        return self.trace.local

    @local.setter
    def local(self, value: int):
        self.trace.local = value

    # --- a job ----------------------------------------------------------------------
    def start(self, job: RenderJob, initial: Accumulator | None = None):
        """Get ready for a job: buffers for its image, zero sums (or `initial`)."""
        f = self.film
        if f is not None and (f.n_pix, f.caustic is not None) == (job.n_pix, job.offline):
            if initial is None:
                f.zero()  # the last job's buffers fit: zeroed, not made anew (0.4 against 2.9 ms at 256x256)
        else:
            self.film = None  # the last job's buffers go first
            self.film = Film(self.dctx, job.n_pix, accum_double=self.features.accum_double, caustic=job.offline,
                             aux=self.features.aux, extra_bytes=self.trace.buffer_bytes_for(job.n_pix),
                             label=self.label)
        self.trace.allocate(job.n_pix)
        frame = camera_frame(job.scene.camera, job.width, job.height, self.packed.length_scale)
        self.trace.set_image(job, self.packed, frame, self.eps_abs)
        self.job = job
        if self.photon is not None:
            self.photon.held = None
        for p in self.passes:  # what ran before belongs to no item of this job
            p.counters.clear()
        self.launches = {}
        self.kernel_times = {}
        if initial is not None:
            self.film.load(initial)

    # --- photon maps --------------------------------------------------------------------
    def build_photons(self, seed: int, settings: PhotonSettings, radius: float, mode: int = 0,
                      wait: bool = True) -> dict:
        """Build a photon map of `settings` (in the packed scene's lengths) from
        `seed`: its info. (`mode`, what launches do with the map, does not
        change the map.) wait False: only queued (PhotonPass.build)."""
        info = self.photon.build(self.scene_buf, self.packed.counts, self.eps_abs, self.features.lanes, seed,
                                 settings, radius, wait=wait)
        self.photon.held = None
        info.update(radius=radius, seed=seed)
        return info

    def prepare_photons(self, iteration: int, wait: bool = True) -> dict | None:
        """Build the photon map of `iteration` unless it is the one held; its
        info or None. wait False: the build is only queued, and its info
        completed by self.photon.complete once the queue has finished."""
        job = self.job
        if self.photon is None or job.photons is None or self.photon.held == iteration:
            return None
        seed, radius = photon_plan(job, iteration, self.packed.size, self.packed.length_scale)
        info = self.build_photons(seed, kernel_photons(job.photons, self.packed.length_scale), radius, wait=wait)
        self.photon.held = iteration
        info.update(device=self.label, iteration=iteration)
        return info

    # --- work ---------------------------------------------------------------------------
    def _take_counters(self) -> tuple[dict, dict]:
        """Every pass's launches and device seconds since the last item (the
        filter's run between items), added to the worker's since start()."""
        launches, seconds = {}, {}
        for p in self.passes:
            got_l, got_s = p.counters.take()
            for k, v in got_l.items():
                launches[k] = launches.get(k, 0) + v
            for k, v in got_s.items():
                seconds.setdefault(k, []).extend(v)
        for k, v in launches.items():
            self.launches[k] = self.launches.get(k, 0) + v
        for k, v in seconds.items():
            self.kernel_times.setdefault(k, []).extend(v)
        return launches, seconds

    def run(self, item: WorkItem) -> RunResult:
        """Add an item's samples to the sums; or, for a "photons" item, build
        the photon map of its iteration and measure the power it stores."""
        # A sample range's map is only queued: its launch follows it in the
        # queue without a return to the host in between (one wait per item).
        pm = self.prepare_photons(item.iteration, wait=item.kind == "photons")
        if item.kind == "photons":
            if pm is None:
                raise ValueError(f"{self.label}: the job has no photon map to build")
            pm["power"] = self.photon.stored_power()
            launches, seconds = self._take_counters()
            return RunResult(seconds=pm["host_seconds"], wall=pm["host_seconds"], photon_maps=[pm],
                             launches=launches, kernel_seconds=seconds)
        prepass = item.kind == "prepass"
        job = self.job
        lookup = None
        if self.features.photons:
            pset = kernel_photons(job.photons, self.packed.length_scale) or PhotonSettings()
            lookup = partial(self.photon.lookup, settings=pset, mode=PM_PREPASS if prepass else job.pm_mode,
                             moments=job.moments and self.features.aux)
        rec, global_size = self.trace.item_record((job.seed ^ PREPASS_SEED_SALT) if prepass else job.seed, item,
                                                  lookup)
        sums = self.film.caustic if prepass else self.film.main
        args = TraceArgs(scene=self.scene_buf, launch=None, pix_sum=sums.pix_sum, pix_sq=sums.pix_sq, stats=None,
                         pix_jobs=None, aux=self.film.aux)
        if self.features.photons:
            self.photon.fill(args)
        secs, wall, first, stats = self.trace.run(rec, global_size, args)
        if pm is not None:
            self.photon.complete(pm)  # (the launch has finished, and the build before it)
        launches, seconds = self._take_counters()
        return RunResult(seconds=secs, wall=wall, first=first, stats=stats, photon_maps=[pm] if pm else [],
                         launches=launches, kernel_seconds=seconds)

    def launch_seconds(self) -> float:
        """Host seconds of an empty launch (no samples): the fixed cost of a pass."""
        return self.run(WorkItem("samples", 0, 0)).wall

    def buffer_bytes(self) -> dict[str, int]:
        """Device memory per buffer this worker holds (after a render)."""
        out = {"scene records": self.scene_buf.size}
        for part in (self.film, self.trace, self.photon):
            if part is not None:
                out.update(part.buffer_bytes())
        return out

    # --- sums -----------------------------------------------------------------------------
    def sums(self) -> Accumulator:
        return self.film.read()

    def snapshot(self):
        """Film.snapshot: copies of the sums queued now, and their events."""
        return self.film.snapshot()

    def load(self, acc: Accumulator):
        """Replace the sums by acc's (in this device's layout)."""
        self.film.load(acc)

    def zero(self):
        self.film.zero()

    def empty_sums(self, job: RenderJob) -> Accumulator:
        return Accumulator(job.n_pix, kahan=not self.features.accum_double, aux=self.features.aux,
                           caustic=job.offline)
