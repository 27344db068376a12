"""The reference image of the studies and benchmarks: a high-spp render by
path tracing alone (photon mapping off, so it is unbiased), read from an EXR
when one is there, else rendered and saved there.

The saved EXR keeps its sample count, its path depth (when one was set) and
its noise level (the mean variance of its pixel means, which its own noise
adds to any MSE against it) in the metadata, so a study that reads it back
can take that noise out again. The noise per pixel (the variance of each
pixel's luminance mean) is saved beside it, in <stem>.noise.exr: caustics
concentrate a path-traced reference's noise in a few pixels, where the mean
says little.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

SEED = 0x5EED  # the references' seed unless a caller keeps its own


class Reference(np.ndarray):
    """A reference image (float64, H x W x 3); .noise is the mean variance of
    its pixel means, 0 if unknown; .noise_map the variance of each pixel's
    luminance mean (H x W), None if unknown."""

    noise = 0.0
    noise_map = None


def noise_path(path) -> Path:
    """Where the per-pixel noise of the reference saved at path is kept."""
    path = Path(path)
    return path.with_name(path.stem + ".noise.exr")


def cached_path(folder, scene, width: int, height: int, spp: int, max_depth: int | None = None) -> Path:
    """Where a reference of scene (a name or a file) is cached in folder:
    <stem>_<width>x<height>[_d<max_depth>]_<spp>spp.exr."""
    depth = f"_d{max_depth}" if max_depth is not None else ""
    return Path(folder) / f"{Path(str(scene)).stem}_{width}x{height}{depth}_{spp}spp.exr"


def reference_image(scene, width: int, height: int, spp: int, path=None, device=None, *,
                    max_depth: int | None = None, seed: int = SEED) -> Reference:
    """The reference of scene (a Scene, a file or a shipped scene's name) at
    width x height: read from path if that file exists (it must have that
    size), else rendered with spp samples per pixel (max_depth: the scene's
    unless given) and, with a path, saved there."""
    from ..image import load_image, read_metadata, save_image
    from ..render import Renderer
    from ..scene import SettingsError

    if path is not None and Path(path).exists():
        img = load_image(path)[..., :3]
        if img.shape[:2] != (height, width):
            raise SettingsError(f"reference {path} is {img.shape[1]}x{img.shape[0]}, not {width}x{height}")
        out = img.astype(np.float64).view(Reference)
        out.noise = float(read_metadata(path).get("clpt:noise", 0.0))
        if noise_path(path).exists():
            out.noise_map = load_image(noise_path(path))[..., 0].astype(np.float64)
        return out
    res = Renderer(scene, device=device, photons=False).render(spp, width=width, height=height, seed=seed,
                                                              max_depth=max_depth)
    noise_map = res.lum_var.astype(np.float64) / np.maximum(res.sample_count, 1)
    noise = float(noise_map.mean())
    if path is not None:
        meta = {"clpt:reference_spp": spp, "clpt:noise": noise}
        if max_depth is not None:
            meta["clpt:max_depth"] = max_depth
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        save_image(path, res.image, metadata=meta)
        save_image(noise_path(path), noise_map, metadata={"clpt:reference_spp": spp,
                                                         "clpt:content": "variance of each pixel's luminance mean"})
    out = res.image.astype(np.float64).view(Reference)
    out.noise = noise
    out.noise_map = noise_map
    return out
