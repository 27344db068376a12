"""Textures: Mitsuba 3's `bitmap` and `checkerboard`, on the host.

A Texture is looked up at a surface point's (u, v) after its to_uv affine
map, as Mitsuba 3 does:

- bitmap: an H x W RGB image of linear values (an 8-bit sRGB file is decoded
  to linear once, on loading, unless raw: Mitsuba filters the decoded
  values). Texel (i, j) (column, row; row 0 the file's first) covers
  [i, i+1)/W x [j, j+1)/H. nearest: the texel under (u W, v H); bilinear:
  the four texels around (u W - 1/2, v H - 1/2), weighted by distance. Each
  texel index is wrapped by wrap_mode: repeat (modulo), mirror (period 2W,
  the second half reversed) or clamp.
- checkerboard: color0 where the fractional parts of u and v are both above
  1/2 or both at most 1/2, color1 elsewhere.

``eval`` is the numpy reference the kernels (kernels/texture.h) are tested
against. ``TEXEL_BYTES`` is what a texel takes on the device (kernels
texture.h reads 3 reals a texel from the scene's records).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .errors import SceneError
from .image import load_image

FILTERS = ("bilinear", "nearest")
WRAP_MODES = ("repeat", "mirror", "clamp")
KINDS = ("bitmap", "checkerboard")
# Formats whose values are linear already (everything else is read as sRGB-encoded unless raw).
LINEAR_SUFFIXES = (".exr", ".hdr", ".pfm")
TEXEL_BYTES = {False: 12, True: 24}  # float builds, double builds: 3 reals a texel


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """The sRGB transfer function, inverted (IEC 61966-2-1), as Mitsuba decodes 8-bit images."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _affine(to_uv) -> tuple:
    """A 2x3 uv map (rows (a, b, c), (d, e, f): u' = a u + b v + c) from a
    4x4 to_uv transform (Mitsuba keeps its x and y rows, columns x, y and the
    translation) or a 2x3/3x3 array."""
    m = np.asarray(to_uv, dtype=np.float64)
    if m.shape == (4, 4):
        m = m[:2][:, [0, 1, 3]]
    elif m.shape in ((3, 3), (2, 3)):
        m = m[:2]
    else:
        raise SceneError(f"a texture's to_uv must be a 4x4, 3x3 or 2x3 matrix (got shape {m.shape})")
    if not np.isfinite(m).all():
        raise SceneError("a texture's to_uv must be finite")
    return tuple(tuple(float(x) for x in row) for row in m)


@dataclass(frozen=True, eq=False)
class Texture:
    """kind "bitmap" (data: H x W x 3 linear float32) or "checkerboard"
    (color0, color1); filter, wrap and to_uv as Mitsuba 3's. Compared and
    hashed by identity: one texture, one device copy."""

    kind: str
    data: np.ndarray | None = None
    color0: tuple = (0.4, 0.4, 0.4)
    color1: tuple = (0.2, 0.2, 0.2)
    filter: str = "bilinear"
    wrap: str = "repeat"
    to_uv: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    name: str = field(default="texture")

    def __post_init__(self):
        if self.kind not in KINDS:
            raise SceneError(f"{self.name}: unknown texture kind {self.kind!r}; known: {', '.join(KINDS)}")
        if self.filter not in FILTERS:
            raise SceneError(f"{self.name}: filter_type must be one of {', '.join(FILTERS)} (got {self.filter!r})")
        if self.wrap not in WRAP_MODES:
            raise SceneError(f"{self.name}: wrap_mode must be one of {', '.join(WRAP_MODES)} (got {self.wrap!r})")
        object.__setattr__(self, "to_uv", _affine(self.to_uv))
        if self.kind == "bitmap":
            d = np.asarray(self.data, dtype=np.float32)
            if d.ndim != 3 or d.shape[2] != 3 or d.shape[0] < 1 or d.shape[1] < 1:
                raise SceneError(f"{self.name}: a bitmap's data must be H x W x 3 (got shape {d.shape})")
            if not np.isfinite(d).all() or d.min() < 0:
                raise SceneError(f"{self.name}: a bitmap's texels must be finite and not negative")
            d = np.ascontiguousarray(d)
            d.setflags(write=False)
            object.__setattr__(self, "data", d)
        else:
            for k in ("color0", "color1"):
                c = tuple(float(x) for x in np.broadcast_to(np.asarray(getattr(self, k), dtype=np.float64), 3))
                if not all(np.isfinite(c)) or min(c) < 0:
                    raise SceneError(f"{self.name}: {k} must be 3 finite numbers >= 0 (got {c})")
                object.__setattr__(self, k, c)

    @property
    def texels(self) -> int:
        return 0 if self.data is None else self.data.shape[0] * self.data.shape[1]

    def scaled(self, k) -> "Texture":
        """This texture times k per channel (a bitmap's texels or a checkerboard's colours)."""
        k = np.broadcast_to(np.asarray(k, dtype=np.float64), 3)
        if self.kind == "bitmap":
            return replace(self, data=(self.data * k).astype(np.float32))
        return replace(self, color0=tuple(np.asarray(self.color0) * k), color1=tuple(np.asarray(self.color1) * k))

    def max(self) -> tuple:
        """The largest value of each channel anywhere (filtering only mixes texels)."""
        if self.kind == "bitmap":
            return tuple(float(x) for x in self.data.reshape(-1, 3).max(axis=0))
        return tuple(float(x) for x in np.maximum(self.color0, self.color1))

    def mean(self) -> tuple:
        """The mean over the texture's [0, 1)^2 (Mitsuba's Texture::mean: the texels' or the two colours')."""
        if self.kind == "bitmap":
            return tuple(float(x) for x in self.data.reshape(-1, 3).astype(np.float64).mean(axis=0))
        return tuple(float(x) for x in 0.5 * (np.asarray(self.color0) + np.asarray(self.color1)))

    def eval(self, uv) -> np.ndarray:
        """RGB (..., 3) at surface coordinates uv (..., 2): the reference lookup."""
        uv = np.asarray(uv, dtype=np.float64)
        a = np.asarray(self.to_uv)
        u = a[0, 0] * uv[..., 0] + a[0, 1] * uv[..., 1] + a[0, 2]
        v = a[1, 0] * uv[..., 0] + a[1, 1] * uv[..., 1] + a[1, 2]
        if self.kind == "checkerboard":
            m0 = ((u - np.floor(u)) > 0.5) == ((v - np.floor(v)) > 0.5)
            return np.where(m0[..., None], np.asarray(self.color0), np.asarray(self.color1))
        h, w = self.data.shape[:2]
        d = self.data.astype(np.float64)
        if self.filter == "nearest":
            return d[wrap_index(np.floor(v * h), h, self.wrap), wrap_index(np.floor(u * w), w, self.wrap)]
        x, y = u * w - 0.5, v * h - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = (x - x0)[..., None], (y - y0)[..., None]
        i0, i1 = wrap_index(x0, w, self.wrap), wrap_index(x0 + 1, w, self.wrap)
        j0, j1 = wrap_index(y0, h, self.wrap), wrap_index(y0 + 1, h, self.wrap)
        return (1 - fy) * ((1 - fx) * d[j0, i0] + fx * d[j0, i1]) + fy * ((1 - fx) * d[j1, i0] + fx * d[j1, i1])


# The most texture lookups one emitter's surface mean makes (surface_mean_sphere, surface_mean_planar).
MEAN_LOOKUPS = 1 << 20
_MEAN_CHUNK = 1 << 16


def _texels_per_unit(tex: Texture) -> float:
    """The most texels (a checkerboard's squares) one unit of surface (u, v) spans along u or v."""
    res = max(tex.data.shape[:2]) if tex.kind == "bitmap" else 2
    a = np.abs(np.asarray(tex.to_uv, dtype=np.float64)[:, :2])
    return float(res * a.sum(axis=0).max())


def _eval_mean(tex: Texture, uv: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """sum(weights * tex(uv)) / sum(weights) over points uv (N, 2), in chunks."""
    acc = np.zeros(3)
    for i in range(0, len(uv), _MEAN_CHUNK):
        acc += weights[i:i + _MEAN_CHUNK] @ tex.eval(uv[i:i + _MEAN_CHUNK])
    return acc / weights.sum()


def surface_mean_sphere(tex: Texture) -> tuple:
    """The mean of tex over a sphere by area, (u, v) = (phi / 2 pi, theta /
    pi) in its own frame (Sphere), where the area element is sin(pi v) du dv:
    the midpoint rule on a (u, v) grid of at least 8 points per texel row
    and 4 per texel column (at most MEAN_LOOKUPS in all), each row weighted
    by sin(pi v). Texture.mean weighs the rows alike, which overweights the
    poles' texels."""
    s = _texels_per_unit(tex)
    nv = int(np.clip(math.ceil(8 * s), 64, 4096))
    nu = int(np.clip(math.ceil(4 * s), 16, max(16, MEAN_LOOKUPS // nv)))
    u = (np.arange(nu) + 0.5) / nu
    v = (np.arange(nv) + 0.5) / nv
    uv = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)
    w = np.repeat(np.sin(np.pi * v), nu)
    return tuple(float(x) for x in _eval_mean(tex, uv, w))


def surface_mean_planar(tex: Texture, uv, areas, triangle: bool) -> tuple:
    """The mean of tex by area over planar primitives (quads or triangles)
    with areas (M,) and (u, v) maps uv (M, 3, 2) or (3, 2): the corner's,
    the change along edge u and along edge v. Within one primitive (u, v) is
    affine in its edge coordinates, so uniform by area is uniform over its
    (u, v) footprint: the midpoint rule on k x k equal cells (a triangle's:
    the centroids of its k^2 equal sub-triangles), k giving about 4 points
    per texel across the largest footprint (at most MEAN_LOOKUPS in all);
    the primitives' means weighted by their areas."""
    areas = np.asarray(areas, dtype=np.float64).reshape(-1)
    m = len(areas)
    uv = np.broadcast_to(np.asarray(uv, dtype=np.float64), (m, 3, 2))
    extent = float((np.abs(uv[:, 1]) + np.abs(uv[:, 2])).max()) if m else 0.0
    k = int(np.clip(math.ceil(4 * extent * _texels_per_unit(tex)), 1,
                    max(1, int(math.isqrt(max(1, MEAN_LOOKUPS // max(m, 1)))))))
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    i, j = i.reshape(-1), j.reshape(-1)
    if triangle:  # the sub-triangles pointing up (i + j < k) and down (i + j < k - 1)
        up, down = i + j < k, i + j < k - 1
        bu = np.concatenate([(i[up] + 1 / 3) / k, (i[down] + 2 / 3) / k])
        bv = np.concatenate([(j[up] + 1 / 3) / k, (j[down] + 2 / 3) / k])
    else:
        bu, bv = (i + 0.5) / k, (j + 0.5) / k
    n = len(bu)
    acc = np.zeros(3)
    step = max(1, _MEAN_CHUNK // n)
    for a in range(0, m, step):
        q = uv[a:a + step]
        pts = q[:, None, 0] + bu[None, :, None] * q[:, None, 1] + bv[None, :, None] * q[:, None, 2]
        vals = tex.eval(pts.reshape(-1, 2)).reshape(len(q), n, 3).mean(axis=1)
        acc += areas[a:a + step] @ vals
    return tuple(float(x) for x in acc / max(areas.sum(), 1e-300))


def wrap_index(i, n: int, mode: str) -> np.ndarray:
    """Integer texel indices (as floats) wrapped into [0, n)."""
    i = np.asarray(i, dtype=np.float64).astype(np.int64)
    if mode == "repeat":
        return np.mod(i, n)
    if mode == "clamp":
        return np.clip(i, 0, n - 1)
    k = np.mod(i, 2 * n)
    return np.where(k >= n, 2 * n - 1 - k, k)


def load_bitmap(path: Path, raw: bool = False) -> np.ndarray:
    """An image file as H x W x 3 linear float32 texels: grey repeated, alpha
    dropped; 8-bit (and other non-float) formats decoded from sRGB unless raw,
    as Mitsuba 3's bitmap texture does. An unreadable file raises ImageError or OSError."""
    img = np.asarray(load_image(path), dtype=np.float64)
    if img.ndim == 2:
        img = img[:, :, None]
    img = img[:, :, :3] if img.shape[2] >= 3 else np.repeat(img[:, :, :1], 3, axis=2)
    if not raw and Path(path).suffix.lower() not in LINEAR_SUFFIXES:
        img = srgb_to_linear(img)
    return img.astype(np.float32)


def device_bytes(textures, double: bool = False) -> int:
    """What the textures' texels take in the scene's records on the device."""
    return sum(t.texels for t in textures) * TEXEL_BYTES[bool(double)]
