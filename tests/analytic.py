"""Reference images computed in numpy: camera rays through sub-pixel grids,
and direct light from a sphere light on the floor plane y = 0."""

import math

import numpy as np

from clpt.pack import camera_frame


def sub_pixel_rays(cam, w, h, ss):
    """Unit directions through an ss x ss grid of points in every pixel: (h*ss, w*ss, 3)."""
    fr = camera_frame(cam, w, h)
    sub = (np.arange(ss) + 0.5) / ss
    px = (np.arange(w)[:, None] + sub[None, :]).ravel()
    py = (np.arange(h)[:, None] + sub[None, :]).ravel()
    X, Y = np.meshgrid(px, py)
    d = fr.corner + X[..., None] * fr.dx + Y[..., None] * fr.dy
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def pixel_average(values, w, h, ss):
    return values.reshape(h, ss, w, ss).mean(axis=(1, 3))


def sphere_light_on_floor(cam, w, h, ss, center, radius, le, rho, half_size=3.0):
    """Pixel means of the light a diffuse floor (albedo rho, y = 0, |x|, |z| <
    half_size) reflects from a sphere light wholly above its horizon:
    E = pi Le (r/D)^2 cos(theta), L = rho E / pi, over ss x ss points per pixel."""
    d = sub_pixel_rays(cam, w, h, ss)
    o = np.array(cam.origin, dtype=np.float64)
    t = -o[1] / d[..., 1]
    p = o + t[..., None] * d
    to_c = np.asarray(center, dtype=np.float64) - p
    dist = np.linalg.norm(to_c, axis=-1)
    e = math.pi * le * (radius / dist) ** 2 * (to_c[..., 1] / dist)
    on_floor = (t > 0) & (np.abs(p[..., 0]) < half_size) & (np.abs(p[..., 2]) < half_size)
    return pixel_average(rho / math.pi * np.where(on_floor, e, 0.0), w, h, ss)
