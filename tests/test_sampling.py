"""Sampling routines (kernels/sampling.h) against the densities they state:
chi-square tests of the sample histograms, sample/pdf agreement, edge inputs."""

import math

import numpy as np
import pytest

from stats import ALPHA, chi2_test, sidak

pytestmark = pytest.mark.portability

N = 200_000
LANES = (1, 8)


def uniforms(seed, n=N):
    rng = np.random.default_rng(seed)
    return rng.random(n, dtype=np.float32), rng.random(n, dtype=np.float32)


def hist2(z, phi, z_edges, n_phi):
    h, _, _ = np.histogram2d(z, phi, bins=[z_edges, np.linspace(-math.pi, math.pi, n_phi + 1)])
    return h


def check_zphi(x, y, z, z_cdf, z_edges, n_phi, trials):
    """Histogram over (z, phi); expected mass per z band from the analytic CDF,
    spread evenly over phi."""
    phi = np.arctan2(y, x)
    h = hist2(z, phi, z_edges, n_phi)
    band = np.diff(z_cdf(z_edges))
    expected = np.outer(band, np.full(n_phi, 1.0 / n_phi)) * len(z)
    p, stat, dof = chi2_test(h, expected)
    assert p > sidak(ALPHA, trials), f"chi2 {stat:.1f} for {dof} dof, p = {p:.3g}"


@pytest.mark.parametrize("lanes", LANES)
def test_cosine_hemisphere(probes, lanes):
    u1, u2 = uniforms(1)
    x, y, z, pdf = probes(lanes).run("probe_cosine_hemisphere", [u1, u2], 4)
    assert np.allclose(x * x + y * y + z * z, 1, atol=1e-5)
    assert (z >= 0).all()
    # pdf_sa = cos/pi: the z CDF is z^2.
    check_zphi(x, y, z, lambda e: e ** 2, np.linspace(0, 1, 31), 61, trials=len(LANES))
    assert np.allclose(pdf, z / math.pi, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("lanes", LANES)
@pytest.mark.parametrize("n", [0.0, 1.0, 10.0, 1000.0, 1e6])
def test_phong_lobe(probes, lanes, n):
    u1, u2 = uniforms(2)
    x, y, z, pdf = probes(lanes).run("probe_phong_lobe", [u1, u2], 4, scalars_after=(np.float32(n),))
    assert np.isfinite(x).all() and np.isfinite(pdf).all()
    assert np.allclose(x * x + y * y + z * z, 1, atol=1e-5)
    # pdf_sa = (n+1)/(2 pi) z^n over z in [0, 1]: z^(n+1) is uniform. For large
    # n, z rounds to 1 in float, so test the (accurate) sin^2 = x^2 + y^2 instead:
    # 1 - z = 1 - u^(1/(n+1)) ~ -log(u)/(n+1).
    s2 = (x.astype(np.float64) ** 2 + y.astype(np.float64) ** 2)
    omz = s2 / (1 + np.sqrt(np.maximum(1 - s2, 0)))  # 1 - z without cancellation
    w = np.exp((n + 1) * np.log1p(-np.minimum(omz, 1 - 1e-16)))  # z^(n+1)
    check_zphi(x, y, w, lambda e: e, np.linspace(0, 1, 31), 41, trials=2 * 5)
    zz = np.where(z < 0.5, z.astype(np.float64), 1 - omz)  # each form where it is accurate
    ref_pdf = (n + 1) / (2 * math.pi) * np.exp(n * np.log(np.maximum(zz, 1e-300)))
    # The pdf is evaluated from the float cosine, whose rounding (6e-8) moves
    # cos^n by ~n * 6e-8: 6% at n = 1e6, where only the direction is checked.
    if n <= 1000:
        assert np.allclose(pdf, ref_pdf, rtol=2e-3)


@pytest.mark.parametrize("omc", [1.0, 0.3, 1e-3, 1e-9])
def test_uniform_cone(probes, omc):
    u1, u2 = uniforms(3)
    x, y, z = probes(8).run("probe_uniform_cone", [u1, u2], 3, scalars_after=(np.float32(omc),))
    s2 = x.astype(np.float64) ** 2 + y.astype(np.float64) ** 2
    assert np.isfinite(s2).all() and np.allclose(s2 + z.astype(np.float64) ** 2, 1, atol=1e-5)
    # 1 - cos(theta) is uniform on [0, omc]; sin^2 = k (2 - k) with k = 1 - cos.
    k = s2 / (1 + np.sqrt(np.maximum(1 - s2, 0)))
    check_zphi(x, y, k / omc, lambda e: e, np.linspace(0, 1, 21), 31, trials=4)


def test_uniform_sphere(probes):
    u1, u2 = uniforms(4)
    x, y, z = probes(8).run("probe_uniform_sphere", [u1, u2], 3)
    assert np.allclose(x * x + y * y + z * z, 1, atol=1e-5)
    check_zphi(x, y, z, lambda e: (e + 1) / 2, np.linspace(-1, 1, 31), 61, trials=1)


def test_uniform_triangle(probes):
    u1, u2 = uniforms(5)
    b1, b2 = probes(8).run("probe_uniform_triangle", [u1, u2], 2)
    assert (b1 >= 0).all() and (b2 >= 0).all() and (b1 + b2 <= 1 + 1e-6).all()
    m = 24
    h, _, _ = np.histogram2d(b1, b2, bins=[np.linspace(0, 1, m + 1)] * 2)
    # Expected: area of each cell inside b1 + b2 <= 1, over the triangle's 1/2.
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    area = np.where(i + j < m - 1, 1.0, np.where(i + j == m - 1, 0.5, 0.0)) / m ** 2
    mask = area > 0
    p, stat, dof = chi2_test(h[mask], area[mask] / 0.5 * len(b1))
    assert p > ALPHA, f"chi2 {stat:.1f} for {dof} dof, p = {p:.3g}"
    assert h[~mask].sum() == 0


@pytest.mark.parametrize("name,n_in,n_out,extra", [
    ("probe_cosine_hemisphere", 2, 4, ()),
    ("probe_phong_lobe", 2, 4, (np.float32(50.0),)),
    ("probe_uniform_cone", 2, 3, (np.float32(1e-6),)),
    ("probe_uniform_sphere", 2, 3, ()),
])
def test_edge_inputs_are_finite(probes, name, n_in, n_out, extra):
    edge = np.array([0.0, 1 - 2 ** -24, 0.5, 0.0, 1 - 2 ** -24], dtype=np.float32)
    other = np.array([0.0, 1 - 2 ** -24, 0.0, 1 - 2 ** -24, 0.0], dtype=np.float32)
    outs = probes(1).run(name, [edge, other], n_out, scalars_after=extra)
    for o in outs:
        assert np.isfinite(o).all()
    x, y, z = outs[:3]
    assert np.allclose(x * x + y * y + z * z, 1, atol=1e-5)


def test_lanes_agree(probes):
    """The scalar and 8-lane builds compute the same samples."""
    u1, u2 = uniforms(6, 4096)
    a = probes(1).run("probe_phong_lobe", [u1, u2], 4, scalars_after=(np.float32(20.0),))
    b = probes(8).run("probe_phong_lobe", [u1, u2], 4, scalars_after=(np.float32(20.0),))
    for x, y in zip(a, b):
        assert np.allclose(x, y, rtol=1e-5, atol=1e-6)


def test_frame_is_orthonormal(probes):
    rng = np.random.default_rng(7)
    n = rng.normal(size=(10000, 3))
    n = np.vstack([n, [[0, 0, 1], [0, 0, -1], [0, 0, -1 + 1e-7], [1, 0, 0], [0, -1, 0]]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t = probes(8).run("probe_frame", [n[:, 0], n[:, 1], n[:, 2]], 6)
    tv, bv = np.stack(t[:3], 1).astype(np.float64), np.stack(t[3:], 1).astype(np.float64)
    for a, b in ((tv, bv), (tv, n), (bv, n)):
        assert np.abs((a * b).sum(1)).max() < 1e-5
    assert np.allclose(np.linalg.norm(tv, axis=1), 1, atol=1e-5)
    assert np.allclose(np.linalg.norm(bv, axis=1), 1, atol=1e-5)
    assert np.allclose(np.cross(tv, bv), n, atol=1e-5)  # right-handed


@np.errstate(invalid="ignore", divide="ignore")
def fresnel_ref(cos_i, eta):
    sin2_t = (1 - cos_i ** 2) / eta ** 2
    tir = sin2_t >= 1
    cos_t = np.sqrt(np.maximum(1 - sin2_t, 0))
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    f = 0.5 * (rs ** 2 + rp ** 2)
    return np.where(tir, 1.0, f), cos_t


@pytest.mark.parametrize("double", [False, True])
def test_fresnel(probes, double):
    cos_i = np.repeat(np.linspace(0.0, 1.0, 101), 7)
    eta = np.tile(np.array([1.0001, 1.33, 1.5, 2.4, 10.0, 1 / 1.5, 1 / 2.4]), 101)
    f, cos_t = probes(8, double).run("probe_fresnel", [cos_i, eta], 2)
    ref, ref_ct = fresnel_ref(cos_i, eta)
    assert np.isfinite(f).all() and (f >= 0).all() and (f <= 1).all()
    ok = np.abs(cos_i) > 1e-6  # at exactly grazing incidence F = 1 in the limit
    # Near grazing with eta ~ 1, 1 - sin^2 cancels: float keeps ~1e-4 there.
    tol = 1e-9 if double else 1e-4
    assert np.allclose(f[ok], ref[ok], atol=tol)
    assert np.allclose(f[~ok & (eta != 1)], 1.0, atol=tol)
    # Spot values: normal incidence ((eta-1)/(eta+1))^2; total internal reflection.
    f0, _ = probes(1).run("probe_fresnel", [np.array([1.0, 1.0, 0.5]), np.array([1.5, 1.0, 1 / 1.5])], 2)
    assert f0[0] == pytest.approx(0.04, abs=1e-6)
    assert f0[1] == 0.0  # no interface
    assert f0[2] == 1.0  # sin_t = sin(60 deg) * 1.5 > 1


def test_refraction_obeys_snell(probes):
    rng = np.random.default_rng(8)
    n = np.tile([0.0, 0.0, 1.0], (2000, 1))
    d = rng.normal(size=(2000, 3))
    d[:, 2] = -np.abs(d[:, 2]) - 0.05
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    eta = rng.uniform(1.01, 3.0, 2000)
    w = probes(8).run("probe_refract", [d[:, 0], d[:, 1], d[:, 2], n[:, 0], n[:, 1], n[:, 2], eta], 3)
    w = np.stack(w, 1).astype(np.float64)
    assert np.allclose(np.linalg.norm(w, axis=1), 1, atol=1e-5)
    sin_i = np.linalg.norm(d[:, :2], axis=1)
    sin_t = np.linalg.norm(w[:, :2], axis=1)
    assert np.allclose(sin_i, eta * sin_t, atol=1e-5)  # Snell: n_i sin_i = n_t sin_t
    assert (w[:, 2] < 0).all()  # continues through the surface
    # In the plane of incidence: same azimuth.
    cross_z = d[:, 0] * w[:, 1] - d[:, 1] * w[:, 0]
    assert np.allclose(cross_z / np.maximum(sin_i * sin_t, 1e-9), 0, atol=1e-4)
