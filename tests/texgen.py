"""The small images the texture tests read, made here (deterministic):

    python tests/texgen.py          # writes tests/data/textures/*.png

pattern.png: 64 x 64 8-bit sRGB, colour bands and rings with sharp edges (so
that filtering, orientation and wrapping all show in a render), the bitmap
of tests/data/cbox_textured.xml.
spot.png: 16 x 16 8-bit sRGB, the projected texture of tests/data/spot_texture.xml:
red rising along u, green along v, a black 4 x 4 corner (row 0, column 0) and a
white one (the last row and column), so that a flip of either axis shows.
"""

from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent / "data" / "textures"


def pattern(n: int = 64) -> np.ndarray:
    """n x n x 3 uint8: a red-to-yellow ramp along u, blue rings about the
    quarter point, a dark square in the top-left corner (row 0 is the top)."""
    j, i = np.mgrid[0:n, 0:n].astype(np.float64)
    img = np.zeros((n, n, 3))
    img[..., 0] = 0.85
    img[..., 1] = 0.15 + 0.7 * i / (n - 1)
    r = np.hypot(i - n / 4, j - n / 4)
    ring = (np.floor(r / 5) % 2) == 1
    img[ring] = (0.15, 0.3, 0.9)
    img[: n // 4, : n // 4] = (0.05, 0.05, 0.05)
    return np.round(img * 255).astype(np.uint8)


def spot(n: int = 16) -> np.ndarray:
    """n x n x 3 uint8 (spot.png; row 0 is the top)."""
    j, i = np.mgrid[0:n, 0:n].astype(np.float64)
    img = np.zeros((n, n, 3))
    img[..., 0] = 0.2 + 0.8 * i / (n - 1)
    img[..., 1] = 0.2 + 0.8 * j / (n - 1)
    img[..., 2] = 0.3
    k = n // 4
    img[:k, :k] = 0.0
    img[-k:, -k:] = 1.0
    return np.round(img * 255).astype(np.uint8)


def write_png(path: Path, img: np.ndarray):
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], oiio.UINT8)
    out.open(str(path), spec)
    out.write_image(img)
    out.close()


if __name__ == "__main__":
    OUT.mkdir(parents=True, exist_ok=True)
    write_png(OUT / "pattern.png", pattern())
    write_png(OUT / "spot.png", spot())
    print(OUT / "pattern.png", OUT / "spot.png")
