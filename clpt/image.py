"""Images: linear float RGB in, files out through OpenImageIO.

EXR (and HDR/TIFF float) files keep linear float32 values and the render's
metadata; PNG, JPEG and other 8-bit formats get an exposure (in stops), the
sRGB transfer curve, clamping and dithering-free rounding.
"""

from __future__ import annotations

import contextlib
import os
import struct
import zlib
from pathlib import Path

import numpy as np

from .errors import ImageError

FLOAT_FORMATS = {".exr", ".hdr", ".tif", ".tiff", ".pfm"}


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def to_display(img: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB."""
    v = linear_to_srgb(np.nan_to_num(img, nan=0.0, posinf=1.0, neginf=0.0) * (2.0 ** exposure))
    return np.round(v * 255.0).astype(np.uint8)


def png_bytes(img: np.ndarray, exposure: float = 0.0) -> bytes:
    """Linear RGB (H x W x 3) -> a PNG file's bytes, tone-mapped as save_image
    writes PNGs (for notebooks: no file, no OpenImageIO)."""
    rgb = to_display(np.asarray(img, dtype=np.float32), exposure)
    if rgb.ndim == 2:
        rgb = rgb[:, :, None]
    h, w, c = rgb.shape
    if c not in (1, 3):
        raise ValueError(f"png_bytes: need 1 or 3 channels (got {c})")

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    rows = np.concatenate([np.zeros((h, 1), np.uint8), rgb.reshape(h, w * c)], axis=1)  # filter type 0 per row
    header = struct.pack(">IIBBBBB", w, h, 8, 2 if c == 3 else 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows.tobytes(), 6))
            + chunk(b"IEND", b""))
def _attribute_value(v, typed: bool):
    """A metadata value OpenImageIO can store: numbers as int32 or float
    where the format keeps them (larger integers, which OpenImageIO cannot
    take, as text), everything else as text."""
    if isinstance(v, (bool, np.bool_)):
        v = int(v)
    if typed and isinstance(v, (int, np.integer)) and -2 ** 31 <= int(v) < 2 ** 31:
        return int(v)
    if typed and isinstance(v, (float, np.floating)):
        return float(v)
    return str(v)


def save_image(path, img: np.ndarray, metadata: dict | None = None, exposure: float = 0.0):
    """Write H x W x C linear float data; the format follows the file extension."""
    import OpenImageIO as oiio  # optional and heavy: imported when an EXR or other format needs it

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
    float_file = path.suffix.lower() in FLOAT_FORMATS
    for k, v in (metadata or {}).items():
        spec.attribute(k, _attribute_value(v, float_file))
    if metadata and "ImageDescription" not in metadata:
        # The one text field every format keeps (JPEG drops the others, PNG keeps only text).
        spec.attribute("ImageDescription", "; ".join(f"{k.removeprefix('clpt:')}={v}" for k, v in metadata.items()))
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise ImageError(f"{path}: cannot write this image format ({oiio.geterror()})")
    # Written beside the target under a temporary name (the same extension,
    # which picks the format), flushed to disk, then renamed over it: a write
    # that is killed or fails never leaves a truncated file where a good image was.
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        try:
            if not out.open(str(tmp), spec) or not out.write_image(data):
                raise ImageError(f"{path}: {out.geterror()}")
        finally:
            out.close()
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def load_image(path) -> np.ndarray:
    """Read an image as float32 H x W x C (8-bit files scaled to [0, 1], not linearized)."""
    import OpenImageIO as oiio  # optional and heavy: imported when an EXR or other format needs it

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
    import OpenImageIO as oiio  # optional and heavy: imported when an EXR or other format needs it

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageError(f"{path}: cannot read ({oiio.geterror()})")
    try:
        spec = inp.spec()
        return {a.name: a.value for a in spec.extra_attribs}
    finally:
        inp.close()
