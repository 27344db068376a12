"""Images: linear float RGB in, files out through OpenImageIO.

EXR (and HDR/TIFF float) files keep linear float32 values and the render's
metadata; PNG, JPEG and other 8-bit formats get an exposure (in stops), the
sRGB transfer curve, clamping and dithering-free rounding.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

FLOAT_FORMATS = {".exr", ".hdr", ".tif", ".tiff", ".pfm"}


class ImageError(RuntimeError):
    """An image could not be written or read."""


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def to_display(img: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB."""
    v = linear_to_srgb(np.nan_to_num(img, nan=0.0, posinf=1.0, neginf=0.0) * (2.0 ** exposure))
    return np.round(v * 255.0).astype(np.uint8)


def save_image(path, img: np.ndarray, metadata: dict | None = None, exposure: float = 0.0):
    """Write H x W x C linear float data; the format follows the file extension."""
    import OpenImageIO as oiio

    path = Path(path)
    img = np.asarray(img)
    if img.ndim == 2:
        img = img[:, :, None]
    h, w, c = img.shape
    if path.suffix.lower() in FLOAT_FORMATS:
        data = np.ascontiguousarray(np.nan_to_num(img, nan=0.0).astype(np.float32))
        spec = oiio.ImageSpec(w, h, c, oiio.FLOAT)
    else:
        data = np.ascontiguousarray(to_display(img, exposure))
        spec = oiio.ImageSpec(w, h, c, oiio.UINT8)
        spec.attribute("oiio:ColorSpace", "sRGB")
    for k, v in (metadata or {}).items():
        spec.attribute(k, v if isinstance(v, (int, float)) else str(v))
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise ImageError(f"{path}: cannot write this image format ({oiio.geterror()})")
    # Atomically: into a temporary file beside it, then renamed over it, so a
    # killed write never leaves a truncated image where a good one was.
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        try:
            if not out.open(str(tmp), spec) or not out.write_image(data):
                raise ImageError(f"{path}: {out.geterror()}")
        finally:
            out.close()
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def load_image(path) -> np.ndarray:
    """Read an image as float32 H x W x C (8-bit files scaled to [0, 1], not linearized)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageError(f"{path}: cannot read ({oiio.geterror()})")
    try:
        data = inp.read_image(oiio.FLOAT)
    finally:
        inp.close()
    if data is None:
        raise ImageError(f"{path}: cannot read pixels")
    return np.asarray(data, dtype=np.float32)


def read_metadata(path) -> dict:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageError(f"{path}: cannot read ({oiio.geterror()})")
    try:
        spec = inp.spec()
        return {a.name: a.value for a in spec.extra_attribs}
    finally:
        inp.close()
