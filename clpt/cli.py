"""The clpt command line: render, bench, devices, scenes, check, cache.

Exit codes: 0 done, 1 a device or kernel-build failure, 2 a mistake in the
command or the scene (reported in one line, never a traceback), 130
interrupted by Ctrl-C, 143 by SIGTERM, 129 by SIGHUP (a render still writes
the image it has so far, and a checkpoint to continue it from).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

from . import __version__


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


def _tev_address(text):
    from .tev import parse_address

    try:
        parse_address(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def _add_render_options(p):
    p.add_argument("--device", "-d", default=None, help="device index, platform:device, name substring, "
                                                        "'all', or a comma list (default: PYOPENCL_CTX, a GPU, "
                                                        "else the CPU runtime measured fastest for the scene "
                                                        "that renders here; see clpt devices -v)")
    p.add_argument("--lanes", type=int, default=None, choices=(1, 2, 4, 8, 16),
                   help="paths per work-item (default: tuned per device; see `clpt devices -v`)")
    p.add_argument("--local-size", type=int, default=None, help="work-group size (default: tuned per device)")
    p.add_argument("--precision", choices=("float", "double"), default=None,
                   help=f"real type of the kernels (default {_renderer_default('precision')})")
    p.add_argument("--kernel", choices=("specialized", "generic"), default=None,
                   help="kernel build: only the scene's features (specialized) or everything (generic) "
                        f"(default {_renderer_default('kernel')})")
    p.add_argument("--no-nee", action="store_true", help="no next event estimation (pure path tracing)")
    p.add_argument("--no-cache", action="store_true", help="do not use the kernel build cache")


def _add_photon_options(p):
    from .options import PHOTON_OPTIONS, add_options
    from .photons import PhotonSettings

    add_options(p.add_argument_group("caustic photons (scenes with mirror or glass objects)"), PhotonSettings,
                PHOTON_OPTIONS)


def _add_quality_options(p):
    from .adaptive import AdaptiveSettings
    from .denoise import FilterSettings, OidnSettings
    from .options import ADAPTIVE_OPTIONS, CONE_FILTER_OPTIONS, DENOISER_OPTIONS, OIDN_OPTIONS, add_options

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
    g.add_argument("--aux-specular", choices=("surface", "through"), default=None,
                   help="feature buffers of mirrors and glass: the surface itself (default) or what is seen "
                        "through it")
    add_options(g, FilterSettings, CONE_FILTER_OPTIONS + DENOISER_OPTIONS)
    g.add_argument("--write-aux", action="store_true",
                   help="write the feature buffers: <out>.normal.exr, .albedo.exr, .depth.exr, .variance.exr")


def _adaptive_settings(a):
    from .adaptive import AdaptiveSettings
    from .options import ADAPTIVE_OPTIONS, settings_kwargs

    if a.adaptive is None:
        return None
    return AdaptiveSettings(scheme=a.adaptive, **settings_kwargs(a, ADAPTIVE_OPTIONS)).check()


DENOISE_HELP = (
    "Measured with clpt bench-denoise (128x128, 16 and 64 spp, against path-traced references): OIDN has less "
    "error than the cone filter in every case (1.3-1.6x with cleaned albedo+normal, the default of --denoise "
    "oidn) and keeps caustics within 2%, but costs 45-118% of a 16-spp render's CPU time at 512x512 with "
    "cleaned guides (10-28% with --oidn-aux noisy or none). The cone filter (--denoise cone) costs 3-5%, needs "
    "no extra package and leaves the photon map's caustics as rendered: use it for previews "
    "(--filter-interval) and quick renders, OIDN for final images.")


def _filter_settings(a):
    from .denoise import FilterSettings, OidnSettings
    from .options import CONE_FILTER_OPTIONS, DENOISER_OPTIONS, OIDN_OPTIONS, given, settings_kwargs
    from .scene import SettingsError

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
    from .options import PHOTON_OPTIONS, settings_kwargs
    from .photons import PhotonSettings

    return PhotonSettings(**settings_kwargs(a, PHOTON_OPTIONS)).check()


def _renderer_default(name: str):
    """A build option's default, as clpt.engine.job.DeviceOptions has it (the CLI does not restate it)."""
    from .engine.job import DeviceOptions
    from .options import field_default
    return field_default(DeviceOptions, name)


def _renderer_kwargs(a):
    kw = dict(device=a.device, lanes=a.lanes, local_size=a.local_size, nee=not a.no_nee, use_cache=not a.no_cache)
    kw.update({k: getattr(a, k) for k in ("precision", "kernel") if getattr(a, k, None) is not None})
    if getattr(a, "photons", None) == 0:
        kw["photons"] = False
    return kw


def _add_scene_params(p):
    p.add_argument("-D", "--param", action="append", default=[], metavar="NAME=VALUE",
                   help="set a Mitsuba XML scene parameter ($NAME), overriding its <default> (repeatable)")
    p.add_argument("--strict", action="store_true", help="Mitsuba XML: treat every import warning as an error")


def _scene_params(a) -> dict:
    from .scene import SceneError

    params = {}
    for item in a.param:
        name, eq, value = item.partition("=")
        if not eq or not name.strip():
            raise SceneError(f"-D {item}: expected NAME=VALUE")
        params[name.strip()] = value
    return params


def _load(a):
    from .loading import load_scene

    return load_scene(a.scene, _scene_params(a), strict=a.strict)


def _warn(msg):
    print(f"clpt: warning: {msg}", file=sys.stderr)


def _dask_client(spec: str):
    """A distributed.Client for --dask: a scheduler's address, or local:N worker processes."""
    from .scene import SceneError

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


def cmd_render(a) -> int:
    import threading

    from . import preflight
    from .engine.checkpoint import Checkpoint
    from .engine.driver import interrupt_signals
    from .render import Renderer
    from .scene import SceneError

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
        from .tev import UPDATE_INTERVAL, TevViewer

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
    from .image import save_image

    preview = None
    if filt is not None and filt.interval:
        def preview(img):
            from .image import ImageError
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
                               aux_specular=a.aux_specular or "surface", **run)
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
    from . import preflight
    from .image import save_image

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
        from .adaptive import sample_map_image
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


def cmd_devices(a) -> int:
    from . import device as devmod, runtimes
    from .device import DeviceContext, list_devices

    devs = list_devices()
    for d in devs:
        print(d.line())
        if a.verbose:
            from . import tune

            dev = devmod._all_devices()[d.index][3]
            dctx = DeviceContext(dev)
            print(f"    float vector width: native {dev.native_vector_width_float}, preferred "
                  f"{dev.preferred_vector_width_float}; max work-group {dev.max_work_group_size}; "
                  f"max allocation {d.max_alloc / 2**30:.1f} GiB")
            if devmod.is_simulator(dev):
                print("    check: a simulator (never a default; name it with --device to debug kernels)")
            else:
                print(f"    check: {devmod.check_device(dev).line()}")
            for photons in (False, True):
                print(f"    defaults{' with photons' if photons else ''}: "
                      f"{tune.query_tuning(dctx, photons).describe()}")
            for e in tune.cached_choices(dctx):
                print(f"    measured: lanes {e['lanes']}, local size {e['local_size']}, pass {e['pass_seconds']:g} s "
                      f"({e['why']})")
    if not devs:
        print("no OpenCL devices found", file=sys.stderr)
        return 1
    if a.verbose:
        reg = runtimes.registration()
        if reg is not None:
            print(f"runtimes: {reg.note}")
        for photons, kind in ((False, "for path tracing"), (True, "with photon merging")):
            try:
                c = devmod.default_device(photons)
                print(f"default {kind}: {devmod.device_label(c.device)}: {c.why}"
                      + "".join(f"; {s}" for s in c.skipped))
            except devmod.DeviceError as e:
                print(f"default {kind}: none ({e})")
    return 0


def cmd_scenes(a) -> int:
    from .resources import scene_dir, shipped_scenes

    for name in shipped_scenes():
        first = (scene_dir() / f"{name}.toml").read_text().splitlines()[0].lstrip("# ").strip()
        print(f"{name:28s} {first}")
    return 0


def cmd_check(a) -> int:
    from .features import scene_features
    from .pack import pack_scene

    scene = _load(a)
    packed = pack_scene(scene)
    names = ("materials", "spheres", "quads", "triangles", "planes", "lights")
    line = ", ".join(f"{n} {c}" for n, c in zip(names, packed.counts))
    if packed.bvh is not None:
        line = (f"materials {packed.count('materials')}, {packed.primitives} spheres, quads and triangles in a BVH "
                f"of {packed.count('nodes')} nodes, planes {packed.count('planes')}, lights {packed.count('lights')}")
    print(f"{a.scene}: ok; {line}")
    print(f"features: {scene_features(packed).describe()}")
    return 0


def cmd_cache(a) -> int:
    from .program import cache_dir, clear_cache

    if a.clear:
        print(f"removed {clear_cache()} cached kernel builds, the tuned settings and the device checks "
              f"from {cache_dir()}")
    else:
        d = cache_dir() / "kernels"
        files = list(d.glob("*.bin")) if d.is_dir() else []
        print(f"{cache_dir()}: {len(files)} cached kernel builds, {sum(f.stat().st_size for f in files) / 1e6:.1f} MB")
    return 0


def cmd_compare(a) -> int:
    import json

    from .studies import compare, format_table, reference_image, standard_comparison
    from .loading import load_scene

    out = {}
    for name in a.scene:
        scene = load_scene(name)
        ref_path = Path(a.ref_dir) / f"{Path(name).stem}_{a.width}x{a.height}_{a.ref_spp}spp.exr"
        ref = reference_image(scene, a.width, a.height, a.ref_spp, ref_path, a.device)
        out[name] = compare(scene, standard_comparison(), ref=ref, seconds=a.seconds, width=a.width,
                            height=a.height, device=a.device)
    if a.json:
        print(json.dumps(out, indent=1, default=str))
    else:
        for name, rows in out.items():
            print(f"{name}, {a.seconds} s each:")
            print(format_table(rows, ("value", "seconds", "spp", "relmse", "rmse", "ssim", "flip")))
    return 0


def cmd_tradeoff(a) -> int:
    from .resources import shipped_scenes
    from .studies import compare, reference_image, standard_comparison, tradeoff, write_summary
    from .loading import load_scene

    names = shipped_scenes() if a.scene == ["all"] else a.scene
    summaries, comparisons = [], {}
    for name in names:
        print(f"{name}:", file=sys.stderr)
        sub_dir = Path(a.out) / Path(name).stem
        summaries.append(tradeoff(name, out_dir=sub_dir, width=a.width, height=a.height, spp=a.spp,
                                  ref_spp=a.ref_spp, reference=a.reference, device=a.device,
                                  log=lambda m: print(m, file=sys.stderr)))
        if a.compare_seconds > 0:
            ref_path = sub_dir / f"reference_{a.width}x{a.height}_{a.ref_spp}spp.exr"
            ref = reference_image(load_scene(name), a.width, a.height, a.ref_spp, ref_path, a.device)
            comparisons[name] = compare(load_scene(name), standard_comparison(), ref=ref, seconds=a.compare_seconds,
                                        width=a.width, height=a.height, device=a.device)
    command = "clpt tradeoff " + " ".join(a.scene) + f" --out {a.out} --width {a.width} --height {a.height} " \
              f"--spp {a.spp} --ref-spp {a.ref_spp}" + (f" --compare-seconds {a.compare_seconds}"
                                                       if a.compare_seconds else "")
    write_summary(a.out, summaries, comparisons or None, command)
    print(f"wrote {Path(a.out) / 'README.md'}", file=sys.stderr)
    return 0


def cmd_bench(a) -> int:
    from .bench import run_bench

    return run_bench(a)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="clpt", description="OpenCL path tracer with caustic photon mapping")
    ap.add_argument("--version", action="version", version=f"clpt {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("render", help="render a scene to an image file")
    p.add_argument("scene", nargs="?", default=None, help="scene file, or a shipped scene's name "
                                                         "(default: cornell_box, or the checkpoint's with --resume)")
    p.add_argument("-o", "--output", help="image file: .png, .jpg (8-bit sRGB) or .exr (linear float); "
                                          "default <scene>.png")
    p.add_argument("--spp", type=int, help="samples per pixel (default: the scene's)")
    p.add_argument("--width", type=int)
    p.add_argument("--height", type=int)
    p.add_argument("--max-depth", type=int, help="most scattering events per path (0: emitters only)")
    p.add_argument("--rr-depth", type=int, help="depth from which Russian roulette may absorb paths")
    p.add_argument("--seed", type=int)
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
    _add_scene_params(p)
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("bench", help="measure samples/s, rays/s and kernel build times")
    p.add_argument("scene", nargs="*", default=["cornell_box"], help="scenes to measure ('all': every shipped "
                                                                      "scene; default cornell_box)")
    p.add_argument("--width", type=int, default=256)
    p.add_argument("--height", type=int, default=256)
    p.add_argument("--max-depth", type=int, default=8)
    p.add_argument("--rounds", type=int, default=5, help="timed passes per configuration, taken in turn")
    p.add_argument("--no-cold", action="store_true", help="skip the cold-build measurement (a subprocess)")
    p.add_argument("--json", action="store_true", help="print the results as JSON (for --compare)")
    p.add_argument("--csv", action="store_true", help="print the results as CSV")
    p.add_argument("--compare", metavar="OLD.json", help="also print ratios against an earlier --json run")
    p.add_argument("--device", "-d", default=None, help="as for render; a comma list measures each device")
    p.add_argument("--lanes", default=None, help="paths per work-item, or a comma list to compare (auto,1,8,16)")
    p.add_argument("--local-size", default=None, help="work-group size, or a comma list (auto,16,64)")
    p.add_argument("--kernel", default="specialized", help="specialized, generic, or specialized,generic")
    p.add_argument("--precision", default="float", help="float, double, or float,double")
    p.add_argument("--mitsuba", action="store_true", help="also time Mitsuba 3's cornell_box() (if installed)")
    p.add_argument("--no-nee", action="store_true")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("bench-builds", help="cold and warm kernel builds of scenes per device, as a first "
                                            "render meets them")
    p.add_argument("scene", nargs="*", default=["all"], help="scenes ('all': every shipped scene, the default)")
    p.add_argument("--device", "-d", default="default",
                   help="comma list of devices to measure ('default': the device clpt render picks)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=lambda a: __import__("clpt.bench", fromlist=["x"]).run_bench_builds(a))

    p = sub.add_parser("bench-photons", help="photon pass and grid build times, gather cost, and the error "
                                             "of caustics at equal render time")
    p.add_argument("scene", nargs="?", default="cornell_box_caustics")
    p.add_argument("--counts", default="1e5,1e6,1e7", help="photon counts to build (comma list)")
    p.add_argument("--width", type=int, default=128)
    p.add_argument("--height", type=int, default=128)
    p.add_argument("--equal-time", default=None, metavar="SECONDS",
                   help="also compare errors at these render times (comma list)")
    p.add_argument("--reference", default=None, help="reference EXR: read if it exists, else rendered and saved")
    p.add_argument("--ref-spp", type=int, default=16384)
    p.add_argument("--max-depth", type=int, default=64, help="path depth of the equal-time renders (default 64)")
    p.add_argument("--cpu-time", action="store_true",
                   help="equal CPU time of this process instead of equal wall time (for a machine shared with other work)")
    p.add_argument("--device", "-d", default=None)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=lambda a: __import__("clpt.bench", fromlist=["x"]).run_bench_photons(a))

    p = sub.add_parser("bench-denoise", help="the cone filter and OIDN against a path-traced reference: error, "
                                             "caustic energy, halos around lights, time")
    p.add_argument("scene", nargs="*", default=["cornell_box", "cornell_box_caustics"])
    p.add_argument("--width", type=int, default=128)
    p.add_argument("--height", type=int, default=128)
    p.add_argument("--spp", default="16,64", help="comma list")
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--max-depth", type=int, default=64)
    p.add_argument("--ref-spp", type=int, default=4096)
    p.add_argument("--ref-dir", default=".clpt-references", help="where references are cached")
    p.add_argument("--time-size", type=int, default=512, help="image size of the timing (0: no timing)")
    p.add_argument("--image", default=None, help="write raw | cone | OIDN | reference of the caustics box here")
    p.add_argument("--device", "-d", default=None)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=lambda a: __import__("clpt.bench_denoise", fromlist=["x"]).run_bench_denoise(a))

    p = sub.add_parser("bench-bvh", help="BVH build time, memory and rays/s for generated meshes; plain loops "
                                          "vs BVH; scene setup time")
    p.add_argument("--triangles", default="1e3,1e5,1e6", help="mesh sizes (comma list; empty: none)")
    p.add_argument("--methods", default="sah,lbvh", help="BVH builders to compare (comma list)")
    p.add_argument("--walks", default="hybrid", help="BVH traversals to compare (comma list): hybrid (packets "
                                                     "for coherent camera rays, the default) and lane (every ray "
                                                     "alone)")
    p.add_argument("--width", type=int, default=128)
    p.add_argument("--height", type=int, default=128)
    p.add_argument("--max-depth", type=int, default=8)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--threshold", action="store_true", help="also measure plain loops against the BVH")
    p.add_argument("--setup", default=None, metavar="TRIANGLES", help="also time scene setup for this many")
    p.add_argument("--mitsuba", default=None, metavar="MESH", help="also race Mitsuba 3 (llvm_ad_rgb; pip install "
                                                                  "mitsuba) on this mesh in the Cornell box")
    p.add_argument("--device", "-d", default=None)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=lambda a: __import__("clpt.bench", fromlist=["x"]).run_bench_bvh(a))

    p = sub.add_parser("compare", help="uniform vs adaptive sampling vs the filter, at equal render time")
    p.add_argument("scene", nargs="+")
    p.add_argument("--seconds", type=float, default=4.0)
    p.add_argument("--width", type=int, default=128)
    p.add_argument("--height", type=int, default=128)
    p.add_argument("--ref-spp", type=int, default=16384)
    p.add_argument("--ref-dir", default=".clpt-references", help="where references are cached")
    p.add_argument("--device", "-d", default=None)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("tradeoff", help="sweep every speed/accuracy knob; tables, plots and a summary")
    p.add_argument("scene", nargs="+", help="scenes, or 'all' for the shipped ones")
    p.add_argument("--out", default="tradeoff", help="output folder (one subfolder per scene, README.md)")
    p.add_argument("--width", type=int, default=64)
    p.add_argument("--height", type=int, default=64)
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--ref-spp", type=int, default=16384)
    p.add_argument("--reference", default=None, help="reference EXR (one scene); default: rendered and cached")
    p.add_argument("--compare-seconds", type=float, default=0.0,
                   help="also run the equal-time comparison for this long per method")
    p.add_argument("--device", "-d", default=None)
    p.set_defaults(func=cmd_tradeoff)

    p = sub.add_parser("devices", help="list the OpenCL devices")
    p.add_argument("-v", "--verbose", action="store_true", help="also the vector widths and the tuned defaults")
    p.set_defaults(func=cmd_devices)
    p = sub.add_parser("scenes", help="list the shipped scenes")
    p.set_defaults(func=cmd_scenes)
    p = sub.add_parser("check", help="validate a scene file")
    p.add_argument("scene")
    _add_scene_params(p)
    p.set_defaults(func=cmd_check)
    p = sub.add_parser("cache", help="show or clear the kernel build cache")
    p.add_argument("--clear", action="store_true")
    p.set_defaults(func=cmd_cache)
    return ap


def main(argv=None) -> int:
    from .device import DeviceError
    from .image import ImageError
    from .program import KernelBuildError
    from .scene import SceneError

    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return args.func(args)
    except SceneError as e:
        print(f"clpt: error: {e}", file=sys.stderr)
        return 2
    except (DeviceError, KernelBuildError, ImageError) as e:
        print(f"clpt: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("\nclpt: interrupted", file=sys.stderr)
        return 130


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Scene warnings as one line each, like the errors."""
    from .scene import SceneWarning

    import pyopencl as cl

    from .device import DeviceWarning

    if issubclass(category, cl.CompilerWarning):
        return  # compiler remarks are not the user's business (builds in threads can slip past program.build's filter)
    if issubclass(category, (SceneWarning, DeviceWarning)):
        print(f"clpt: warning: {message}", file=sys.stderr)
    else:
        print(warnings.formatwarning(message, category, filename, lineno, line), file=sys.stderr, end="")


if __name__ == "__main__":
    sys.exit(main())
