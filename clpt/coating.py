"""Host-side tables of Mitsuba 3's `plastic` and `roughplastic` (a dielectric
coating over a diffuse base), which kernels/bsdf.h evaluates.

A rough coating needs, per material, its specular transmittance t(mu) from
outside at cos theta = mu (TABLE_RES values at mu = linspace(0, 1), mu at
least 1e-6; read by linear interpolation, as Mitsuba's `lerp_gather`) and the
internal reflectance that the diffuse light meets from below (Mitsuba's
`m_internal_reflectance`: the reflectance from inside, eta -> 1 / eta,
cosine-weighted over the same nodes). Both are integrals over the visible
microfacet normals,

    t(wi) = int D_wi(m) (1 - F(wi.m)) G1(wt, m) dm,   wt refracted about m,
    r(wi) = int D_wi(m) F(wi.m) G1(wr, m) dm,          wr reflected about m,

with D_wi(m) = G1(wi, m) max(0, wi.m) D(m) / cos_i. They are computed as
Mitsuba computes them, so that the tables are Mitsuba's: a 32x32 (128x128
from inside) Gauss-Legendre rule over its visible-normal sampler (the same
mapping of (u1, u2) to normals, ported to numpy). That rule is off the
converged integral by up to about 0.5% at grazing angles; matching Mitsuba
means keeping its error. A smooth coating needs only Mitsuba's fitted
diffuse Fresnel reflectance (`fresnel_diffuse_reflectance`) of 1 / eta.
"""

from __future__ import annotations

import functools

import numpy as np

TABLE_RES = 64    # Mitsuba's MI_ROUGH_TRANSMITTANCE_RES


def fresnel_diffuse_reflectance(eta: float) -> float:
    """Mitsuba 3's fit of the diffuse Fresnel reflectance seen from the side
    with relative index eta (Egan and Hilgeman below 1, d'Eon and Irving above)."""
    inv = 1.0 / eta
    if eta < 1.0:
        return 0.0636 * inv + eta * (eta * -1.4399 + 0.7099) + 0.6681
    return float(np.polyval([-1.36881, 4.98554, -7.80989, 6.75335, -3.4793, 0.919317], inv))


def _fresnel(c, eta):
    """(F, cos_t) of a dielectric at cos c >= 0 (from the side where the index ratio is eta)."""
    s2t = (1 - c * c) / (eta * eta)
    ct = np.sqrt(np.maximum(1 - s2t, 0.0))
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    F = np.where(s2t >= 1, 1.0, 0.5 * (rs * rs + rp * rp))
    return F, ct


def _g1(v, m, alpha, beckmann):
    """Smith G1 of direction v (..., 3) against normal m (Mitsuba's, Beckmann's rational fit)."""
    xy = alpha * alpha * (v[..., 0] ** 2 + v[..., 1] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        tan2 = xy / (v[..., 2] ** 2)
        if beckmann:
            a = 1 / np.sqrt(tan2)
            r = np.where(a >= 1.6, 1.0, (3.535 * a + 2.181 * a * a) / (1 + 2.276 * a + 2.577 * a * a))
        else:
            r = 2 / (1 + np.sqrt(1 + tan2))
    r = np.where(xy == 0, 1.0, r)
    return np.where(np.sum(v * m, -1) * v[..., 2] <= 0, 0.0, r)


def _erf(x):
    """erf (Abramowitz and Stegun 7.1.26; absolute error below 1.5e-7, float's)."""
    t = 1.0 / (1.0 + 0.3275911 * np.abs(x))
    y = 1.0 - ((((1.061405429 * t - 1.453152027) * t + 1.421413741) * t - 0.284496736) * t + 0.254829592) * t * \
        np.exp(-x * x)
    return np.sign(x) * y


def _erfinv(x):
    """Inverse error function (Giles' single-precision approximation, as kernels/microfacet.h)."""
    x = np.clip(x, -0.99999, 0.99999)
    w = -np.log((1 - x) * (1 + x))
    w1, w2 = w - 2.5, np.sqrt(w) - 3.0
    p1 = np.polyval([2.81022636e-08, 3.43273939e-07, -3.5233877e-06, -4.39150654e-06, 0.00021858087,
                     -0.00125372503, -0.00417768164, 0.246640727, 1.50140941], w1)
    p2 = np.polyval([-0.000200214257, 0.000100950558, 0.00134934322, -0.00367342844, 0.00573950773,
                     -0.0076224613, 0.00943887047, 1.00167406, 2.83297682], w2)
    return np.where(w < 5, p1, p2) * x


def _slopes(ci, u1, u2, beckmann):
    """Mitsuba 3's sample_visible_11: a visible slope of the unit-roughness
    distribution seen from cos theta = ci (azimuth 0)."""
    if beckmann:
        tan_i = np.sqrt(np.maximum(1 - ci * ci, 0)) / ci
        with np.errstate(divide="ignore"):
            cot_i = 1 / tan_i
        maxval = _erf(cot_i)
        u1 = np.clip(u1, 1e-6, 1 - 1e-6)
        u2 = np.clip(u2, 1e-6, 1 - 1e-6)
        x = maxval - (maxval + 1) * _erf(np.sqrt(-np.log(u1)))
        u1 = u1 * (1 + maxval + tan_i * np.exp(-cot_i * cot_i) / np.sqrt(np.pi))
        for _ in range(3):
            slope = _erfinv(x)
            value = 1 + x + tan_i * np.exp(-slope * slope) / np.sqrt(np.pi) - u1
            x = x - value / (1 - slope * tan_i)
        return _erfinv(x), _erfinv(2 * u2 - 1)
    # GGX: a concentric disk point projected onto the visible half.
    a, b = 2 * u1 - 1, 2 * u2 - 1
    q13 = np.abs(a) < np.abs(b)
    r, rp = np.where(q13, b, a), np.where(q13, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = 0.25 * np.pi * rp / r
    phi = np.where(q13, 0.5 * np.pi - phi, phi)
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    px, py = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1 + ci)
    py = np.sqrt(np.maximum(1 - px * px, 0)) + (py - np.sqrt(np.maximum(1 - px * px, 0))) * s
    pz = np.sqrt(np.maximum(1 - px * px - py * py, 0))
    si = np.sqrt(np.maximum(1 - ci * ci, 0))
    norm = 1 / (si * py + ci * pz)
    return (ci * py - si * pz) * norm, px * norm


def _integrals(alpha: float, beckmann: bool, eta: float, mu: np.ndarray, transmit: bool):
    """Mitsuba 3's eval_transmittance / eval_reflectance: the Gauss-Legendre
    product rule (32 x 32 nodes for eta > 1, else 128 x 128) over its
    visible-normal sampler, for incident directions (sqrt(1 - mu^2), 0, mu)."""
    res = 32 if eta > 1 else 128
    x, w = np.polynomial.legendre.leggauss(res)
    u1, u2 = np.meshgrid(0.5 * x + 0.5, 0.5 * x + 0.5, indexing="ij")
    ww = np.outer(w, w).ravel() * 0.25
    u1, u2 = u1.ravel()[None], u2.ravel()[None]
    wi = np.stack([np.sqrt(1 - mu * mu), np.zeros_like(mu), mu], -1)           # (k, 3)
    # Stretch wi (its azimuth is 0), draw slopes, unstretch.
    st = np.stack([alpha * wi[:, 0], np.zeros_like(mu), mu], -1)
    st /= np.linalg.norm(st, axis=1, keepdims=True)
    sx, sy = np.broadcast_arrays(*_slopes(st[:, 2:3], u1, u2, beckmann))
    m = np.stack([-sx * alpha, -sy * alpha, np.ones_like(sx)], -1)
    m /= np.linalg.norm(m, axis=-1, keepdims=True)                               # (k, n, 3)
    wi3 = wi[:, None, :]
    c = np.sum(wi3 * m, -1)
    F, cos_t = _fresnel(np.maximum(c, 0.0), eta)
    if transmit:
        inv = 1.0 / eta
        wo = -inv * wi3 + m * (inv * c - cos_t)[..., None]
        val = (1 - F) * _g1(wo, m, alpha, beckmann)
        val = np.where(wo[..., 2] * wi3[..., 2] >= 0, 0.0, val)
    else:
        wo = 2 * c[..., None] * m - wi3
        val = F * _g1(wo, m, alpha, beckmann)
        val = np.where(wo[..., 2] <= 0, 0.0, val)
    return np.sum(np.nan_to_num(val) * ww[None], -1)


@functools.lru_cache(maxsize=256)
def rough_tables(alpha: float, distribution: str, eta: float) -> tuple[tuple, float]:
    """(t(mu) at TABLE_RES values of mu, internal reflectance) of a rough
    coating of roughness alpha and relative index eta (inside over outside)."""
    beckmann = distribution == "beckmann"
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, TABLE_RES))
    t = _integrals(alpha, beckmann, eta, mu, True)
    r = _integrals(alpha, beckmann, 1.0 / eta, mu, False)
    return tuple(float(x) for x in t), float(np.mean(r * 2.0 * mu))


def lerp_table(table, mu):
    """The kernels' (and Mitsuba's) linear interpolation of a TABLE_RES table at mu in [0, 1]."""
    table = np.asarray(table)
    x = np.asarray(mu, dtype=np.float64) * (TABLE_RES - 1)
    i = np.minimum(x.astype(np.int64), TABLE_RES - 2)
    return table[i] + (table[i + 1] - table[i]) * (x - i)
