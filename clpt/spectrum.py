"""Spectra to linear RGB, as Mitsuba 3's RGB variants convert them.

A tabulated spectrum (wavelengths in nm with values, linearly interpolated
between them and zero outside them) becomes CIE 1931 XYZ by a Riemann sum of
1000 evenly spaced samples over 360-830 nm against the colour matching
functions (clpt/data/cie1931_2deg.csv, interpolated linearly), scaled so that
a spectrum of ones has luminance Y = 1, and then linear sRGB (Rec. 709
primaries). Reflectances are weighted by the D65 illuminant (normalized to
luminance 1) and clamped to [0, 1]; emitted radiance is integrated as it is
and only clamped below at 0. A constant spectrum is a grey reflectance, or
for an emitter the colour of the equal-energy spectrum times the value.
"""

from __future__ import annotations

import difflib
import functools
import json
from pathlib import Path

import numpy as np

from .errors import SceneError

CIE_MIN, CIE_MAX = 360.0, 830.0
STEPS = 1000  # Riemann sum samples, as Mitsuba
# Luminance of the integrals of a spectrum of ones (Y) and of D65 (Y), for normalization.
Y_INTEGRAL = 106.7502593994140625
D65_Y_INTEGRAL = 98.99741751876255

XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                        [-0.969256, 1.875991, 0.041556],
                        [0.055648, -0.204043, 1.057311]])


@functools.lru_cache(maxsize=1)
def cie_tables():
    """(wavelengths (95,), xyz (95, 3), d65 (95,)) at 5 nm from 360 to 830 nm."""
    t = np.loadtxt(Path(__file__).resolve().parent / "data" / "cie1931_2deg.csv", delimiter=",", comments="#")
    return t[:, 0], t[:, 1:4], t[:, 4]


def _interp(x, xp, fp):
    return np.interp(x, xp, fp, left=0.0, right=0.0)


def spectrum_to_rgb(wavelengths, values, *, emitter: bool, bounded: bool | None = None) -> tuple[float, float, float]:
    """Linear sRGB of a tabulated spectrum: a reflectance (emitter=False: D65
    weighted, clamped to [0, 1]) or emitted radiance (unweighted, clamped at
    0). bounded=False leaves a non-emitter's values above 1 (as Mitsuba does
    for indices of refraction, eta and k)."""
    rgb, _ = spectrum_to_rgb_checked(wavelengths, values, emitter=emitter, bounded=bounded)
    return rgb


def spectrum_to_rgb_checked(wavelengths, values, *, emitter: bool, bounded: bool | None = None):
    """(rgb, clamped): as spectrum_to_rgb, and whether the colour was out of gamut."""
    if bounded is None:
        bounded = not emitter
    wl = np.asarray(wavelengths, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if wl.ndim != 1 or wl.shape != v.shape or len(wl) < 1:
        raise ValueError("a spectrum needs as many values as wavelengths, at least one")
    if not (np.isfinite(wl).all() and np.isfinite(v).all()):
        raise ValueError("spectrum wavelengths and values must be finite")
    if len(wl) > 1 and (np.diff(wl) <= 0).any():
        raise ValueError("spectrum wavelengths must increase")
    cw, xyz_t, d65_t = cie_tables()
    x = CIE_MIN + np.arange(STEPS) / (STEPS - 1) * (CIE_MAX - CIE_MIN)
    inside = (x >= wl[0]) & (x <= wl[-1])
    x = x[inside]
    y = np.interp(x, wl, v) if len(wl) > 1 else np.full_like(x, v[0])
    if not emitter:
        y = y * _interp(x, cw, d65_t) / D65_Y_INTEGRAL
    xyz = np.stack([_interp(x, cw, xyz_t[:, k]) for k in range(3)], axis=1)
    total = (xyz * y[:, None]).sum(axis=0) * ((CIE_MAX - CIE_MIN) / STEPS) / Y_INTEGRAL
    rgb = XYZ_TO_SRGB @ total
    clipped = np.clip(rgb, 0.0, 1.0 if bounded else None)
    return tuple(float(c) for c in clipped), bool((clipped != rgb).any())


def constant_spectrum_to_rgb(value: float, *, emitter: bool) -> tuple[float, float, float]:
    """A constant spectrum: grey for a reflectance; for emitted radiance the
    colour of the equal-energy spectrum (a little red, (1.205, 0.948, 0.909))
    times the value."""
    if not emitter:
        return (float(value),) * 3
    return spectrum_to_rgb([CIE_MIN, CIE_MAX], [value, value], emitter=True)


def parse_spectrum_pairs(text: str):
    """'400:0.343, 404:0.445, ...' -> (wavelengths, values). Raises ValueError."""
    wl, vals = [], []
    for item in text.replace("\n", " ").split(","):
        item = item.strip()
        if not item:
            continue
        if ":" not in item:
            raise ValueError(f"expected wavelength:value, got {item!r}")
        a, b = item.split(":", 1)
        try:
            wl.append(float(a))
            vals.append(float(b))
        except ValueError:
            raise ValueError(f"bad number in {item!r}") from None
    if not wl:
        raise ValueError("empty spectrum")
    return wl, vals


@functools.cache
def ior_data() -> dict:
    """Mitsuba 3's tables of named dielectrics ("ior") and conductors
    ("conductor": RGB eta and k), from clpt/data/mitsuba_ior.json."""
    return json.loads((Path(__file__).resolve().parent / "data" / "mitsuba_ior.json").read_text())


def conductor_ior(name: str) -> tuple:
    """(eta, k), RGB tuples, of a conductor Mitsuba 3 names ("none": eta 0,
    k 1, a perfect mirror)."""
    if name == "none":
        return (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)
    table = ior_data()["conductor"]
    if name not in table:
        close = difflib.get_close_matches(str(name), list(table), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise SceneError(f"unknown conductor {name!r}{hint}; known: none, {', '.join(table)}")
    return tuple(float(x) for x in table[name]["eta"]), tuple(float(x) for x in table[name]["k"])
