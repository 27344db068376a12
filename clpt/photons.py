"""Caustic photon mapping on the device: photon pass, hash-grid build, and the
settings of the gather (kernels/photons.cl, kernels/grid.cl,
kernels/photon_grid.h).

A scene without caustic casters (purely specular objects) compiles no photon
code and allocates nothing here. For the others, each device builds its own
photon map from the same seed, so every device sees the same photons.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from .constants import LOCAL_SIZE_CPU, LOCAL_SIZE_GPU
from .program import note_time

RADIX_BITS = 8
GRID_CELL_RADII = 2  # grid cells are cubes of this many gather radii (kernels/photon_grid.h)
MAX_TABLE_BITS = 24
# What a trace_paths launch does with the photon map (PhotonMap.lookup turns
# a mode into the launch record's choices, kernels/path.h): none; merge at
# vertices with a non-delta part; the map owns the paths through the first
# one (x) and gathers there (online), or leaves that to a caustic buffer
# (offline); the offline pre-pass, which fills that buffer.
PM_OFF, PM_MERGE, PM_OWNED, PM_OFFLINE, PM_PREPASS = 0, 1, 2, 3, 4
MODES = ("merge", "online", "offline")


@dataclass(frozen=True)
class PhotonSettings:
    """How caustics are rendered with photons.

    count: photons emitted per photon map. radius: gather radius, a fraction
    of the scene's size (the diagonal of its geometry's bounds) unless
    radius_absolute. cone_k: Jensen's cone filter constant (>= 1).
    max_photons: most photons one gather uses (0: all within the radius; the
    paper's cap, which biases dense regions dark). budget: most photons a
    gather visits per row of three cells; denser rows are subsampled without
    bias (every s-th photon from a random offset, weighted by s).
    mode: "online" (the default) gathers in every sample; "offline" gathers in
    the offline_spp samples per pixel of a pre-pass (at most the render's spp)
    into a caustic buffer that is added to the image: cheaper, but where a
    caustic changes within a pixel, as at its focus, those few gathers leave
    noise that online mode averages away. Progressive rendering gathers online. aim: "solid_angle" picks casters by the solid angle
    they subtend from the light, "equal" gives each the same share (the
    paper). progressive: a fresh photon map every spp_per_map samples per
    pixel, with the radius shrinking as r_i^2 = r_0^2 prod (j + alpha)/(j + 1)
    (progressive photon mapping), so caustics converge instead of keeping a
    fixed blur.
    """

    count: int | None = None
    radius: float = 0.004
    budget: int = 128
    radius_absolute: bool = False
    cone_k: float = 1.1
    max_photons: int = 0
    mode: str = "merge"
    merge_vertices: int = 1 << 20
    merge_probability: float = 1.0
    aim: str = "solid_angle"
    offline_spp: int = 16
    progressive: bool | None = None
    photons_per_sample: float = 0.05
    pilot: bool = True
    min_caustic_share: float = 1e-3
    alpha: float = 0.7
    spp_per_map: int = 8

    def check(self):
        from .scene import SettingsError

        def bad(what):
            raise SettingsError(f"photons: {what}")

        def is_int(v):
            return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))

        def is_num(v):
            return (is_int(v) or isinstance(v, (float, np.floating))) and math.isfinite(v)

        if self.count is not None and (not is_int(self.count) or not 0 <= self.count < 2 ** 31):
            bad(f"count must be an integer from 0 to 2^31 - 1 (got {self.count!r})")
        if not (is_num(self.radius) and 0 < self.radius < 3e38):
            bad(f"radius must be a number > 0 (got {self.radius!r})")
        if not (is_num(self.cone_k) and 1 <= self.cone_k < 3e38):
            bad(f"cone_k must be a number >= 1 (got {self.cone_k!r})")
        if not is_int(self.max_photons) or not 0 <= self.max_photons < 2 ** 32:
            bad(f"max_photons must be an integer from 0 to 2^32 - 1 (got {self.max_photons!r})")
        if not is_int(self.budget) or not 1 <= self.budget < 2 ** 32:
            bad(f"budget must be an integer from 1 to 2^32 - 1 (got {self.budget!r})")
        if self.mode not in MODES:
            bad(f"mode must be one of {', '.join(MODES)} (got {self.mode!r})")
        if not (is_num(self.merge_probability) and 0 < self.merge_probability <= 1):
            bad(f"merge_probability must be in (0, 1] (got {self.merge_probability!r})")
        if not is_int(self.merge_vertices) or not 1 <= self.merge_vertices < 2 ** 31:
            bad(f"merge_vertices must be an integer >= 1 (got {self.merge_vertices!r})")
        if self.aim not in ("solid_angle", "equal"):
            bad(f"aim must be 'solid_angle' or 'equal' (got {self.aim!r})")
        if not (is_num(self.photons_per_sample) and 0 < self.photons_per_sample < 1e6):
            bad(f"photons_per_sample must be > 0 (got {self.photons_per_sample!r})")
        if not isinstance(self.pilot, (bool, np.bool_)):
            bad(f"pilot must be True or False (got {self.pilot!r})")
        for key in ("offline_spp", "spp_per_map"):
            v = getattr(self, key)
            if not is_int(v) or not 1 <= v < 2 ** 32:
                bad(f"{key} must be an integer from 1 to 2^32 - 1 (got {v!r})")
        if not (is_num(self.alpha) and 0 < self.alpha <= 1):
            bad(f"alpha must be in (0, 1] (got {self.alpha!r})")
        if not isinstance(self.radius_absolute, (bool, np.bool_)):
            bad(f"radius_absolute must be True or False (got {self.radius_absolute!r})")
        if self.progressive is not None and not isinstance(self.progressive, (bool, np.bool_)):
            bad(f"progressive must be True, False or None (got {self.progressive!r})")
        return self

    def resolved(self, n_pixels: int) -> "PhotonSettings":
        """The settings with their automatic values filled in: merging is
        progressive unless told otherwise, and a progressive map holds
        photons_per_sample photons per camera sample of its iteration (so that
        tracing photons and building the grid stay a small share of the time,
        whatever the image size); a fixed map holds 10^6 photons."""
        from dataclasses import replace
        progressive = self.mode == "merge" if self.progressive is None else bool(self.progressive)
        count = self.count
        if count is None:
            count = (max(1000, min(2 ** 30, int(self.photons_per_sample * n_pixels * self.spp_per_map)))
                     if progressive else 1_000_000)
        return replace(self, progressive=progressive, count=int(count))

    def check_radius(self, scene_size: float, double: bool = False):
        """The gather radius must be representable: its square above the
        smallest normal number of the kernels' real type (a smaller one finds
        nothing and divides by zero)."""
        from .scene import SettingsError

        r = self.radius_for(scene_size)
        tiny = float(np.finfo(np.float64 if double else np.float32).tiny)
        if not r * r > tiny * 4:
            raise SettingsError(f"photons: radius {r:.3g} is too small for {'double' if double else 'float'} "
                             f"precision (its square underflows); use a radius above {math.sqrt(tiny) * 2:.3g}")

    def radius_for(self, scene_size: float, iteration: int = 0) -> float:
        r = self.radius if self.radius_absolute else self.radius * scene_size
        if self.progressive:
            # r_{i+1}^2 = r_i^2 (i + alpha) / (i + 1), in closed form through lgamma
            # (Knaus and Zwicker, progressive photon mapping).
            log_ratio = (math.lgamma(iteration + self.alpha) - math.lgamma(self.alpha)
                         - math.lgamma(iteration + 1))
            r *= math.exp(0.5 * log_ratio)
        return r


def photon_seed(seed: int, iteration: int) -> int:
    """Seed of the photon map of a progressive iteration (0: the render's seed)."""
    if iteration == 0:
        return seed
    x = (seed * 0x9E3779B1 + iteration * 0x85EBCA77 + 0x165667B1) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x2C1B3C6D) & 0xFFFFFFFF
    return x ^ (x >> 12)


class PhotonMap:
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
        self.launches = {}
        self.kernel_times = {}  # kernel name -> device seconds per launch
        self._events = []
        self.n_stored = 0
        self.n_emitted = 0
        self.radius = 0.0
        self.inv_cell = 1.0
        self.sorted_keys = None

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
            from .device import DeviceError
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
        local = LOCAL_SIZE_CPU if self.dctx.is_cpu else LOCAL_SIZE_GPU
        kernel.set_args(*args)
        ev = cl.enqueue_nd_range_kernel(self.dctx.queue, kernel, (-(-max(1, global_size) // local) * local,), (local,))
        self.launches[name] = self.launches.get(name, 0) + 1
        self._events.append((name, ev))
        return ev

    def _note_times(self):
        for name, ev in self._events:
            note_time(self.kernel_times, name, ev)
        self._events = []

    def build(self, scene_buf, counts, eps_abs, lanes: int, seed: int, settings: PhotonSettings, radius: float):
        """Trace settings.count photons and build the grid for `radius`
        (counts: the packed scene's; eps_abs: the ray-origin offset's floor).
        Returns {"stored", "trace_seconds", "grid_seconds", "host_seconds"}
        (device times from profiling events)."""
        from .engine.launch import RecordBuffer, fill_scene_info, photon_record
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
            events.append(self._launch("trace_photons", self.k_trace, -(-n // lanes), scene_buf,
                                       self.launch.write(rec), *self.raw, self.counter))
        stored = np.zeros(1, dtype=np.uint32)
        cl.enqueue_copy(q, stored, self.counter)
        grid_events = self.build_grid(n, radius)
        self.n_stored = int(stored[0])
        self.n_emitted = n
        self._note_times()
        return {"stored": self.n_stored, "trace_seconds": _device_seconds(events),
                "grid_seconds": _device_seconds(grid_events), "host_seconds": time.perf_counter() - t_host}

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
        self._note_times()
        return {"stored": n, "grid_seconds": _device_seconds(events)}

    def build_grid(self, n: int, radius: float):
        """Sort the n photon slots by bucket and fill bucket_start; returns the events."""
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
        q.finish()
        return events

    def lookup(self, rec, settings: PhotonSettings, mode: int):
        """Fill rec, a PhotonLookup record (clpt/layout.py), for a trace_paths
        launch over this map in mode PM_*: the map's grid, the gather's
        settings, and what the launch does with them (kernels/path.h)."""
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

    def buffers(self) -> dict:
        """trace_paths' photon-map buffers, by argument name (clpt/engine/launch.py PHOTON_ARGS)."""
        return dict(zip(("ph_pos", "ph_dir", "ph_pow"), self.sorted), bucket_start=self.bucket_start, ph_occ=self.occ)


def _device_seconds(events) -> float:
    try:
        return sum(e.profile.end - e.profile.start for e in events) * 1e-9
    except cl.Error:
        return float("nan")


def pilot(renderer, settings: PhotonSettings, *, seed: int) -> tuple[PhotonSettings, dict]:
    """Whether photon merging pays on this scene, from one photon map of the
    render's settings (after Grittmann et al. 2018, lightweight photon
    mapping, which falls back to path tracing where photons bring nothing):
    the share of the lights' power that the stored caustic photons carry
    (light that reaches a diffuse surface through mirrors or glass). Below
    min_caustic_share the caustic paths are too faint to be worth a gather at
    every vertex and the render path traces alone. Deterministic: the same
    seed and scene give the same choice.
    Returns the settings to render with (count 0: path tracing) and what the
    pilot measured."""
    from dataclasses import replace
    st = renderer.states[0]
    info = st.build_photons(photon_seed(seed, 0), settings, settings.radius_for(renderer.packed.size), PM_MERGE)
    pm = st.pmap
    n = pm.capacity
    power = np.zeros((max(n, 1), 4), np.float32)
    if n > 0:
        cl.enqueue_copy(pm.dctx.queue, power, pm.sorted[2])
    share = float(power[:, :3].sum(axis=0, dtype=np.float64).max()) / max(renderer.packed.max_flux, 1e-300)
    use = share >= settings.min_caustic_share
    out = {"choice": "photon merging" if use else "path tracing", "caustic_share": share,
           "stored": info["stored"], "photons": n, "seconds": info["host_seconds"]}
    return (replace(settings, pilot=False) if use else replace(settings, count=0, pilot=False)), out
