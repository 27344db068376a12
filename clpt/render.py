"""Rendering: the public API (Renderer, RenderResult, render, resume) over the
engine (clpt/engine: jobs, schedule, accumulators, executors, driver).

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

import hashlib
import inspect
import math
import time
import weakref
from dataclasses import replace
from pathlib import Path

import numpy as np

from . import tune
from .adaptive import AdaptiveSettings
from .constants import luminance
from .device import DeviceContext, choose_devices
from .engine.checkpoint import Checkpoint
from .engine.device import DeviceWorker, device_features, kernel_source
from .engine.driver import Driver, run_item
from .engine.executors import DaskExecutor, LocalExecutor
from .engine.job import AUX_SPECULAR, DeviceOptions, RenderJob, WorkItem, kernel_photons
from .engine.processes import ProcessExecutor
from .engine.schedule import Schedule
from .errors import CheckpointError, DeviceError, SettingsError
from .features import KERNEL_MODES, SAMPLERS, Experimental, Features
from .loading import load_scene
from .photons import (TRIAL_ROUNDS, TRIAL_SPP, PhotonSettings, path_variance, pilot_choice, relmse_per_sample, trial_size,
                      weigh_cost)
from .preview import RenderUpdate  # noqa: F401 - part of the API
from .result import RenderResult, RenderStats  # noqa: F401 - part of the API
from .scene import Scene


class Renderer:
    """A scene prepared for rendering on one or more devices.

    Kernels are built (or loaded from the build cache) once, here; render()
    can then be called any number of times with different settings.
    photons: None (the default) turns caustic photon mapping on when the scene
    has caustic casters (purely specular objects); False never compiles it.
    bvh: "auto" puts the primitives in a BVH when the scene has at least
    clpt.pack.BVH_MIN_PRIMS of them (plain loops are faster below), "on" or
    "off" force it; bvh_method: "sah" or "lbvh" (clpt/bvh.py). experimental:
    a clpt.features.Experimental, the kernel variants kept for `clpt bench`
    to compare (renders never need one). sampler: "stratified" (the default)
    draws each pixel's camera positions and first-vertex decisions (light
    point, light pick, lobe, direction, Fresnel's choice) from scrambled
    (0,2)-sequences, every power-of-two run of its samples a stratified net;
    "independent" draws every number from the hash (kernels/sampler.h).
    """

    def __init__(self, scene, *, device=None, lanes: int | None = None, local_size: int | None = None,
                 precision: str = "float", kernel: str = "specialized", nee: bool = True,
                 photons: bool | None = None, aux: bool = False, use_cache: bool = True, accumulate: str = "auto",
                 bvh="auto", bvh_method: str = "lbvh", experimental: Experimental | None = None,
                 sampler: str = "stratified"):
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
        if kernel not in KERNEL_MODES:
            raise ValueError(f"kernel must be 'specialized' or 'generic' (got {kernel!r})")
        if sampler not in SAMPLERS:
            raise ValueError(f"sampler must be one of {', '.join(SAMPLERS)} (got {sampler!r})")
        if experimental is not None and not isinstance(experimental, Experimental):
            raise TypeError(f"experimental must be a clpt.features.Experimental (got {type(experimental).__name__})")
        if photons is not None and not isinstance(photons, (bool, PhotonSettings)):
            raise TypeError(f"photons must be None, True, False or a PhotonSettings (got {type(photons).__name__})")
        # A PhotonSettings is render()'s default for this Renderer (and compiles the photon code).
        self.photon_settings = photons.check() if isinstance(photons, PhotonSettings) else None
        if self.photon_settings is not None:
            photons = None
        self.scene = scene
        self._twins = {}
        self.options = DeviceOptions(lanes=lanes, precision=precision, kernel=kernel, nee=nee, sampler=sampler,
                                     photons=photons, aux=aux, use_cache=use_cache, accumulate=accumulate, local_size=local_size,
                                     bvh=bvh, bvh_method=bvh_method)
        self.experimental = (experimental or Experimental()).check()
        t0 = time.perf_counter()
        self.packed = self.options.pack(scene)
        self.pack_seconds = time.perf_counter() - t0
        self._local = self._processes = None
        wants_photons = self.packed.has_caustics and photons is not False
        selection = choose_devices(device, photons=wants_photons, lanes=lanes)
        # What Dask workers select: the name the user gave (a worker's own default if none).
        self._worker_device = device if device is None or isinstance(device, (str, int)) else None
        self.device_choice = selection.why  # render -v
        self.devices = [DeviceContext(d) for d in selection.devices]
        names = [d.label for d in self.devices]
        for i, d in enumerate(self.devices):
            if names.count(names[i]) > 1:  # one device twice, or its sub-devices: told apart in stats
                d.part = f" #{names[:i].count(names[i]) + 1}"
        self.states = []
        for dctx in self.devices:
            if local_size is not None and local_size > dctx.device.max_work_group_size:
                raise DeviceError(f"local size {local_size} is above {dctx.label}'s maximum work-group size "
                                  f"{dctx.device.max_work_group_size}")

            def make(n_lanes, dctx=dctx):
                return DeviceWorker(dctx, self.packed, device_features(dctx, self.packed, self.options, n_lanes,
                                                                       self.experimental),
                                    use_cache)

            f = device_features(dctx, self.packed, self.options, lanes or 1, self.experimental)
            tuning, st = tune.choose(dctx, kernel_source(None, f), f.options(), make, self._trial,
                                     lanes=lanes, local_size=local_size, use_cache=use_cache)
            if st is None:
                st = make(tuning.lanes)
            st.local = tuning.local_size
            st.tuning = tuning
            self.states.append(st)
        self.features = self.states[0].features

    def _trial(self, st, spp: int, seed: int):
        """Render spp samples per pixel of a tune.TRIAL_SIZE square image the
        default way (the photon pilot included) on worker st alone, as a job
        of its own; (samples/s of the passes after the one-sample probe,
        seconds per spp)."""
        n = tune.TRIAL_SIZE
        ex = LocalExecutor([st])
        try:
            job = self._job(st.features, spp, width=n, height=n, seed=seed)
            job = self._pilot(job, ex)[0]
            res = self._run(job, None, None, 0.0, pass_seconds=1e9, executor=ex, workers=[st])
        finally:
            ex.close()
        passes = res.stats.passes[1:] or res.stats.passes
        secs = max(sum(p[3] for p in passes), 1e-9)
        done = sum(p[2] for p in passes)
        return done * n * n / secs, secs / max(done, 1)

    @property
    def build_seconds(self) -> float:
        return sum(s.build.seconds for s in self.states)

    def job(self, spp: int | None = None, *, seed: int | None = None, max_depth: int | None = None,
            rr_depth: int | None = None, width: int | None = None, height: int | None = None,
            photons: PhotonSettings | None = None, adaptive: AdaptiveSettings | None = None,
            filter=None, aux_specular: str = "glass") -> RenderJob:
        """The RenderJob of render()'s settings (checked; the scene's where not given)."""
        return self._job(self.features, spp, seed=seed, max_depth=max_depth, rr_depth=rr_depth, width=width,
                         height=height, photons=photons, adaptive=adaptive, filter=filter, aux_specular=aux_specular)

    def _job(self, features: Features, spp: int | None = None, *, seed: int | None = None,
             max_depth: int | None = None, rr_depth: int | None = None, width: int | None = None,
             height: int | None = None, photons: PhotonSettings | None = None,
             adaptive: AdaptiveSettings | None = None, filter=None, aux_specular: str = "glass") -> RenderJob:
        """job() for workers of the given build."""
        if photons is None:
            photons = self.photon_settings
        elif photons is False:  # path tracing only, with the kernels built for photons
            photons = PhotonSettings(count=0)
        elif not isinstance(photons, PhotonSettings):
            raise SettingsError(f"render: photons must be a PhotonSettings or False (got {photons!r})")
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
                raise SettingsError(f"render: {name} must be an integer >= {lo} (got {v!r})")
        if spp >= 2**32 or seed >= 2**32:
            raise SettingsError("render: spp and seed must be below 2^32")
        pset = (photons or PhotonSettings()).check().resolved(width * height) if features.photons else None
        if pset is not None:
            kernel_photons(pset, self.packed.length_scale).check_radius(self.packed.size, features.double)
        aset = adaptive.check() if adaptive is not None else None
        fset = filter.check() if filter is not None else None
        if aux_specular not in AUX_SPECULAR:
            raise SettingsError(f"render: aux_specular must be one of {', '.join(AUX_SPECULAR)} (got {aux_specular!r})")
        return RenderJob(self.scene, int(spp), int(seed), int(max_depth), int(rr_depth), int(width), int(height),
                         self.options, pset, aset, fset, aux_specular, bool(rs.hide_emitters))

    def render(self, spp: int | None = None, *, seed: int | None = None, max_depth: int | None = None,
               rr_depth: int | None = None, width: int | None = None, height: int | None = None,
               photons: PhotonSettings | None = None, adaptive: AdaptiveSettings | None = None,
               filter=None, aux_specular: str = "glass", progress=None, preview=None,
               time_limit: float | None = None, pass_seconds: float | None = None, executor=None,
               checkpoint=None, checkpoint_every: float | None = None, on_update=None,
               update_interval: float = 0.25, stop=None) -> RenderResult:
        """Render; keywords override the scene's settings.

        spp is the average number of samples per pixel (with adaptive
        sampling, the budget shared among the pixels). progress(done_spp,
        total_spp, elapsed_seconds, samples_per_second) is called after each
        pass; preview(image) every filter.interval passes with the filtered
        image so far; filter: the cone filter (FilterSettings) or OIDN
        (OidnSettings) on the final image; aux_specular: what the feature
        buffers show of mirrors and glass: "glass" (the default; mirrors
        as surfaces, what is seen through glass), "surface" (both as
        surfaces) or "through" (the first non-delta vertex seen through
        both);
        on_update(update) is called between passes, at most every
        update_interval seconds, with a clpt.preview.RenderUpdate (the image
        so far, counts, variances, feature images, statistics), and once at
        the end with update.final True. pass_seconds: how long a pass should
        take (default: the device's tuned choice); time_limit: seconds after
        which no new pass starts (result.time_limited).
        executor: "processes" runs each of this Renderer's devices in a
        process of its own (several PoCL devices in one process share one
        thread pool); a dask.distributed Client (or an executor object) runs
        the passes on a cluster instead. checkpoint: a file that
        holds the render so far, written every checkpoint_every seconds and
        when the render is interrupted; resume() continues it. Ctrl-C
        (KeyboardInterrupt) or stop.set() ends the render early with what is
        done (result.interrupted)."""
        if filter is not None and not self.features.aux:
            # The filters need the feature buffers: a twin of this Renderer with them renders it.
            return self._twin(aux=True).render(
                spp, seed=seed, max_depth=max_depth, rr_depth=rr_depth, width=width, height=height,
                photons=photons if photons is not None else self.photon_settings, adaptive=adaptive,
                filter=filter, aux_specular=aux_specular, progress=progress, preview=preview,
                time_limit=time_limit, pass_seconds=pass_seconds, executor=executor, checkpoint=checkpoint,
                checkpoint_every=checkpoint_every, on_update=on_update, update_interval=update_interval, stop=stop)
        job = self.job(spp, seed=seed, max_depth=max_depth, rr_depth=rr_depth, width=width, height=height,
                       photons=photons, adaptive=adaptive, filter=filter, aux_specular=aux_specular)
        _check_run_options(on_update, update_interval, time_limit, pass_seconds, checkpoint_every)
        job, pilot_info, pilot_seconds = self._pilot(job, self._executor(None))
        if pilot_info is not None and time_limit is not None:
            time_limit = max(time_limit - pilot_seconds, 0.0)  # the pilot is part of the render's time
        runner = self
        if pilot_info is not None and job.photons.count == 0 and executor is None and checkpoint is None:
            # The pilot chose path tracing: a build without the photon map's code renders it. Its
            # image is the photon build's with no photons, bit for bit, at less cost per sample (the
            # photon build's bookkeeping costs 9-14% on the shipped photon scenes with no merge).
            # (A checkpoint or another executor keeps this Renderer's build, so that resume and the
            # workers see the job they were given.)
            runner = self._twin(photons=False)
            job = replace(job, options=runner.options, photons=None)
        if pass_seconds is None:
            pass_seconds = runner.states[0].tuning.pass_seconds
        res = runner._run(job, None, None, 0.0, progress=progress, preview=preview, time_limit=time_limit,
                        pass_seconds=pass_seconds, executor=executor, checkpoint=checkpoint,
                        checkpoint_every=checkpoint_every, on_update=on_update, update_interval=update_interval,
                        stop=stop)
        res.stats.render_seconds += pilot_seconds
        res.stats.photon_pilot = pilot_info
        return res

    def _pilot(self, job: RenderJob, executor) -> tuple[RenderJob, dict | None, float]:
        """(the job to render, what the photon pilot measured, its seconds):
        where the job's photon settings ask for the pilot, a job of their own
        builds one photon map on the executor's first worker and the pilot
        chooses between photon merging and path tracing from it
        (photons.pilot_choice); else the job as it is."""
        pset = job.photons
        if not (pset is not None and pset.pilot and pset.mode == "merge" and pset.count > 0):
            return job, None, 0.0
        t0 = time.perf_counter()
        res = run_item(executor, job, WorkItem("photons", iteration=0))
        pm = res.photon_maps[0]
        pset, info = pilot_choice(pset, pm["power"], self.packed.max_flux, pm["stored"], pm["host_seconds"])
        if pset.count > 0 and pset.pilot_trial:
            pset, info = self._pilot_trial(job, pset, info, executor)
        return replace(job, photons=pset), info, time.perf_counter() - t0

    def _pilot_trial(self, job: RenderJob, pset: PhotonSettings, info: dict, executor):
        """The pilot's weighing of cost against gain (photons.weigh_cost): the
        job at a small resolution and few samples per pixel, with photon
        merging and with path tracing alone on the same build, in
        TRIAL_ROUNDS alternating rounds of their own seeds; each technique's
        variance is the rounds' mean, its cost the fastest round's kernel
        device seconds per sample (photon maps included: on a machine shared
        with other work, the least disturbed round is the closest to the
        cost)."""
        w, h = trial_size(job.width, job.height)
        small = replace(job, spp=min(TRIAL_SPP, job.spp), width=w, height=h, filter=None)
        techniques = (("path", replace(pset, count=0)), ("merge", pset))
        images, variances, seconds = ({k: [] for k, _ in techniques} for _ in range(3))
        for i in range(TRIAL_ROUNDS):
            for name, ps in techniques:
                r = self._run(replace(small, photons=ps, seed=(job.seed + i) % 2**32), None, None, 0.0,
                              executor=executor)
                images[name].append(luminance(r.image))
                variances[name].append(r.lum_var)
                seconds[name].append(sum(sum(v) for v in r.stats.kernel_seconds.values()) / max(r.samples, 1))
        trials = {k: (np.mean(images[k], axis=0), np.mean(variances[k], axis=0)) for k in images}
        seconds = {k: min(v) for k, v in seconds.items()}
        # Path tracing's error on the paths merging takes: its own trial rarely meets them (a small
        # light through glass), so it is estimated from the merges instead (kernels/photon_grid.h),
        # by a build with feature buffers. Path tracing's variance is then at least merging's on
        # the other paths plus that second moment (photons.path_variance).
        twin = self._twin(aux=True)
        m = twin._run(replace(small, options=twin.options, photons=pset, moments=True), None, None, 0.0)
        trials["path"] = (trials["path"][0], path_variance(trials["path"][1], trials["merge"][1],
                                                           m.aux["caustic_sq"]))
        info = dict(info, path_moment=float(np.mean(m.aux["caustic_sq"])))
        # The costs of a trial are measured once per device and trial and then
        # taken from the cache, so a render's choice is reproducible from its seed.
        key = hashlib.sha256(repr(([s.dctx.identity() for s in self.states], small.key,
                                   TRIAL_ROUNDS)).encode()).hexdigest()[:32]
        cached = tune.load_measured("pilot", key) if self.options.use_cache else None
        if cached is not None and set(cached.get("seconds_per_sample", ())) == {"path", "merge"}:
            seconds = {k: float(v) for k, v in cached["seconds_per_sample"].items()}
        elif self.options.use_cache:
            tune.save_measured("pilot", key, {"seconds_per_sample": seconds, "trial": [w, h, small.spp]})
        return weigh_cost(pset, info, job.n_pix, relmse_per_sample(trials), seconds)

    def resume(self, checkpoint, *, out_checkpoint=None, **kw) -> RenderResult:
        """Continue the render saved in `checkpoint` (of this Renderer's scene
        and options) to its end; keywords as for render() (progress, executor,
        time_limit, checkpoint_every, ...). The checkpoint goes on being
        updated (or out_checkpoint, if given). On the device that wrote it, the
        image is bit-identical to that of the uninterrupted render."""
        ck = checkpoint if isinstance(checkpoint, Checkpoint) else Checkpoint(checkpoint)
        _check_run_options(kw.get("on_update"), kw.get("update_interval", 0.25), kw.get("time_limit"),
                           kw.get("pass_seconds"), kw.get("checkpoint_every"))
        job = ck.job
        ck.check_against(RenderJob(self.scene, job.spp, job.seed, job.max_depth, job.rr_depth, job.width,
                                   job.height, self.options, job.photons, job.adaptive, job.filter,
                                   job.aux_specular, job.hide_emitters))
        job = replace(job, scene=self.scene)
        return self._run(job, Schedule.from_state(job, ck.schedule), ck.sums, float(ck.meta.get("elapsed", 0.0)),
                         checkpoint=out_checkpoint or ck.path, **kw)

    def _twin(self, **changes) -> "Renderer":
        """This Renderer with other build options (built once, then kept)."""
        key = tuple(sorted(changes.items()))
        if key not in self._twins:
            kw = {**self.options.renderer_kwargs(), **changes}
            if kw.get("photons") is None and self.photon_settings is not None:
                kw["photons"] = self.photon_settings
            twin = Renderer(self.scene, device=[d.device for d in self.devices], use_cache=self.options.use_cache,
                            experimental=self.experimental, **kw)
            twin._worker_device = self._worker_device
            self._twins[key] = twin
        return self._twins[key]

    def _executor(self, executor):
        if executor is None:
            if self._local is None:
                self._local = LocalExecutor(self.states)
                weakref.finalize(self, self._local.close)  # its threads end with the Renderer
            self._local.live = set(range(len(self.states)))
            return self._local
        if executor == "processes":  # each device in a process of its own, kept for the next render
            if self._processes is None:
                self._processes = ProcessExecutor([d.device for d in self.devices])
                weakref.finalize(self, self._processes.close)
            self._processes.live = set(range(len(self._processes.children)))
            return self._processes
        if isinstance(executor, str):
            raise SettingsError(f"render: executor must be None, 'processes', a dask.distributed Client or an "
                                f"executor object (got {executor!r})")
        if hasattr(executor, "scheduler_info") and hasattr(executor, "submit"):  # a distributed.Client
            return DaskExecutor(executor, device=getattr(self, "_worker_device", None))
        return executor

    def _run(self, job, schedule, initial, elapsed_before, *, progress=None, preview=None, time_limit=None,
             pass_seconds=None, executor=None, checkpoint=None, checkpoint_every=None, on_update=None,
             update_interval=0.25, stop=None, workers=None):
        """Render job on the executor; workers: the local workers whose build
        it renders with (default: this Renderer's)."""
        workers = self.states if workers is None else workers
        features = workers[0].features
        if pass_seconds is None:
            pass_seconds = workers[0].tuning.pass_seconds
        stats = RenderStats(build_seconds=sum(s.build.seconds for s in workers),
                            cache_hits=sum(s.build.cache_hit for s in workers))
        ex = self._executor(executor)
        empty = workers[0].empty_sums
        if initial is not None:
            try:
                initial = initial.with_layout(empty(job))  # fp64 sums onto a Kahan device, or back
            except ValueError as e:
                raise CheckpointError(f"the checkpoint's sums do not fit this render: {e}") from None
        drv = Driver(job, ex, stats=stats, lum_scale=self.packed.lum_scale, length_scale=self.packed.length_scale,
                     lanes=features.lanes,
                     schedule=schedule, initial=initial, empty=lambda: empty(job), pass_seconds=pass_seconds,
                     time_limit=time_limit, progress=progress, preview=preview, on_update=on_update,
                     update_interval=update_interval, checkpoint=checkpoint, checkpoint_every=checkpoint_every,
                     stop=stop, elapsed_before=elapsed_before, describe=features.describe())
        interrupted = drv.run()
        sums = drv.total()
        if interrupted:
            drv.write_checkpoint(sums, wait=True)
        stats.render_seconds = drv.elapsed()
        stats.failures = drv.failures
        stats.checkpoints = drv.checkpoints
        res = sums.finish(job.width, job.height, self.packed.lum_scale, self.packed.length_scale, seed=job.seed,
                          max_depth=job.max_depth, rr_depth=job.rr_depth, devices=list(ex.labels),
                          features=features, stats=stats, photons=job.photons, adaptive=job.adaptive,
                          interrupted=interrupted, scene_source=self.scene.source, scene_sha256=self.scene.sha256)
        # Stopped by the time limit, not by a signal (adaptive: not by convergence either).
        if time_limit is not None and not interrupted:
            budget = job.spp * job.n_pix
            if job.adaptive is None:
                res.time_limited = res.samples < budget
            else:
                res.time_limited = res.samples < budget and drv.elapsed() >= time_limit
        if job.filter is not None and res.aux is not None:
            res.filtered = drv._filtered(res.image, res.lum_var, res.sample_count, res.caustic_image, res.aux)
        if on_update is not None:
            drv._update(True, filtered=res.filtered, res=res)
        return res


def _check_run_options(on_update, update_interval, time_limit, pass_seconds, checkpoint_every):
    if on_update is not None and not callable(on_update):
        raise TypeError(f"render: on_update must be callable (got {type(on_update).__name__})")
    if isinstance(update_interval, bool) or not isinstance(update_interval, (int, float)) \
            or not update_interval >= 0 or update_interval == float("inf"):
        raise ValueError(f"render: update_interval must be a number of seconds >= 0 (got {update_interval!r})")
    for name, v in (("time_limit", time_limit), ("pass_seconds", pass_seconds),
                    ("checkpoint_every", checkpoint_every)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating))
                              or not (math.isfinite(v) and v > 0)):
            raise SettingsError(f"render: {name} must be a finite number of seconds > 0 (got {v!r})")


def render(scene, *, spp: int | None = None, device=None, **kw) -> np.ndarray:
    """Render a scene (a Scene, a path, or a shipped scene's name) and return
    linear RGB as a float32 H x W x 3 array: clpt.render("cornell_box",
    spp=64). Every other keyword is Renderer's (device, lanes, precision,
    photons, ...) or Renderer.render's (seed, width, height, adaptive,
    filter, time_limit, ...), each with the same name and meaning there."""
    own = set(inspect.signature(Renderer.__init__).parameters) - {"self", "scene"}
    runs = set(inspect.signature(Renderer.render).parameters) - {"self", "spp"}
    unknown = set(kw) - own - runs
    if unknown:
        raise TypeError(f"render() got unexpected keyword arguments: {', '.join(sorted(unknown))}")
    r = Renderer(scene, device=device, **{k: v for k, v in kw.items() if k in own})
    return r.render(spp, **{k: v for k, v in kw.items() if k in runs}).image


def resume(checkpoint, *, device=None, use_cache: bool = True, **kw) -> RenderResult:
    """Continue a checkpointed render (its scene and options are in the
    checkpoint) to the end; keywords as for Renderer.resume."""
    ck = Checkpoint(checkpoint)
    r = Renderer(ck.job.scene, device=device, use_cache=use_cache, **ck.job.options.renderer_kwargs())
    return r.resume(ck, **kw)
