"""Rendering: builds kernels per device, runs progressive passes, returns images.

A pass adds samples [s0, s0 + n) to every pixel. Samples are keyed by
(pixel, sample index), so passes can be of any size, on any device, in any
order: on one device the image is bit-identical however the samples were
split; with several devices each pulls the next sample range when it is free
and the host adds their sums at the end.

Scenes with caustic casters also get a photon map (photons.py): built once
per render from the seed, or once per iteration of spp_per_map samples when
progressive. Online, every sample gathers from it; offline, a pre-pass fills
a per-pixel caustic buffer that is added to the path-traced image.
"""

from __future__ import annotations

import copy
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pyopencl as cl
import pyopencl.cltypes as clt

from . import program, tune
from .device import DeviceContext, DeviceError, select_devices
from .features import Features, scene_features
from .pack import MAX_FLOAT_RECORDS, CameraFrame, PackedScene, camera_frame, pack_scene
from .adaptive import AdaptiveSettings, allocate_error, allocate_paper
from .constants import LOCAL_SIZE_CPU, LOCAL_SIZE_GPU, LUMA, OFFSET_FLOOR
from .denoise import ConeFilter, FilterSettings, OidnSettings, apply_denoiser
from .photons import PM_MERGE, PM_OFF, PM_OFFLINE, PM_OWNED, PM_PREPASS, PhotonMap, PhotonSettings, counts_arg, photon_seed
from .preview import RenderUpdate
from .scene import Scene, SceneError, load_scene

PREPASS_SEED_SALT = 0x2545F491


@dataclass
class RenderStats:
    nonfinite: int = 0       # samples dropped because they were NaN or infinite
    camera_rays: int = 0
    bounce_rays: int = 0
    shadow_rays: int = 0
    build_seconds: float = 0.0
    cache_hits: int = 0
    first_launch_seconds: float = 0.0  # includes a lazy device compile (PoCL)
    render_seconds: float = 0.0
    passes: list = field(default_factory=list)  # (device label, first sample, samples, seconds)
    photon_maps: list = field(default_factory=list)  # per build: stored, radius, trace/grid device seconds
    adaptive_rounds: int = 0
    photon_pilot: dict | None = None  # what the pilot measured and chose (PhotonSettings.pilot)
    launches: dict = field(default_factory=dict)  # kernel name -> launches, all devices
    kernel_seconds: dict = field(default_factory=dict)  # kernel name -> device seconds per launch (profiling)

    @property
    def rays(self) -> int:
        return self.camera_rays + self.bounce_rays + self.shadow_rays


@dataclass
class RenderResult:
    image: np.ndarray          # H x W x 3 float32, linear RGB
    sample_count: np.ndarray   # H x W samples per pixel
    lum_var: np.ndarray        # H x W variance of one sample's luminance (lum_var / count: of the mean)
    spp: int
    seed: int
    max_depth: int
    rr_depth: int
    devices: list
    features: Features
    stats: RenderStats
    photons: PhotonSettings | None = None
    caustic_image: np.ndarray | None = None  # offline photon mapping: the caustic buffer (part of image)
    aux: dict | None = None                  # feature images: normal, albedo, depth, emission, emitter,
                                             # caustic (Renderer(aux=True))
    filtered: np.ndarray | None = None       # the denoiser's output (render(filter=...)): cone filter or OIDN
    adaptive: AdaptiveSettings | None = None
    interrupted: bool = False    # stopped by Ctrl-C (KeyboardInterrupt)
    time_limited: bool = False   # stopped by time_limit before the samples asked for
    scene_source: str | None = None
    scene_sha256: str | None = None

    @property
    def samples(self) -> int:
        return int(self.sample_count.sum())

    def __repr__(self):
        h, w = self.image.shape[:2]
        spp = f"{self.sample_count.mean():.4g} spp on average" if self.stats.adaptive_rounds else f"{self.spp} spp"
        return (f"<RenderResult {w}x{h}, {spp}, seed {self.seed}, {self.stats.render_seconds:.2f} s"
                f"{', filtered' if self.filtered is not None else ''}{', interrupted' if self.interrupted else ''}>")

    def metadata(self, exposure: float | None = None) -> dict:
        """What the image files record of the render (clpt:* keys)."""
        from . import __version__

        count = self.sample_count
        meta = {"clpt:version": __version__,
                "clpt:spp": round(float(count.mean()), 4) if count.size else 0.0,
                "clpt:spp_min": int(count.min()) if count.size else 0,
                "clpt:spp_max": int(count.max()) if count.size else 0,
                "clpt:seed": self.seed, "clpt:max_depth": self.max_depth,
                "clpt:rr_depth": self.rr_depth, "clpt:device": "; ".join(self.devices),
                "clpt:render_seconds": round(self.stats.render_seconds, 4),
                "clpt:kernel": self.features.describe(), "clpt:interrupted": int(self.interrupted),
                "clpt:time_limited": int(self.time_limited)}
        if self.scene_source is not None:
            meta["clpt:scene"] = self.scene_source
        if self.scene_sha256 is not None:
            meta["clpt:scene_sha256"] = self.scene_sha256
        if exposure is not None:
            meta["clpt:exposure"] = float(exposure)
        if self.stats.photon_pilot is not None:
            meta["clpt:photon_choice"] = self.stats.photon_pilot["choice"]
        if self.photons is not None:
            p = self.photons
            meta["clpt:photons"] = (f"{p.count} photons, radius {p.radius}{'' if p.radius_absolute else ' x size'}, "
                                    f"k {p.cone_k}, {p.mode}{', progressive alpha %g' % p.alpha if p.progressive else ''}"
                                    f", budget {p.budget}, max {p.max_photons or 'all'}, aim {p.aim}")
        if self.adaptive is not None:
            a = self.adaptive
            meta["clpt:adaptive"] = (f"{a.scheme}, min spp {a.min_spp}, threshold {a.threshold:g}, "
                                     f"pass spp {a.pass_spp}, {self.stats.adaptive_rounds} rounds")
        return meta

    def save(self, path, exposure: float = 0.0):
        from .image import save_image
        save_image(path, self.image, metadata=self.metadata(exposure), exposure=exposure)

    def _repr_png_(self) -> bytes:
        """Notebooks show a result as its image, tone-mapped as save() writes a PNG."""
        from .image import png_bytes
        return png_bytes(self.image)


class _Sums:
    """Per-pixel sums on a device (accum.h's layout)."""

    def __init__(self, dctx, n_pix: int, accum_double: bool):
        self.dctx, self.n_pix, self.accum_double = dctx, n_pix, accum_double
        ctx, q = dctx.context, dctx.queue
        self.pix_sum = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, n_pix * 32)
        self.pix_sq = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, n_pix * 8)
        cl.enqueue_fill_buffer(q, self.pix_sum, np.float32(0), 0, n_pix * 32)
        cl.enqueue_fill_buffer(q, self.pix_sq, np.float32(0), 0, n_pix * 8)

    def read(self):
        """(r, g, b, count) sums and sums of squared luminance, float64."""
        raw, _ = self.read_async()
        self.dctx.queue.finish()
        return self.decode(raw)

    def read_async(self):
        """Queue copies of the sums into fresh host arrays; (arrays, events).
        Queued between two passes, they see the sums of the passes before."""
        q = self.dctx.queue
        dt, k = (np.float64, 1) if self.accum_double else (np.float32, 2)  # Kahan: (sum, compensation) pairs
        s = np.empty((self.n_pix, 4 * k), dtype=dt)
        sq = np.empty((self.n_pix, k), dtype=dt)
        events = [cl.enqueue_copy(q, s, self.pix_sum, is_blocking=False),
                  cl.enqueue_copy(q, sq, self.pix_sq, is_blocking=False)]
        return (s, sq), events

    def decode(self, raw):
        s, sq = raw
        if self.accum_double:
            return s, sq[:, 0]
        # Kahan pairs: the compensation is what the float sum holds in excess.
        s64, sq64 = s.astype(np.float64), sq.astype(np.float64)
        return s64[:, :4] - s64[:, 4:], sq64[:, 0] - sq64[:, 1]


def kernel_sources(packed: PackedScene | None, features: Features) -> list[str]:
    """The stitched programs a scene's build compiles (without a baked scene's
    records when packed is None): the path pass (and the filter), and for
    scenes with caustic photons the photon pass and grid build apart, so that
    the two build in parallel."""
    generated = {}
    if features.mode == "baked" and packed is not None:
        generated["<baked scene>"] = _baked_source(packed.records, features.double)
    out = [program.stitch(["trace.cl"] + (["filter.cl"] if features.aux else []), generated)]
    if features.photons:
        out.append(program.stitch(["photons.cl", "grid.cl"], generated))
    return out


def kernel_source(packed: PackedScene | None, features: Features) -> str:
    return "\n".join(kernel_sources(packed, features))


class _DeviceState:
    """Everything one device holds for one scene: programs, kernels, buffers."""

    def __init__(self, dctx: DeviceContext, packed: PackedScene, features: Features, use_cache: bool):
        self.dctx = dctx
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
        self.counts = counts_arg(packed.counts)
        self.eps_abs = OFFSET_FLOOR['double' if features.double else 'float']  # kernels/scene.h
        self.lum_scale = packed.lum_scale
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
            pmap.build(self.scene_buf, self.counts, self.eps_abs, features.lanes, 0, PhotonSettings(count=1),
                       0.01 * max(packed.size, 1e-30))
            pmap.launches.clear()
            pmap.kernel_times.clear()
            return pmap, info

        if len(sources) == 1:
            built = [build(sources[0])]
            self.pmap = None
        else:  # the OpenCL compilers release the GIL: the programs build at once
            with ThreadPoolExecutor(2) as pool:
                photon_side = pool.submit(build_photons, sources[1])
                built = [build(sources[0]), photon_side.result()]
            self.pmap = built[1][0]
        self.program = built[0][0]
        self.build = program.BuildInfo(time.perf_counter() - t0, all(b.cache_hit for _, b in built),
                                       "+".join(b.key for _, b in built), built[0][1].options)
        self.kernel = cl.Kernel(self.program, "trace_paths")
        self.local = LOCAL_SIZE_CPU if dctx.is_cpu else LOCAL_SIZE_GPU
        self.launched = False
        self.filter = ConeFilter(dctx, self.program) if features.aux else None
        self.launches = {}
        self.kernel_times = {}  # kernel name -> device seconds of each launch since allocate()

    def allocate(self, n_pix: int, caustic_buffer: bool, width: int | None = None):
        lanes = self.features.lanes
        groups = -(-n_pix // lanes)
        tw = self.features.tile_width
        if tw > 1:  # one work-item per tile (width None: one image row)
            w = width or n_pix
            groups = -(-w // tw) * -(-(n_pix // w) // (lanes // tw))
        self.global_size = -(-groups // self.local) * self.local
        need = n_pix * 40 * (2 if caustic_buffer else 1) + self.global_size * 16 + n_pix * 64 * self.features.aux
        dev = self.dctx.device
        if n_pix * 32 > dev.max_mem_alloc_size or need > dev.global_mem_size:
            raise DeviceError(f"{n_pix} pixels need {need / 2**20:.0f} MiB of accumulation buffers, more than "
                              f"{self.dctx.label} offers ({dev.global_mem_size / 2**20:.0f} MiB, at most "
                              f"{dev.max_mem_alloc_size / 2**20:.0f} MiB per buffer); render a smaller image")
        ctx, q, rw = self.dctx.context, self.dctx.queue, cl.mem_flags.READ_WRITE
        try:
            self.main = _Sums(self.dctx, n_pix, self.features.accum_double)
            self.caustic = _Sums(self.dctx, n_pix, self.features.accum_double) if caustic_buffer else None
            self.stats_buf = cl.Buffer(ctx, rw, self.global_size * 16)
            self.list_buf = cl.Buffer(ctx, rw, 4)   # adaptive passes replace these
            self.jobs_buf = cl.Buffer(ctx, rw, 16)
            self.aux = []
            if self.features.aux:
                self.aux = [cl.Buffer(ctx, rw, n_pix * 16) for _ in range(4)]
                for b in self.aux:
                    cl.enqueue_fill_buffer(q, b, np.float32(0), 0, n_pix * 16)
            q.finish()
        except cl.Error as e:
            raise DeviceError(f"cannot allocate {need / 2**20:.0f} MiB on {self.dctx.label} for "
                              f"{n_pix} pixels ({e}); render a smaller image") from None
        self.stats_host = np.empty((self.global_size, 4), dtype=np.uint32)
        self.n_pix = n_pix

    def set_frame(self, frame: CameraFrame, width: int, height: int, max_depth: int, rr_depth: int, seed: int):
        r4 = clt.make_double4 if self.features.double else clt.make_float4
        self.head = [self.scene_buf, self.counts, self.real(self.eps_abs), self.real(self.lum_scale), r4(*frame.origin, 0),
                     r4(*frame.corner, 0), r4(*frame.dx, 0), r4(*frame.dy, 0), np.uint32(width),
                     np.uint32(height), np.uint32(0)]
        self.depths = [np.uint32(min(max_depth, 2**31)), np.uint32(min(rr_depth, 2**31))]
        self.seed = seed

    def build_photons(self, seed: int, settings: PhotonSettings, radius: float, mode: int):
        info = self.pmap.build(self.scene_buf, self.counts, self.eps_abs, self.features.lanes, seed, settings,
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

    def run(self, s0: int, n: int, prepass: bool = False, pixels=None, jobs=None):
        """Add samples [s0, s0 + n) to every pixel (of the caustic buffer, for the
        offline pre-pass), or, given pixels and jobs (adaptive), jobs[i] =
        (samples, max depth, first sample index, 0) to pixel pixels[i]. Returns
        (seconds, stats row sums)."""
        q = self.dctx.queue
        sums = self.caustic if prepass else self.main
        seed = (self.seed ^ PREPASS_SEED_SALT) if prepass else self.seed
        global_size, n_list = self.global_size, 0
        if pixels is not None:
            n_list = len(pixels)
            global_size = -(-(-(-n_list // self.features.lanes)) // self.local) * self.local
            if global_size > len(self.stats_host):
                self.stats_buf = cl.Buffer(self.dctx.context, cl.mem_flags.READ_WRITE, global_size * 16)
                self.stats_host = np.empty((global_size, 4), dtype=np.uint32)
            mf = cl.mem_flags
            self.list_buf = cl.Buffer(self.dctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                      hostbuf=np.ascontiguousarray(pixels, dtype=np.uint32))
            self.jobs_buf = cl.Buffer(self.dctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                      hostbuf=np.ascontiguousarray(jobs, dtype=np.uint32))
        args = [*self.head, np.uint32(s0), np.uint32(n), *self.depths, np.uint32(seed), sums.pix_sum, sums.pix_sq,
                self.stats_buf, self.list_buf, self.jobs_buf, np.uint32(n_list)]
        if self.features.aux:
            args += [*self.aux, np.uint32(self.aux_specular)]
        if self.features.photons:
            mode = PM_PREPASS if prepass else self.pm_mode
            args += self.pmap.kernel_args(self.pm_settings, mode)
        self.kernel.set_args(*args)
        t0 = time.perf_counter()
        ev = cl.enqueue_nd_range_kernel(q, self.kernel, (global_size,), (self.local,))
        stats = self.stats_host[:global_size]
        cl.enqueue_copy(q, stats, self.stats_buf)  # blocking: the launch has finished
        seconds = time.perf_counter() - t0
        program.note_time(self.kernel_times, "trace_paths", ev)
        self.launches["trace_paths"] = self.launches.get("trace_paths", 0) + 1
        return seconds, stats.sum(axis=0, dtype=np.uint64)

    def buffer_bytes(self) -> dict[str, int]:
        """Device memory per buffer this state holds (after a render)."""
        out = {"scene records": self.scene_buf.size}
        for name, sums in (("pixel sums", getattr(self, "main", None)), ("caustic sums", getattr(self, "caustic", None))):
            if sums is not None:
                out[name] = sums.pix_sum.size + sums.pix_sq.size
        if hasattr(self, "stats_buf"):
            out["work-item stats"] = self.stats_buf.size
            out["adaptive lists"] = self.list_buf.size + self.jobs_buf.size
        if getattr(self, "aux", None):
            out["feature buffers"] = sum(b.size for b in self.aux)
        if self.pmap is not None:
            out.update(self.pmap.buffer_bytes())
        return out

    def read_aux(self):
        """Per-pixel feature sums: (normal xyz, count), (albedo rgb, distance), (emission rgb, emitter
        count), (caustic rgb, its squared scaled luminance)."""
        out, _ = self.read_aux_async()
        self.dctx.queue.finish()
        return [h.astype(np.float64) for h in out]

    def read_aux_async(self):
        out = [np.empty((self.n_pix, 4), np.float32) for _ in self.aux]
        return out, [cl.enqueue_copy(self.dctx.queue, h, b, is_blocking=False) for h, b in zip(out, self.aux)]

    def snapshot(self, caustic: bool):
        """Queue copies of everything an image so far is made of; (raw, events)."""
        main, events = self.main.read_async()
        raw = {"main": main}
        if caustic and self.caustic is not None:
            raw["caustic"], ev = self.caustic.read_async()
            events += ev
        if self.features.aux:
            raw["aux"], ev = self.read_aux_async()
            events += ev
        self.dctx.queue.flush()
        return raw, events


def _baked_source(records: np.ndarray, double: bool) -> str:
    t = "double4" if double else "float4"
    fmt = "%.17g" if double else "%.9g"
    # Printed from the kernel's own precision: 9 digits give back exactly the
    # float the buffer would hold (rounding the double's digits could miss it).
    records = np.asarray(records, dtype=np.float64 if double else np.float32).astype(np.float64)
    rows = ",\n".join(f"    ({t})({', '.join(fmt % v for v in r)})" for r in records) or f"    ({t})(0)"
    return f"__constant real4 clpt_scene[{max(1, len(records))}] = {{\n{rows}\n}};\n"


def _lane_group_max(n: np.ndarray, lanes: int) -> np.ndarray:
    """Each entry raised to the largest of its group of `lanes` consecutive entries."""
    pad = -len(n) % lanes
    g = np.concatenate([n, np.zeros(pad, dtype=n.dtype)]).reshape(-1, lanes)
    return np.repeat(g.max(axis=1), lanes)[:len(n)].astype(n.dtype)


def _combine(states, which: str, n_pix: int, lum_scale: float = 1.0):
    return _mean_var([getattr(st, which).read() for st in states if getattr(st, which) is not None], n_pix,
                     lum_scale)


def _mean_var(parts, n_pix: int, lum_scale: float = 1.0):
    """Mean, variance of one sample's luminance, and count per pixel, from
    every device's (sums, sums of squares)."""
    if len(parts) == 1:  # one device: its sums as they are
        total, total_sq = parts[0]
    else:
        total = np.zeros((n_pix, 4), dtype=np.float64)
        total_sq = np.zeros(n_pix, dtype=np.float64)
        for s, sq in parts:
            total += s
            total_sq += sq
    count = total[:, 3]
    safe = np.maximum(count, 1.0)
    mean = total[:, :3] / safe[:, None]
    lum_mean = (mean @ LUMA) * lum_scale  # the kernels square scaled luminance
    var = np.maximum(total_sq / safe - lum_mean ** 2, 0.0) * (safe / np.maximum(safe - 1.0, 1.0)) / lum_scale ** 2
    return mean, var, count


class Renderer:
    """A scene prepared for rendering on one or more devices.

    Kernels are built (or loaded from the build cache) once, here; render()
    can then be called any number of times with different settings.
    photons: None (the default) turns caustic photon mapping on when the scene
    has caustic casters (purely specular objects); False never compiles it.
    bvh: "auto" puts the primitives in a BVH when the scene has at least
    clpt.pack.BVH_MIN_PRIMS of them (plain loops are faster below), "on" or
    "off" force it; bvh_method: "sah" or "lbvh" (clpt/bvh.py); bvh_walk:
    "packet" or "lane" (kernels/bvh.h).
    """

    def __init__(self, scene, *, device=None, lanes: int | None = None, local_size: int | None = None,
                 precision: str = "float", kernel: str = "specialized", nee: bool = True,
                 photons: bool | None = None, aux: bool = False, use_cache: bool = True, accumulate: str = "auto",
                 tiles: bool = False, bvh="auto", bvh_method: str = "lbvh", bvh_walk: str = "packet"):
        if isinstance(scene, (str, Path)):
            scene = load_scene(scene)
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a clpt.Scene or a path, not {type(scene).__name__}")
        if precision not in ("float", "double"):
            raise ValueError(f"precision must be 'float' or 'double' (got {precision!r})")
        if accumulate not in ("auto", "double", "kahan"):
            raise ValueError(f"accumulate must be 'auto', 'double' or 'kahan' (got {accumulate!r})")
        if lanes is not None and (isinstance(lanes, bool) or lanes not in tune.LANE_WIDTHS):
            raise ValueError(f"lanes must be one of {', '.join(map(str, tune.LANE_WIDTHS))} (got {lanes!r})")
        if local_size is not None and (isinstance(local_size, bool) or not isinstance(local_size, int)
                                       or local_size < 1):
            raise ValueError(f"local_size must be a positive integer (got {local_size!r})")
        if kernel not in ("specialized", "generic", "baked"):
            raise ValueError(f"kernel must be 'specialized', 'generic' or 'baked' (got {kernel!r})")
        self.scene = scene
        t0 = time.perf_counter()
        self.packed = pack_scene(scene, bvh=bvh, bvh_method=bvh_method)
        self.pack_seconds = time.perf_counter() - t0
        use_photons = self.packed.has_caustics and photons is not False
        self.devices = [DeviceContext(d) for d in select_devices(device)]
        self.states = []
        for dctx in self.devices:
            if (precision == "double" or accumulate == "double") and not dctx.fp64:
                raise DeviceError(f"{dctx.label} has no double precision (cl_khr_fp64); "
                                  f"render with precision='float'")
            acc_double = dctx.fp64 if accumulate == "auto" else accumulate == "double"
            if local_size is not None and local_size > dctx.device.max_work_group_size:
                raise DeviceError(f"local size {local_size} is above {dctx.label}'s maximum work-group size "
                                  f"{dctx.device.max_work_group_size}")

            def feats(n_lanes):
                return scene_features(self.packed, lanes=n_lanes, double=precision == "double",
                                      accum_double=acc_double or precision == "double", mode=kernel, nee=nee,
                                      photons=use_photons, aux=aux, tiles=tiles, bvh_walk=bvh_walk)

            f = feats(lanes or 1)
            tuning, st = tune.choose(dctx, kernel_source(None, f), f.options(),
                                     lambda n: _DeviceState(dctx, self.packed, feats(n), use_cache), self._trial,
                                     lanes=lanes, local_size=local_size, use_cache=use_cache)
            if st is None:
                st = _DeviceState(dctx, self.packed, feats(tuning.lanes), use_cache)
            st.local = tuning.local_size
            st.tuning = tuning
            self.states.append(st)
        self.features = self.states[0].features

    def _trial(self, st, spp: int, seed: int):
        """Render spp samples per pixel of a tune.TRIAL_SIZE square image the
        default way on state st alone; (samples/s of the passes after the
        one-sample probe, seconds per spp)."""
        shell = Renderer.__new__(Renderer)
        shell.scene, shell.packed, shell.states, shell.features = self.scene, self.packed, [st], st.features
        n = tune.TRIAL_SIZE
        res = shell.render(spp, width=n, height=n, seed=seed, pass_seconds=1e9)
        passes = res.stats.passes[1:] or res.stats.passes
        secs = max(sum(p[3] for p in passes), 1e-9)
        done = sum(p[2] for p in passes)
        return done * n * n / secs, secs / max(done, 1)

    def _kernel_photons(self, pset):
        """The photon settings in the packed scene's lengths (an absolute radius scaled with them)."""
        if pset is not None and pset.radius_absolute and self.packed.length_scale != 1.0:
            return replace(pset, radius=pset.radius * self.packed.length_scale)
        return pset

    @property
    def build_seconds(self) -> float:
        return sum(s.build.seconds for s in self.states)

    def render(self, spp: int | None = None, *, seed: int | None = None, max_depth: int | None = None,
               rr_depth: int | None = None, width: int | None = None, height: int | None = None,
               photons: PhotonSettings | None = None, adaptive: AdaptiveSettings | None = None,
               filter: FilterSettings | OidnSettings | None = None, aux_specular: str = "surface",
               progress=None, preview=None, time_limit: float | None = None,
               pass_seconds: float | None = None, on_update=None, update_interval: float = 0.25) -> RenderResult:
        """Render; keywords override the scene's settings.

        spp is the average number of samples per pixel (with adaptive
        sampling, the budget shared among the pixels). progress(done_spp,
        total_spp, elapsed_seconds, samples_per_second) is called after each
        pass; preview(image) every filter.interval passes with the filtered
        image so far. filter: the cone filter (FilterSettings) or OIDN
        (OidnSettings) on the final image. aux_specular: what the feature
        buffers show of mirrors and glass, "surface" (the delta surface
        itself, the default: both denoisers measure better with it) or
        "through" (the first non-delta vertex seen through them, the
        throughput folded into its albedo). on_update(update) is called
        between passes, at most every update_interval seconds, with a
        clpt.preview.RenderUpdate (the image so far, counts, variances,
        feature images, statistics), and once at the end with update.final
        True. Ctrl-C (KeyboardInterrupt) ends the render early with what is
        done. pass_seconds: how long a pass should take (default: the
        device's tuned choice)."""
        if pass_seconds is None:
            pass_seconds = self.states[0].tuning.pass_seconds
        rs = self.scene.render
        spp = rs.spp if spp is None else spp
        seed = rs.seed if seed is None else seed
        max_depth = rs.max_depth if max_depth is None else max_depth
        rr_depth = rs.rr_depth if rr_depth is None else rr_depth
        width = self.scene.camera.width if width is None else width
        height = self.scene.camera.height if height is None else height
        for name, v, lo in (("spp", spp, 1), ("seed", seed, 0), ("max_depth", max_depth, 0),
                            ("rr_depth", rr_depth, 0), ("width", width, 1), ("height", height, 1)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise SceneError(f"render: {name} must be an integer >= {lo} (got {v!r})")
        if spp >= 2**32 or seed >= 2**32:
            raise SceneError("render: spp and seed must be below 2^32")
        if on_update is not None and not callable(on_update):
            raise TypeError(f"render: on_update must be callable (got {type(on_update).__name__})")
        if isinstance(update_interval, bool) or not isinstance(update_interval, (int, float)) \
                or not update_interval >= 0 or update_interval == float("inf"):
            raise ValueError(f"render: update_interval must be a number of seconds >= 0 (got {update_interval!r})")
        for name, v in (("time_limit", time_limit), ("pass_seconds", pass_seconds)):
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating))
                                  or not (math.isfinite(v) and v > 0)):
                raise SceneError(f"render: {name} must be a finite number of seconds > 0 (got {v!r})")
        pset = (photons or PhotonSettings()).check().resolved(width * height) if self.features.photons else None
        pilot_info = None
        t_pilot = time.perf_counter()
        if pset is not None:
            self._kernel_photons(pset).check_radius(self.packed.size, self.features.double)
            if pset.pilot and pset.mode == "merge" and pset.count > 0 and adaptive is None:
                from .photons import pilot
                pset, pilot_info = pilot(self, pset, seed=seed)
        pilot_seconds = time.perf_counter() - t_pilot
        if pilot_info is not None and time_limit is not None:
            time_limit = max(time_limit - pilot_seconds, 0.0)  # the pilot is part of the render's time
        kset = self._kernel_photons(pset)  # in the packed scene's lengths
        # No photons: the path tracer keeps every path (pm_mode PM_OFF), as with photons=False.
        no_photons = pset is not None and pset.count == 0
        progressive = pset is not None and pset.progressive and not no_photons
        offline = pset is not None and pset.mode == "offline" and not progressive and not no_photons
        aset = adaptive.check() if adaptive is not None else None
        fset = filter.check() if filter is not None else None
        if fset is not None and not self.features.aux:
            raise SceneError("render: the filter needs the feature buffers: make the Renderer with aux=True")
        if aux_specular not in ("through", "surface"):
            raise SceneError(f"render: aux_specular must be 'through' or 'surface' (got {aux_specular!r})")
        frame = camera_frame(self.scene.camera, width, height, self.packed.length_scale)
        n_pix = width * height
        stats = RenderStats(build_seconds=self.build_seconds,
                            cache_hits=sum(s.build.cache_hit for s in self.states))
        for st in self.states:
            st.allocate(n_pix, caustic_buffer=offline, width=width)
            st.set_frame(frame, width, height, max_depth, rr_depth, seed)
            st.aux_specular = int(aux_specular == "surface")
            st.launches = {}
            st.kernel_times = {}

        lock = threading.Lock()
        uniform_spp = spp if aset is None else min(spp, aset.min_spp)
        budget = spp * n_pix  # samples in all
        state = {"next": 0, "done": 0, "stop": False, "error": None, "passes": 0}
        t_start = time.perf_counter()
        mode = (PM_OFF if pset is None or no_photons else PM_OFFLINE if offline
                else PM_MERGE if pset.mode == "merge" else PM_OWNED)

        def elapsed():
            return time.perf_counter() - t_start

        last_update = [-float("inf")]

        def update():
            """Hand on_update the image so far, if update_interval has passed."""
            if on_update is None or elapsed() - last_update[0] < update_interval:
                return
            with lock:
                done = state["done"]
                snap = copy.copy(stats)
            load, load_aux = self._snapshot(n_pix, width, height, offline)
            last_update[0] = now = elapsed()
            on_update(RenderUpdate(spp_done=done, spp_total=spp, elapsed=now, stats=snap, load=load,
                                   load_aux=load_aux))

        def note_pass(st, s0, n, seconds, row):
            with lock:
                state["done"] += n
                state["passes"] += 1
                stats.nonfinite += int(row[0])
                stats.camera_rays += int(row[1])
                stats.bounce_rays += int(row[2])
                stats.shadow_rays += int(row[3])
                stats.passes.append((st.dctx.label, s0, n, seconds))
                return state["done"], state["passes"]

        def photon_map(st, iteration):
            info = st.build_photons(photon_seed(seed, iteration), kset, kset.radius_for(self.packed.size, iteration),
                                    mode)
            with lock:
                stats.photon_maps.append({"device": st.dctx.label, "iteration": iteration, **info})
            if offline:  # the caustic buffer
                st.run(0, min(pset.offline_spp, spp), prepass=True)

        # With several devices, each one's first pass is reserved for it (a
        # sample index, or a photon iteration's samples when progressive), so
        # a device that starts late (a slower build or photon map) still gets
        # work instead of finding every sample taken.
        reserved = {}
        if len(self.states) > 1:
            k = pset.spp_per_map if progressive else 1
            firsts = range(0, uniform_spp, k)
            reserved = {id(st): (s0, min(k, uniform_spp - s0)) for st, s0 in zip(self.states, firsts)}
            state["next"] = min(uniform_spp, len(reserved) * k)

        def take(st, per_spp):
            with lock:
                if id(st) in reserved and state["error"] is None:
                    return reserved.pop(id(st))
                if state["stop"] or state["next"] >= uniform_spp:
                    return None
                s0 = state["next"]
                if progressive:  # one photon map per spp_per_map samples
                    n = pset.spp_per_map
                else:
                    n = 1 if per_spp is None else int(max(1, min(pass_seconds / max(per_spp, 1e-9), 1 << 16)))
                if time_limit is not None and per_spp is not None:
                    left = time_limit - elapsed()
                    if left < per_spp * 0.5:
                        state["stop"] = True
                        return None
                    if not progressive:
                        n = max(1, min(n, int(left / per_spp)))
                n = min(n, uniform_spp - s0)
                state["next"] = s0 + n
                return s0, n

        def work(st):
            per_spp = None
            try:
                if pset is not None and not progressive:
                    photon_map(st, 0)
                while True:
                    job = take(st, per_spp)
                    if job is None:
                        return
                    s0, n = job
                    if progressive:
                        photon_map(st, s0 // pset.spp_per_map)
                    seconds, row = st.run(s0, n)
                    if st.launched:
                        per_spp = seconds / n
                    else:  # may include the device's own lazy compile: not a pass-size guide
                        st.launched = True
                        stats.first_launch_seconds += seconds
                    done, passes = note_pass(st, s0, n, seconds, row)
                    if len(self.states) == 1:
                        update()
                        if progress is not None:
                            progress(done, spp, elapsed(), done * n_pix / max(elapsed(), 1e-9))
                        if preview is not None and fset is not None and fset.interval and passes % fset.interval == 0:
                            preview(self._finish(n_pix, width, height, offline, fset)[-1])
            except BaseException as e:  # noqa: BLE001 - handed to the main thread
                with lock:
                    state["error"] = e
                    state["stop"] = True

        interrupted = self._run_threads(work, state, lock, progress, spp, n_pix, elapsed, update)
        if aset is not None and not interrupted and not state["stop"]:
            # Progressive photons: each adaptive round gets the next iteration's map.
            first_round_map = -(-uniform_spp // pset.spp_per_map) if progressive else 0
            round_map = (lambda st, k: photon_map(st, first_round_map + k)) if progressive else None
            interrupted = self._adaptive_rounds(aset, max_depth, budget, n_pix, width, height, state, lock,
                                                note_pass, stats, progress, spp, elapsed, time_limit, round_map,
                                                update=update)
        if state["error"] is not None:
            raise state["error"]
        image, var, count, caustic, aux, filtered = self._finish(n_pix, width, height, offline, fset)
        # Stopped by the time limit, not by Ctrl-C (adaptive: not by convergence either).
        time_limited = time_limit is not None and not interrupted and (
            state["done"] < spp if aset is None else count.sum() < budget and elapsed() >= time_limit)
        stats.render_seconds = elapsed() + (pilot_seconds if pilot_info is not None else 0.0)
        stats.photon_pilot = pilot_info
        for st in self.states:
            for k, v in st.launches.items():
                stats.launches[k] = stats.launches.get(k, 0) + v
            if st.filter is not None:
                st.kernel_times.update(st.filter.kernel_times)
                st.filter.kernel_times = {}
            for k, v in st.kernel_times.items():
                stats.kernel_seconds.setdefault(k, []).extend(v)
        sample_count = count.reshape(height, width).astype(np.uint32)
        if on_update is not None:
            on_update(RenderUpdate(spp_done=float(count.mean()) if n_pix else 0.0, spp_total=spp,
                                   elapsed=stats.render_seconds, stats=stats, final=True, filtered=filtered,
                                   image=image, sample_count=sample_count,
                                   lum_var=var.reshape(height, width).astype(np.float32), aux=aux))
        return RenderResult(image=image, sample_count=sample_count,
                            lum_var=var.reshape(height, width),
                            spp=int(count.max()) if n_pix else 0, seed=seed, max_depth=max_depth,
                            rr_depth=rr_depth, devices=[s.dctx.label for s in self.states],
                            features=self.features, stats=stats, photons=pset, caustic_image=caustic,
                            aux=aux, filtered=filtered, adaptive=aset, interrupted=interrupted,
                            time_limited=bool(time_limited), scene_source=self.scene.source,
                            scene_sha256=self.scene.sha256)

    def _run_threads(self, work, state, lock, progress, spp, n_pix, elapsed, update) -> bool:
        """Run work(state) on every device (in threads when several); True if interrupted."""
        interrupted = False
        if len(self.states) == 1:
            try:
                work(self.states[0])
            except KeyboardInterrupt:
                interrupted = True
            if isinstance(state["error"], KeyboardInterrupt):
                interrupted = True
                state["error"] = None
            return interrupted
        threads = [threading.Thread(target=work, args=(st,), daemon=True) for st in self.states]
        for t in threads:
            t.start()
        try:
            last = -1
            while any(t.is_alive() for t in threads):
                for t in threads:
                    t.join(timeout=0.1)
                with lock:
                    done = state["done"]
                if done > 0:  # the merged image so far
                    update()
                if progress is not None and done != last:
                    last = done
                    progress(done, spp, elapsed(), done * n_pix / max(elapsed(), 1e-9))
        except KeyboardInterrupt:
            interrupted = True
            with lock:
                state["stop"] = True
            for t in threads:
                t.join()
        return interrupted

    def _adaptive_rounds(self, aset, max_depth, budget, n_pix, width, height, state, lock, note_pass, stats,
                         progress, spp, elapsed, time_limit, round_map=None, update=None) -> bool:
        """Adaptive passes until the pixels are below the threshold (error
        scheme) or the sample budget or time runs out; round_map(state, k),
        if given, builds the photon map of round k first. True if interrupted."""
        stats.adaptive_rounds = 0
        try:
            while True:
                if time_limit is not None and elapsed() >= time_limit:
                    break
                mean, var, count = _combine(self.states, "main", n_pix, self.packed.lum_scale)
                used = int(count.sum())
                left = budget - used
                if left <= 0:
                    break
                shape = (height, width)
                lum = (mean @ LUMA).reshape(shape)
                if aset.scheme == "error":
                    # A round spends at most an eighth of the budget, so later rounds
                    # see what the earlier ones achieved.
                    round_budget = min(left, max(budget // 8, n_pix))
                    if time_limit is not None and used > 0:
                        # Half the time left at the rate so far: the last rounds shrink
                        # with it instead of running past the limit.
                        rate = used / max(elapsed(), 1e-9)
                        round_budget = min(round_budget, max(n_pix, int(rate * (time_limit - elapsed()) / 2)))
                    n, _ = allocate_error(lum, var.reshape(shape), count.reshape(shape), aset, round_budget)
                    depth = np.full(shape, max_depth)
                else:
                    se = np.sqrt(var / np.maximum(count, 1.0)).reshape(shape)
                    n, depth, _ = allocate_paper(lum, aset, max_depth, se)
                    if n.sum() > left:  # the last round: scale down to the budget
                        n = np.floor(n * (left / n.sum())).astype(np.int64)
                pixels = np.flatnonzero(n)
                if len(pixels) == 0:
                    break
                jobs = np.zeros((len(pixels), 4), dtype=np.uint32)
                jobs[:, 0] = n.ravel()[pixels]
                jobs[:, 1] = np.minimum(depth.ravel()[pixels], 2**31)
                jobs[:, 2] = count[pixels]  # each pixel continues its own sample sequence
                # Split the list among the devices in contiguous parts (neighbouring
                # pixels share a work-item: their paths run alike in its lanes).
                parts = np.array_split(np.arange(len(pixels)), len(self.states))
                # A work-item lasts as long as its busiest lane: each lane gets as many
                # samples as the busiest of its work-item's lanes, when the budget allows.
                more = [_lane_group_max(jobs[idx, 0], st.features.lanes) for st, idx in zip(self.states, parts)]
                if sum(int(m.sum()) for m in more) <= left:
                    for idx, m in zip(parts, more):
                        jobs[idx, 0] = m
                errors = []

                def one(st, idx):
                    try:
                        if round_map is not None:
                            round_map(st, stats.adaptive_rounds)
                        if len(idx):
                            seconds, row = st.run(0, 0, pixels=pixels[idx], jobs=jobs[idx])
                            note_pass(st, -1, int(jobs[idx, 0].sum()) / n_pix, seconds, row)
                    except BaseException as e:  # noqa: BLE001
                        errors.append(e)

                threads = [threading.Thread(target=one, args=(st, idx)) for st, idx in zip(self.states, parts)]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join()
                if errors:
                    raise errors[0]
                stats.adaptive_rounds += 1
                if update is not None:
                    update()
                if progress is not None:
                    done = (used + int(jobs[:, 0].sum())) / n_pix
                    progress(min(done, spp), spp, elapsed(), done * n_pix / max(elapsed(), 1e-9))
        except KeyboardInterrupt:
            return True
        return False

    def _finish(self, n_pix, width, height, offline, fset):
        """The image so far, its variance and counts, the caustic buffer, the
        feature images and the denoised image."""
        main = [st.main.read() for st in self.states]
        caustic_parts = [st.caustic.read() for st in self.states] if offline else None
        image, var, count, caustic, caustic_var = self._compose(main, caustic_parts, n_pix, width, height)
        aux = filtered = None
        if self.features.aux:
            aux, online_caustic, online_var = self._aux_images(n_pix, width, height, count)
            if offline:
                aux["caustic"], aux["caustic_var"] = caustic, caustic_var.reshape(height, width)
            else:
                aux["caustic"], aux["caustic_var"] = online_caustic, online_var.reshape(height, width)
            if fset is not None:
                filtered = apply_denoiser(self.states[0].filter, image, var.reshape(height, width),
                                          count.reshape(height, width), aux, fset)
        return image, var, count, caustic, aux, filtered

    def _compose(self, main, caustic_parts, n_pix, width, height):
        """Image, variance and counts from every device's sums (and caustic
        buffer sums, offline); also the caustic image and its variance."""
        mean, var, count = _mean_var(main, n_pix, self.packed.lum_scale)
        caustic = caustic_var = None
        if caustic_parts is not None:
            c_mean, c_var, c_count = _mean_var(caustic_parts, n_pix, self.packed.lum_scale)
            caustic = c_mean.astype(np.float32).reshape(height, width, 3)
            mean = mean + c_mean
            # As the variance of one sample: the caustic mean's variance scaled to count samples.
            caustic_var = c_var * np.maximum(count, 1.0) / np.maximum(c_count, 1.0)
            var = var + caustic_var
        image = mean.astype(np.float32).reshape(height, width, 3)
        bad = ~np.isfinite(image)
        if bad.any():  # the kernels drop non-finite samples; this is the last guard
            warnings.warn(f"{int(bad.sum())} non-finite pixel values set to 0")
            image[bad] = 0.0
        return image, var, count, caustic, caustic_var

    def _snapshot(self, n_pix, width, height, offline):
        """Queue copies of the sums on every device (between passes, without
        waiting for them); return load() -> (image, sample_count, lum_var) and
        load_aux() -> the feature images or None, made from them when called,
        for a RenderUpdate."""
        taken = [st.snapshot(offline) for st in self.states]

        def wait():
            for _, events in taken:
                cl.wait_for_events(events)

        def main_parts():
            return [st.main.decode(raw["main"]) for st, (raw, _) in zip(self.states, taken)]

        def load():
            wait()
            caustic = ([st.caustic.decode(raw["caustic"]) for st, (raw, _) in zip(self.states, taken)]
                       if offline else None)
            image, var, count, _, _ = self._compose(main_parts(), caustic, n_pix, width, height)
            return image, count.reshape(height, width).astype(np.uint32), var.reshape(height, width).astype(np.float32)

        def load_aux():
            if not self.features.aux:
                return None
            wait()
            count = sum(s[:, 3] for s, _ in main_parts())
            return self._aux_images(n_pix, width, height, count, [raw["aux"] for raw, _ in taken])[0]

        return load, load_aux

    def _aux_images(self, n_pix, width, height, count, parts=None):
        """The feature images (per-sample means), the online photon part and
        its per-sample luminance variance, from every device's feature sums
        (read now, unless given)."""
        parts = [st.read_aux() for st in self.states] if parts is None else parts
        sums = [np.zeros((n_pix, 4)) for _ in range(4)]
        for part in parts:
            for acc, p in zip(sums, part):
                acc += p
        nsum, asum, esum, csum = sums
        k = np.maximum(nsum[:, 3:4], 1.0)
        normal = nsum[:, :3]
        normal = normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)

        def img(a):
            return a.reshape(height, width, -1).astype(np.float32)

        aux = {"normal": img(normal), "albedo": img(asum[:, :3] / k),
               "depth": (asum[:, 3] / k[:, 0] / self.packed.length_scale).reshape(height, width).astype(np.float32),
               "emission": img(esum[:, :3] / k),
               "emitter": (esum[:, 3] / k[:, 0]).reshape(height, width).astype(np.float32)}
        n = np.maximum(count, 1.0)
        c_mean = csum[:, :3] / n[:, None]
        ls = self.packed.lum_scale
        c_lum = (c_mean @ LUMA) * ls
        c_var = np.maximum(csum[:, 3] / n - c_lum ** 2, 0.0) * (n / np.maximum(n - 1.0, 1.0)) / ls ** 2
        return aux, img(c_mean), c_var


def render(scene, *, spp: int | None = None, seed: int | None = None, max_depth: int | None = None,
           width: int | None = None, height: int | None = None, device=None, **kw) -> np.ndarray:
    """Render a scene (a Scene, a path, or a shipped scene's name) and return
    linear RGB as a float32 H x W x 3 array. Keywords override the scene's
    settings; other keywords go to Renderer (lanes, precision, kernel, nee,
    photons: bool) or Renderer.render (rr_depth, progress, time_limit;
    photon_settings: a PhotonSettings)."""
    render_kw = {k: kw.pop(k) for k in ("rr_depth", "progress", "time_limit", "pass_seconds", "adaptive")
                 if k in kw}
    if "photon_settings" in kw:
        render_kw["photons"] = kw.pop("photon_settings")
    r = Renderer(scene, device=device, **kw)
    return r.render(spp, seed=seed, max_depth=max_depth, width=width, height=height, **render_kw).image
