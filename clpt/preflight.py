"""Checks made before a render starts, so that a finished render is never lost
to a mistake found at the end: the output path (writable, a format that can be
written), the options (finite, in range), and the memory the render will need
against what the machine offers. And, should saving fail anyway, a fallback
EXR that keeps the render.

Every check raises SceneError (a one-line mistake in the command, exit
status 2) with what to change.
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

from .errors import ImageError, SceneError
from .hostio import available_host_bytes
from .image import save_image
from .options import ADAPTIVE_OPTIONS, CONE_FILTER_OPTIONS, DENOISER_OPTIONS, OIDN_OPTIONS, PHOTON_OPTIONS, given
from .scene import EnvironmentLight, Mesh

# Measured peak resident memory of `clpt render` (cornell_box, PoCL, 1 spp;
# 1024^2 and 2048^2 against 256^2): bytes per pixel of the plain render, and
# what the feature buffers and the filter add.
HOST_BASE_BYTES = 128 << 20
BYTES_PER_PIXEL = 190
AUX_BYTES_PER_PIXEL = 420
ADAPTIVE_BYTES_PER_PIXEL = 30
PHOTON_BYTES = 130  # traced, sorted and keyed copies of each photon

# Measured peak resident memory of `clpt render` of the Cornell box with one
# mesh (spheres of 0.26 and 1.05 million triangles against one of 6; Intel's
# CPU runtime, 64x64, 1 spp, generic kernel): bytes per triangle of the mesh's
# arrays, its packed records, their BVH and the device's copies (990 and 1340
# on average, 1450 between the two), and what an emissive mesh's light table
# adds (150 and 290).
MESH_BYTES_PER_TRIANGLE = 1450
MESH_LIGHT_BYTES_PER_TRIANGLE = 300
# A bitmap texture's texels while it renders (not measured: counted from the copies made): the
# decoded float32 image (12 bytes a texel), the packed float64 records (24) and the device's copy (12
# in float builds; host memory on a CPU device).
TEXTURE_BYTES_PER_TEXEL = 12 + 24 + 12
# An environment map (Intel's CPU runtime): the 8192x4096 map's packed texels,
# sampling tables and the device's copy raised the peak resident memory of a
# 32x32 render by 2.84 GiB (3.6 GiB in all), 91 bytes a texel, with the file's
# float pixels (12) on top; the alias tables that replaced its guide tables
# add 8 bytes a cell packed and 4 on the device (counted, not measured).
ENV_BYTES_PER_TEXEL = 116

MAX_EXPOSURE = 64.0  # stops; 2^64 already saturates every float image


def _reason(e: OSError) -> str:
    r = e.strerror or str(e)
    return r[:1].lower() + r[1:]


def check_folder(folder: Path, what: str, path) -> Path:
    """Make sure a file can be written in `folder` by doing it: create the
    folder (and those above it) and create and remove a temporary file in it.
    Permission bits are not asked (os.access says yes to root everywhere, and
    read-only or virtual file systems refuse what the bits allow)."""
    folder = folder if str(folder) else Path(".")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise SceneError(f"{what} {path}: {folder} is not a folder") from None
    except OSError as e:
        raise SceneError(f"{what} {path}: cannot create the folder {folder} ({_reason(e)})") from None
    if not folder.is_dir():
        raise SceneError(f"{what} {path}: {folder} is not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".clpt-probe-", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise SceneError(f"{what} {path}: cannot write in {folder} ({_reason(e)})") from None
    return folder


def check_output(path, what: str = "-o") -> Path:
    """An output path that can be written, in a format OpenImageIO writes:
    its folder is created and written to (check_folder), an existing file
    opened for writing (not truncated)."""
    import OpenImageIO as oiio  # optional and heavy: imported only to check an image format

    if path is None or str(path).strip() == "":
        raise SceneError(f"{what}: the output path is empty; give a file name such as out.png or out.exr")
    p = Path(path)
    if p.suffix == "":
        raise SceneError(f"{what} {path}: no file extension; use .png, .jpg or .exr (or another image format)")
    out = oiio.ImageOutput.create(str(p))
    if out is None:
        oiio.geterror()
        raise SceneError(f"{what} {path}: {p.suffix} is not an image format clpt can write; "
                         f"use .png, .jpg or .exr")
    if p.is_dir():
        raise SceneError(f"{what} {path}: is a folder; give a file name")
    check_folder(p.parent, what, path)
    if p.exists():
        try:
            os.close(os.open(p, os.O_WRONLY | getattr(os, "O_NONBLOCK", 0)))
        except OSError as e:
            raise SceneError(f"{what} {path}: the file exists and cannot be written ({_reason(e)})") from None
    return p


# Largest image side each format can store (OpenImageIO's writers and readers).
MAX_SIDE = {".jpg": 65500, ".jpeg": 65500, ".jpe": 65500, ".jif": 65500, ".jfif": 65500, ".jfi": 65500,
            ".hdr": 65535, ".rgbe": 65535, ".webp": 16383, ".gif": 65535, ".bmp": 65535, ".tga": 65535}


def check_image_size(out, width: int, height: int, what: str = "-o"):
    """The image's size must fit its file format."""
    side = MAX_SIDE.get(Path(out).suffix.lower())
    if side is not None and max(width, height) > side:
        raise SceneError(f"{what} {out}: {Path(out).suffix} images are at most {side} pixels a side "
                         f"(asked {width}x{height}); use .exr or .png")


def _finite_option(name, v, lo=None, hi=None, lo_open=False):
    if v is None:
        return
    if not math.isfinite(v):
        raise SceneError(f"{name}: must be a finite number (got {v})")
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise SceneError(f"{name}: must be {'>' if lo_open else '>='} {lo:g} (got {v:g})")
    if hi is not None and v > hi:
        raise SceneError(f"{name}: must be <= {hi:g} (got {v:g})")


def _int_option(name, v, lo, hi):
    if v is not None and not lo <= v <= hi:
        raise SceneError(f"{name}: must be an integer from {lo} to {hi} (got {v})")


def check_render_options(a):
    """Range checks of `clpt render`'s options (argparse has checked types)."""
    _finite_option("--exposure", a.exposure, -MAX_EXPOSURE, MAX_EXPOSURE)
    _finite_option("--time-limit", a.time_limit, 0.0, lo_open=True)
    _int_option("--spp", a.spp, 1, 2 ** 32 - 1)
    _int_option("--seed", a.seed, 0, 2 ** 32 - 1)
    _int_option("--width", a.width, 1, 1 << 16)
    _int_option("--height", a.height, 1, 1 << 16)
    _int_option("--max-depth", a.max_depth, 0, 2 ** 31 - 1)
    _int_option("--rr-depth", a.rr_depth, 0, 2 ** 31 - 1)
    _int_option("--filter-interval", getattr(a, "filter_interval", None), 0, 2 ** 31 - 1)
    _int_option("--min-spp", getattr(a, "min_spp", None), 1, 2 ** 32 - 1)
    _int_option("--adaptive-pass-spp", getattr(a, "adaptive_pass_spp", None), 1, 2 ** 32 - 1)
    _finite_option("--noise-threshold", getattr(a, "noise_threshold", None), 0.0, lo_open=True)
    for name in ("radius", "cone_k", "alpha", "merge_probability"):
        _finite_option(f"--{name.replace('_', '-')}", getattr(a, name, None))


def warn_unused_options(a, scene_has_casters: bool, warn):
    """One line for each given option that will have no effect."""
    photon_opts = [o.flag for o in given(a, PHOTON_OPTIONS)]
    if photon_opts and not scene_has_casters:
        warn(f"{', '.join(photon_opts)} ignored: the scene has no mirror or glass objects, so no photon map")
    filt_opts = [o.flag for o in given(a, CONE_FILTER_OPTIONS + OIDN_OPTIONS + DENOISER_OPTIONS)]
    if filt_opts and not (a.filter or getattr(a, "denoise", None)):
        warn(f"{', '.join(filt_opts)} ignored without --filter or --denoise")
    ad_opts = [o.flag for o in given(a, ADAPTIVE_OPTIONS)]
    if ad_opts and a.adaptive is None:
        warn(f"{', '.join(ad_opts)} ignored without --adaptive")


def host_bytes_needed(width: int, height: int, aux: bool = False, adaptive: bool = False, photons: int = 0,
                      cpu_device: bool = True, resources: int = 0) -> int:
    """Peak host memory of a render, from the measured costs above (a CPU
    device's buffers are host memory too); resources: scene_resource_bytes."""
    per_px = BYTES_PER_PIXEL + (AUX_BYTES_PER_PIXEL if aux else 0) + (ADAPTIVE_BYTES_PER_PIXEL if adaptive else 0)
    return HOST_BASE_BYTES + width * height * per_px + (photons * PHOTON_BYTES if cpu_device else 0) + resources


def scene_resources(scene) -> list[tuple[str, int]]:
    """(what, bytes) of each of the scene's resources while it renders, from
    the costs above: its meshes, its bitmap textures (their texels; an 8192 x
    8192 bitmap takes 768 MiB on the device in float builds) and its
    environment map."""
    out = []
    seen = set()
    for _, p in scene.primitives():
        for _, t in scene.surface(p).textures:
            if id(t) not in seen and t.texels:
                seen.add(id(t))
                h, w = t.data.shape[:2]
                out.append((f"{w}x{h} texture", t.texels * TEXTURE_BYTES_PER_TEXEL))
    for s in scene.shapes:
        if isinstance(s, EnvironmentLight) and s.image is not None:
            h, w = s.image.shape[:2]
            out.append((f"{w}x{h} environment map", w * h * ENV_BYTES_PER_TEXEL))
        if isinstance(s, Mesh):
            light = scene.surface(s).is_emissive
            per = MESH_BYTES_PER_TRIANGLE + (MESH_LIGHT_BYTES_PER_TRIANGLE if light else 0)
            out.append((f"mesh {s.name or ''} of {len(s.triangles)} triangles".replace("  ", " "),
                        len(s.triangles) * per))
    return out


def scene_resource_bytes(scene) -> int:
    return sum(b for _, b in scene_resources(scene))


def check_scene_memory(scene, available: int | None = None):
    """Refuse a scene whose resources alone will not fit in memory, before
    they are packed for the devices (the render's own buffers are checked
    with them by check_memory, once its size and options are known)."""
    items = scene_resources(scene)
    need = HOST_BASE_BYTES + sum(b for _, b in items)
    avail = available_host_bytes() if available is None else available
    if not items or avail is None or need <= avail:
        return
    what, most = max(items, key=lambda x: x[1])
    n_mesh = sum(w.startswith("mesh") for w, _ in items)
    n_tex = sum(w.endswith(" texture") for w, _ in items)
    n_env = len(items) - n_mesh - n_tex
    kinds = [f"{n} {noun}{plural if n != 1 else ''}" for n, noun, plural in
             ((n_mesh, "mesh", "es"), (n_tex, "texture", "s"), (n_env, "environment map", "s")) if n]
    owners = [o for n, o in ((n_mesh, "meshes"), (n_tex, "textures"), (n_env, "environment map")) if n]
    owner = " and ".join(owners)
    verb = "needs" if owners == ["environment map"] else "need"
    raise SceneError(f"{scene.source}: its {owner} {verb} about {need / 2**30:.1f} GiB of memory to render "
                     f"({', '.join(kinds)}, the largest a {what}: {most / 2**30:.1f} GiB) and "
                     f"{max(avail, 0) / 2**30:.1f} GiB are available")


def check_memory(width: int, height: int, aux: bool, adaptive: bool, photons: int, cpu_device: bool = True,
                 available: int | None = None, resources: int = 0):
    """Refuse a render that will not fit in memory, saying what size would;
    resources: the scene's (scene_resource_bytes)."""
    need = host_bytes_needed(width, height, aux, adaptive, photons, cpu_device, resources)
    avail = available_host_bytes() if available is None else available
    if avail is None or need <= avail:
        return
    fixed = HOST_BASE_BYTES + (photons * PHOTON_BYTES if cpu_device else 0) + resources
    per_px = (need - fixed) / (width * height)
    room = avail - fixed
    fit = ""
    if room > 0:
        k = math.sqrt(room / per_px / (width * height))
        fit = f"; at most about {max(1, int(width * k))}x{max(1, int(height * k))} fits"
    meshes = f" ({resources / 2**30:.1f} GiB of it for the scene's meshes)" if resources else ""
    raise SceneError(f"a {width}x{height} render needs about {need / 2**30:.1f} GiB of memory{meshes} and "
                     f"{max(avail, 0) / 2**30:.1f} GiB are available{fit}")


def fallback_path(out: Path) -> Path:
    """Where the render goes if `out` cannot be written: an EXR beside it, or
    in the temp folder when that folder is not writable."""
    name = f"{out.stem or 'render'}.clpt-unsaved.exr"
    beside = (out.parent if str(out.parent) else Path(".")) / name
    if beside != out and beside.parent.is_dir():
        try:
            check_folder(beside.parent, "", out)
            return beside
        except SceneError:
            pass
    return Path(tempfile.gettempdir()) / name


def save_with_fallback(save, out: Path, image, metadata, warn) -> Path | None:
    """save(out); if that fails, the image as a float EXR at fallback_path(out)
    (returned) after warning with both reasons."""
    try:
        save(out)
        return None
    except (ImageError, OSError, RuntimeError, ValueError, TypeError, OverflowError) as e:
        first = e
    fb = fallback_path(out)
    try:
        save_image(fb, image, metadata=metadata)
    except Exception as e:  # noqa: BLE001 - the last resort: the temp folder
        fb = Path(tempfile.mkdtemp(prefix="clpt-")) / fb.name
        try:
            save_image(fb, image, metadata=metadata)
        except Exception as e2:  # noqa: BLE001
            raise SceneError(f"cannot save the render to {out} ({first}) nor to a fallback ({e}; {e2})") from None
    warn(f"cannot save {out} ({first}); the render was written to {fb}")
    return fb
