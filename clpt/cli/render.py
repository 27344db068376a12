"""`clpt render`: a scene to an image file, with progress, checkpoints,
interrupts (the image so far and a checkpoint to continue from), denoising,
adaptive sampling, tev streaming and clusters (processes or Dask)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from . import common
from .common import load as _load, warn as _warn


def add_parser(sub):
    p = sub.add_parser("render", help="render a scene to an image file")
    p.add_argument("scene", nargs="?", default=None, help="scene file, or a shipped scene's name "
                                                         "(default: cornell_box, or the checkpoint's with --resume)")
    common.output(p)
    common.spp(p, help="samples per pixel (default: the scene's)")
    common.size(p)
    common.max_depth(p, help="most scattering events per path (0: emitters only)")
    p.add_argument("--rr-depth", type=int, help="depth from which Russian roulette may absorb paths")
    common.seed(p)
    p.add_argument("--exposure", type=float, default=0.0, help="exposure in stops for 8-bit images")
    p.add_argument("--time-limit", type=float, help="stop after about this many seconds")
    p.add_argument("-v", "--verbose", action="store_true", help="report device, kernel features, build and rays")
    p.add_argument("-q", "--quiet", action="store_true")
    p.add_argument("--progress", action="store_true", help="show progress even when not on a terminal")
    p.add_argument("--tev", nargs="?", const="127.0.0.1:14158", default=None, type=_tev_address,
                   metavar="HOST:PORT", help="stream the image as it renders to the tev viewer listening there "
                                             "(default 127.0.0.1:14158; needs pip install 'clpt[tev]')")
    g = p.add_argument_group("checkpoints and clusters")
    g.add_argument("--checkpoint", metavar="FILE", help="where the render so far is kept (default <output>.ckpt); "
                                                        "removed when the image is written complete")
    g.add_argument("--checkpoint-every", type=float, default=None, metavar="SECONDS",
                   help="write the checkpoint this often (default 60; 0: only when interrupted)")
    g.add_argument("--resume", metavar="CHECKPOINT", help="continue a checkpointed render (its scene and settings "
                                                          "are in the checkpoint); -o as before by default")
    g.add_argument("--processes", action="store_true",
                   help="run each device (--device all, or a list) in a process of its own: PoCL's devices in "
                        "one process share one thread pool")
    g.add_argument("--dask", metavar="ADDRESS", help="render on a Dask cluster: a scheduler address, or local:N "
                                                     "for N local worker processes (pip install 'clpt[dask]')")
    _add_render_options(p)
    _add_photon_options(p)
    _add_quality_options(p)
    common.scene_params(p)
    p.set_defaults(func=run)
    return p


def _tev_address(text):
    from ..tev import parse_address

    try:
        parse_address(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def _progress_printer(stream, enabled: bool):
    """A one-line progress bar with samples/s and ETA, redrawn in place; and
    note(message), a warning line that does not run into the bar."""
    state = {"last": 0.0, "drawn": False}

    def show(done, total, elapsed, rate):
        now = time.perf_counter()
        if not enabled or (now - state["last"] < 0.1 and done < total):
            return
        state["last"] = now
        state["drawn"] = True
        frac = done / total if total else 1.0
        bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
        eta = elapsed / frac - elapsed if frac > 0 else 0.0
        stream.write(f"\r[{bar}] {done}/{total} spp  {rate / 1e6:6.2f} Msamples/s  "
                     f"elapsed {elapsed:5.1f}s  ETA {eta:5.1f}s ")
        stream.flush()

    def end():
        if enabled:
            stream.write("\n")
            stream.flush()

    def note(message):
        stream.write(("\n" if state["drawn"] else "") + f"clpt: warning: {message}\n")
        stream.flush()
        state["drawn"] = False

    show.note = note
    return show, end


def _add_render_options(p):
    common.device(p, help=common.DEVICE_HELP)
    p.add_argument("--lanes", type=int, default=None, choices=(1, 2, 4, 8, 16),
                   help="paths per work-item (default: tuned per device; see `clpt devices -v`)")
    p.add_argument("--local-size", type=int, default=None, help="work-group size (default: tuned per device)")
    p.add_argument("--precision", choices=("float", "double"), default=None,
                   help=f"real type of the kernels (default {_renderer_default('precision')})")
    p.add_argument("--kernel", choices=("specialized", "generic"), default=None,
                   help="kernel build: only the scene's features (specialized) or everything (generic) "
                        f"(default {_renderer_default('kernel')})")
    common.no_nee(p, help="no next event estimation (pure path tracing)")
    common.sampler(p)
    p.add_argument("--no-cache", action="store_true", help="do not use the kernel build cache")


def _add_photon_options(p):
    from ..options import PHOTON_OPTIONS, add_options
    from ..photons import PhotonSettings

    add_options(p.add_argument_group("caustic photons (scenes with mirror or glass objects)"), PhotonSettings,
                PHOTON_OPTIONS)


def _add_quality_options(p):
    from ..adaptive import AdaptiveSettings
    from ..denoise import FilterSettings, OidnSettings
    from ..engine.job import AUX_SPECULAR
    from ..options import ADAPTIVE_OPTIONS, CONE_FILTER_OPTIONS, DENOISER_OPTIONS, OIDN_OPTIONS, add_options

    g = p.add_argument_group("adaptive sampling")
    g.add_argument("--adaptive", choices=("error", "paper"), default=None,
                   help="spend the samples (--spp on average) where the error is: by each pixel's relative "
                        "error (error) or by disagreement with its neighbours (paper)")
    add_options(g, AdaptiveSettings, ADAPTIVE_OPTIONS)
    g.add_argument("--save-sample-map", metavar="FILE", help="write a heat map of samples per pixel")
    g = p.add_argument_group("denoising", DENOISE_HELP)
    g.add_argument("--denoise", choices=("cone", "oidn"), default=None,
                   help="write the denoised image (and the raw one as <out>.unfiltered<ext>): the edge-aware "
                        "cone filter, or Intel Open Image Denoise (pip install 'clpt[oidn]')")
    g.add_argument("--filter", action="store_true", help="the same as --denoise cone")
    add_options(g, OidnSettings, OIDN_OPTIONS)
    g.add_argument("--aux-specular", choices=AUX_SPECULAR, default=None,
                   help="feature buffers of mirrors and glass: mirrors as surfaces and what is seen through "
                        "glass (glass, the default), both as surfaces, or what is seen through both")
    add_options(g, FilterSettings, CONE_FILTER_OPTIONS + DENOISER_OPTIONS)
    g.add_argument("--write-aux", action="store_true",
                   help="write the feature buffers: <out>.normal.exr, .albedo.exr, .depth.exr, .variance.exr")


def _adaptive_settings(a):
    from ..adaptive import AdaptiveSettings
    from ..options import ADAPTIVE_OPTIONS, settings_kwargs

    if a.adaptive is None:
        return None
    return AdaptiveSettings(scheme=a.adaptive, **settings_kwargs(a, ADAPTIVE_OPTIONS)).check()


DENOISE_HELP = (
    "Measured with clpt bench-denoise (128x128, 16 and 64 spp, against path-traced references): OIDN has less "
    "error than the cone filter in every case (1.1-1.3x with cleaned albedo+normal, the default of --denoise "
    "oidn) and keeps caustics within 2%, but costs 45-118% of a 16-spp render's CPU time at 512x512 with "
    "cleaned guides (10-28% with --oidn-aux noisy or none). The cone filter (--denoise cone) costs 3-5%, needs "
    "no extra package and leaves the photon map's concentrated caustics as rendered: use it for previews "
    "(--filter-interval) and quick renders, OIDN for final images.")


def _filter_settings(a):
    from ..denoise import FilterSettings, OidnSettings
    from ..options import CONE_FILTER_OPTIONS, DENOISER_OPTIONS, OIDN_OPTIONS, given, settings_kwargs
    from ..scene import SettingsError

    kind = a.denoise or ("cone" if a.filter else None)
    if a.filter and a.denoise == "oidn":
        raise SettingsError("--filter is the cone filter; use either it or --denoise oidn")
    if kind is None:
        return None
    mine, others = ((OIDN_OPTIONS, CONE_FILTER_OPTIONS) if kind == "oidn" else (CONE_FILTER_OPTIONS, OIDN_OPTIONS))
    wrong = given(a, others)
    if wrong:
        raise SettingsError(f"{', '.join(o.flag for o in wrong)}: not options of --denoise {kind}")
    cls = OidnSettings if kind == "oidn" else FilterSettings
    return cls(**settings_kwargs(a, mine + DENOISER_OPTIONS)).check()


def _sibling(path: Path, tag: str, ext: str | None = None) -> Path:
    return path.with_name(f"{path.stem}.{tag}{ext or path.suffix}")


def _photon_settings(a):
    from ..options import PHOTON_OPTIONS, settings_kwargs
    from ..photons import PhotonSettings

    return PhotonSettings(**settings_kwargs(a, PHOTON_OPTIONS)).check()


def _renderer_default(name: str):
    """A build option's default, as clpt.engine.job.DeviceOptions has it (the CLI does not restate it)."""
    from ..engine.job import DeviceOptions
    from ..options import field_default
    return field_default(DeviceOptions, name)


def _renderer_kwargs(a):
    kw = dict(device=a.device, lanes=a.lanes, local_size=a.local_size, nee=not a.no_nee, use_cache=not a.no_cache)
    kw.update({k: getattr(a, k) for k in ("precision", "kernel", "sampler") if getattr(a, k, None) is not None})
    if getattr(a, "photons", None) == 0:
        kw["photons"] = False
    return kw


def _dask_client(spec: str):
    """A distributed.Client for --dask: a scheduler's address, or local:N worker processes."""
    from ..scene import SceneError

    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise SceneError("--dask needs Dask: pip install 'clpt[dask]'") from None
    if spec.startswith("local:"):
        n = spec[6:]
        if not n.isdigit() or int(n) < 1:
            raise SceneError(f"--dask local:N needs a number of workers >= 1 (got {spec!r})")
        cluster = LocalCluster(n_workers=int(n), threads_per_worker=1, processes=True, dashboard_address=":0")
        return Client(cluster)
    return Client(spec)


SIGNAL_EXIT = {2: 130, 15: 143, 1: 129}  # SIGINT, SIGTERM, SIGHUP: 128 + the signal
DASK_PASS_SECONDS = 2.0  # a range's raw sums travel back whole: ranges of seconds keep that a small share
PROCESS_PASS_SECONDS = 0.5  # the same, between processes of one machine
CHECKPOINT_EVERY = 60.0  # seconds, --checkpoint-every's default


def run(a) -> int:
    import threading

    from .. import preflight
    from ..engine.checkpoint import Checkpoint
    from ..engine.driver import interrupt_signals
    from ..render import Renderer
    from ..scene import SceneError

    # Everything that can be checked is checked before the first sample.
    preflight.check_render_options(a)
    if a.checkpoint_every is not None and not (a.checkpoint_every >= 0 and a.checkpoint_every != float("inf")):
        raise SceneError(f"--checkpoint-every must be a number of seconds >= 0 (got {a.checkpoint_every})")
    ck = Checkpoint(a.resume) if a.resume else None
    if ck is not None:
        scene = ck.job.scene if a.scene is None else _load(a)
        default_out = Path(a.resume).with_suffix("") if a.resume.endswith(".ckpt") else \
            Path(Path(ck.job.scene.source or "render").stem + ".png")
    else:
        a.scene = a.scene or "cornell_box"
        scene = _load(a)
        default_out = Path(Path(a.scene).stem + ".png")
    preflight.check_scene_memory(scene)
    out = preflight.check_output(a.output if a.output is not None else str(default_out))
    ckpt = Path(a.checkpoint) if a.checkpoint else (Path(a.resume) if a.resume else Path(f"{out}.ckpt"))
    if a.checkpoint:  # written during the render: its folder is tried now, as the output's was
        preflight.check_folder(ckpt.parent, "--checkpoint", a.checkpoint)
    if a.save_sample_map is not None:
        preflight.check_output(a.save_sample_map, "--save-sample-map")
    job0 = ck.job if ck is not None else None
    width = job0.width if job0 else (a.width or scene.camera.width)
    height = job0.height if job0 else (a.height or scene.camera.height)
    preflight.check_image_size(out, width, height)
    if a.save_sample_map is not None:
        preflight.check_image_size(a.save_sample_map, width, height, "--save-sample-map")
    show, end = _progress_printer(sys.stderr, not a.quiet and (a.progress or sys.stderr.isatty()))
    viewer, update_interval = None, 0.25
    if a.tev is not None:
        from ..tev import UPDATE_INTERVAL, TevViewer

        update_interval = UPDATE_INTERVAL
        seed = job0.seed if job0 else (scene.render.seed if a.seed is None else a.seed)
        try:
            viewer = TevViewer(f"{Path(scene.source or 'render').stem} seed {seed}", a.tev, warn=show.note)
        except ImportError as e:
            print(f"clpt: error: {e}", file=sys.stderr)
            return 2
    if ck is not None:
        r = Renderer(scene, device=a.device, use_cache=not a.no_cache, **ck.job.options.renderer_kwargs())
        photons, adaptive, filt = job0.photons, job0.adaptive, job0.filter
    else:
        photons = _photon_settings(a) if a.photons != 0 else None
        adaptive = _adaptive_settings(a)
        filt = _filter_settings(a)
        r = Renderer(scene, aux=filt is not None or a.write_aux, **_renderer_kwargs(a))
    if viewer is not None:
        viewer.cpu_device = any(st.dctx.is_cpu for st in r.states)
    if ck is None:
        preflight.warn_unused_options(a, r.packed.has_caustics, _warn)
    preflight.check_memory(width, height, aux=r.features.aux, adaptive=adaptive is not None,
                           photons=photons.resolved(width * height).count if photons and r.features.photons else 0,
                           cpu_device=all(st.dctx.is_cpu for st in r.states),
                           resources=preflight.scene_resource_bytes(scene))
    if a.verbose:
        print(f"devices: {r.device_choice}", file=sys.stderr)
        for st in r.states:
            b = st.build
            print(f"device: {st.dctx.label}", file=sys.stderr)
            print(f"kernel: {st.features.describe()}", file=sys.stderr)
            print(f"tuning: {st.tuning.describe()}", file=sys.stderr)
            print(f"build: {b.seconds:.3f}s ({'cache hit' if b.cache_hit else 'compiled'}, key {b.key})",
                  file=sys.stderr)
    from ..image import save_image

    preview = None
    if filt is not None and filt.interval:
        def preview(img):
            from ..image import ImageError
            try:
                save_image(out, img, exposure=a.exposure)
            except (ImageError, OSError) as e:  # a preview is not worth the render
                _warn(f"cannot write the preview: {e}")
    client = _dask_client(a.dask) if a.dask else ("processes" if a.processes else None)
    stop = threading.Event()
    every = CHECKPOINT_EVERY if a.checkpoint_every is None else a.checkpoint_every
    run = dict(progress=show, preview=preview, time_limit=a.time_limit, executor=client, checkpoint=ckpt,
               checkpoint_every=every or None, stop=stop, on_update=viewer, update_interval=update_interval)
    if client is not None:  # raw sums travel back per range
        run["pass_seconds"] = DASK_PASS_SECONDS if a.dask else PROCESS_PASS_SECONDS
    # From here on a signal (Ctrl-C, SIGTERM, SIGHUP) ends the render with a
    # checkpoint and the image so far; a second one cannot cut the writing of
    # either short.
    with interrupt_signals(stop) as got:
        try:
            if ck is not None:
                run.pop("checkpoint")
                res = r.resume(ck, out_checkpoint=ckpt, **run)
            else:
                res = r.render(a.spp, seed=a.seed, max_depth=a.max_depth, rr_depth=a.rr_depth, width=a.width,
                               height=a.height, photons=photons, adaptive=adaptive, filter=filt,
                               aux_specular=a.aux_specular or "glass", **run)
        finally:
            if client is not None and client != "processes":
                client.close()
            if viewer is not None:
                viewer.close()
        end()
        if viewer is not None and a.verbose and viewer.updates:
            print(viewer.summary(), file=sys.stderr)
        code = SIGNAL_EXIT.get(got["signal"], 130) if res.interrupted else 0
        if res.samples == 0:  # stopped before the first sample: leave any existing output alone
            print(f"clpt: interrupted before the first sample; {out} was not written", file=sys.stderr)
            return code or 130
        fallback = _write_outputs(a, res, out)
        if not res.interrupted and fallback is None:
            ckpt.unlink(missing_ok=True)  # the image holds it all now
        _report(a, res, out, fallback)
        if res.interrupted:
            print(f"interrupted after {res.spp} spp; the image so far was written to {fallback or out} and the "
                  f"render can be continued with: clpt render --resume {ckpt}", file=sys.stderr)
            return code
        return 1 if fallback is not None else 0


def _write_outputs(a, res, out):
    from .. import preflight
    from ..image import save_image

    meta = res.metadata(a.exposure)
    if res.filtered is not None:
        meta = {**meta, "clpt:filtered": 1}
        fallback = preflight.save_with_fallback(
            lambda p: save_image(p, res.filtered, metadata=meta, exposure=a.exposure), out, res.filtered, meta, _warn)
        preflight.save_with_fallback(lambda p: res.save(p, exposure=a.exposure), _sibling(out, "unfiltered"),
                                     res.image, res.metadata(a.exposure), _warn)
    else:
        fallback = preflight.save_with_fallback(lambda p: res.save(p, exposure=a.exposure), out, res.image, meta,
                                                _warn)
    if a.write_aux and res.aux is not None:
        save_image(_sibling(out, "normal", ".exr"), res.aux["normal"])
        save_image(_sibling(out, "albedo", ".exr"), res.aux["albedo"])
        save_image(_sibling(out, "depth", ".exr"), res.aux["depth"])
        save_image(_sibling(out, "variance", ".exr"), res.lum_var / res.sample_count.clip(1))
    if a.save_sample_map:
        from ..adaptive import sample_map_image
        save_image(a.save_sample_map, sample_map_image(res.sample_count),
                   metadata={"clpt:max_spp": int(res.sample_count.max()), "clpt:min_spp": int(res.sample_count.min())})
    return fallback


def _report(a, res, out, fallback):
    st = res.stats
    secs = max(st.render_seconds, 1e-9)
    spp_text = (f"{res.sample_count.mean():.1f} spp on average" if res.stats.adaptive_rounds else f"{res.spp} spp")
    msg = (f"wrote {fallback or out}: {res.image.shape[1]}x{res.image.shape[0]}, {spp_text}, "
           f"{st.render_seconds:.2f}s, {res.samples / secs / 1e6:.2f} Msamples/s")
    if st.nonfinite:
        msg += f", {st.nonfinite} non-finite samples dropped"
    if not a.quiet:
        print(msg, file=sys.stderr)
    for label, err in st.failures:
        print(f"clpt: warning: {label} failed mid-render ({err}); the others finished its work", file=sys.stderr)
    if a.verbose:
        print(f"rays: {st.camera_rays} camera, {st.bounce_rays} bounce, {st.shadow_rays} shadow "
              f"({st.rays / secs / 1e6:.2f} Mrays/s); first launch {st.first_launch_seconds:.3f}s", file=sys.stderr)
        if st.photon_pilot is not None:
            pl = st.photon_pilot
            print(f"photon pilot: {pl['choice']} (caustic photons carry {pl['caustic_share']:.2%} of the "
                  f"lights' power; {pl['stored']} of {pl['photons']} photons stored)", file=sys.stderr)
            if "predicted_relmse_1s" in pl:
                e, c = pl["predicted_relmse_1s"], pl["seconds_per_sample"]
                print(f"photon pilot: predicted relMSE after 1 s: merging {e['merge']:.3g} "
                      f"({c['merge'] * 1e6:.3g} us/sample), path tracing {e['path']:.3g} "
                      f"({c['path'] * 1e6:.3g} us/sample); merging {pl['predicted_gain']:.3g}x", file=sys.stderr)
        for m in st.photon_maps[:3]:
            print(f"photon map: {m['stored']} of {res.photons.count} photons stored, radius {m['radius']:.4g}, "
                  f"trace {m['trace_seconds'] * 1e3:.1f} ms, grid {m['grid_seconds'] * 1e3:.1f} ms", file=sys.stderr)
        if len(st.photon_maps) > 3:
            print(f"photon maps: {len(st.photon_maps)} in all", file=sys.stderr)
        if st.checkpoints:
            stall, write = sum(c[0] for c in st.checkpoints), sum(c[1] for c in st.checkpoints)
            print(f"checkpoints: {len(st.checkpoints)}, the render waited {stall:.3f}s for them, writing took "
                  f"{write:.3f}s in the background, {st.checkpoints[-1][2] / 1e6:.1f} MB", file=sys.stderr)
    if res.stats.adaptive_rounds and not a.quiet:
        print(f"adaptive: {res.stats.adaptive_rounds} rounds, {res.sample_count.min()} to {res.sample_count.max()} "
              f"samples per pixel", file=sys.stderr)
