"""Furnace tests: closed enclosures with analytic radiance.

Inside a closed sphere or box whose walls emit Le and reflect a fraction rho of the
light arriving (diffusely, by a Phong lobe with n = 0, or as a mirror), every
pixel sees L = Le (1 + rho + rho^2 + ... + rho^d) for paths of up to d
scattering events, Le / (1 - rho) without limit. Lossless glass or mirror
objects inside it must be invisible. This checks unbiasedness of the whole
estimator (NEE bookkeeping, Russian roulette, lobe weights, Fresnel) at once.

Inside a sphere, light sampling has bounded weights (cos cos / d^2 = 1/(4 R^2)
between any two points of a sphere), so pixel means are near-normal and each
pixel is checked. In a box, weights grow without bound near the edges, where
walls meet; its per-sample distribution is heavy-tailed, so only the mean
over the image is checked there.
"""

import functools

import numpy as np
import pytest

import clpt

from stats import assert_mean_within

pytestmark = pytest.mark.portability

RES = 16


def furnace(wall: clpt.Material, *inside, le=1.0, room="sphere"):
    if room == "sphere":
        room = clpt.Sphere(center=(0, 0, 0), radius=1.5, material=wall, emission=(le, le, le), two_sided=True)
    else:
        room = clpt.Box(center=(0, 0, 0), size=(2, 2, 2), inward=True, material=wall, emission=(le, le, le))
    cam = clpt.Camera(origin=(0.1, -0.2, -0.3), target=(0.5, 0.3, 1.0), fov=100, width=RES, height=RES)
    return clpt.Scene(camera=cam, shapes=[room, *inside])


def check_uniform(res, expected, k=5.0, per_pixel=True):
    """Every channel's image mean within k sigma of `expected`, and every pixel too."""
    n = res.sample_count.astype(np.float64)
    var_pix = res.lum_var / n  # variance of each pixel's mean
    sigma_img = np.sqrt(var_pix.sum()) / var_pix.size
    for c in range(3):
        assert_mean_within(res.image[..., c].mean(), expected, sigma_img, k, what=f"image mean, channel {c}")
    # Plus float rounding (2e-5 relative): with light sampling, direct light in a
    # sphere is the same in every sample, and a pixel's variance can be exactly 0.
    z = np.abs(res.image[..., 0] - expected) / np.sqrt(var_pix + (2e-5 * expected) ** 2)
    assert not per_pixel or z.max() < 6.0, f"pixel {np.unravel_index(z.argmax(), z.shape)} is {z.max():.1f} sigma off"
    assert res.stats.nonfinite == 0 and np.isfinite(res.image).all()


WALLS = {
    "diffuse": clpt.Material(kd=(0.5, 0.5, 0.5)),
    "mirror": clpt.Material(kr=(0.5, 0.5, 0.5)),
}


@pytest.mark.parametrize("nee", [True, False])
@pytest.mark.parametrize("wall", list(WALLS))
def test_unlimited_depth(device_spec, wall, nee):
    r = clpt.Renderer(furnace(WALLS[wall]), device=device_spec, nee=nee)
    res = r.render(256, max_depth=1000, rr_depth=2, seed=1)
    check_uniform(res, 1.0 / (1.0 - 0.5))


@functools.lru_cache(maxsize=None)
def phong_albedo_table(n, res=600):
    c = np.linspace(0.0, 1.0, 33)
    return c, phong_albedo(c, n, 1.0, res)


def phong_albedo(cos_i, n, ks=1.0, res=600):
    """Directional albedo of the modified Phong lobe, ks (n+2)/(2 pi) cos^n(alpha)
    around the mirror direction, by midpoint quadrature over the hemisphere."""
    th = (np.arange(res) + 0.5) * (np.pi / 2 / res)
    ph = (np.arange(2 * res) + 0.5) * (np.pi / res)
    T, P = np.meshgrid(th, ph, indexing="ij")
    w = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    dA = np.sin(T) * (np.pi / 2 / res) * (np.pi / res)
    out = []
    for c in np.atleast_1d(cos_i):
        r = np.array([np.sqrt(max(0.0, 1 - c * c)), 0.0, c])  # mirror direction of the incoming ray
        ca = w @ r
        lobe = np.where(ca > 0, np.maximum(ca, 0.0) ** n, 0.0)  # the lobe is the hemisphere around r, also for n = 0
        out.append(ks * (n + 2) / (2 * np.pi) * (lobe * w[..., 2] * dA).sum())
    return np.array(out)


@pytest.mark.parametrize("nee", [True, False])
@pytest.mark.parametrize("n", [0.0, 1.0, 10.0, 100.0])
def test_phong_reflected_radiance(device_spec, n, nee):
    """One bounce in a Phong-walled sphere furnace: L = Le (1 + A(theta_i)),
    with A the lobe's directional albedo at each pixel's incidence angle (from
    the centre A = ks for every n). NEE on checks the BRDF evaluation, NEE off
    the lobe sampling and its weights."""
    ks = 0.8
    wall = clpt.Material(ks=(ks, ks, ks), shininess=n)
    scene = furnace(wall)
    cam = scene.camera
    res = clpt.Renderer(scene, device=device_spec, nee=nee).render(512, max_depth=1, seed=5)
    # Expected image: incidence angle per sub-pixel ray from the camera, via numpy.
    from clpt.pack import camera_frame
    fr = camera_frame(cam, RES, RES)
    sub = (np.arange(8) + 0.5) / 8
    px = (np.arange(RES)[:, None] + sub[None, :]).ravel()
    X, Y = np.meshgrid(px, px)
    d = fr.corner + X[..., None] * fr.dx + Y[..., None] * fr.dy
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o = np.array(cam.origin)
    b = d @ o
    t = -b + np.sqrt(b * b - (o @ o - 1.5 ** 2))
    cos_i = np.abs(((o + t[..., None] * d) / 1.5 * d).sum(-1))
    table_c, table_a = phong_albedo_table(n)
    a = ks * np.interp(cos_i, table_c, table_a)
    expected = (1.0 + a).reshape(RES, 8, RES, 8).mean(axis=(1, 3))
    n_s = res.sample_count
    var_pix = res.lum_var / n_s
    # Inside a sphere each NEE sample is exactly ks or 0, so a pixel can show
    # no variance at all; allow it one sample's worth of error.
    z = np.abs(res.image[..., 0] - expected) / np.sqrt(var_pix + (2 * ks / n_s) ** 2)
    assert z.max() < 6.0, f"pixel off by {z.max():.1f} sigma"
    sigma_img = np.sqrt(var_pix.sum()) / var_pix.size
    assert_mean_within(res.image[..., 0].mean(), expected.mean(), sigma_img, 5.0 + 1e-3 / sigma_img)


@pytest.mark.parametrize("n", [0.0, 10.0])
def test_phong_nee_and_bsdf_sampling_agree(device_spec, n):
    """With every depth, NEE and pure BSDF sampling estimate the same image."""
    wall = clpt.Material(kd=(0.3, 0.3, 0.3), ks=(0.4, 0.4, 0.4), shininess=n)
    out = []
    for nee in (True, False):
        res = clpt.Renderer(furnace(wall), device=device_spec, nee=nee).render(512, max_depth=1000, seed=6)
        var_pix = res.lum_var / res.sample_count
        out.append((res.image[..., 0].mean(), np.sqrt(var_pix.sum()) / var_pix.size))
        assert res.image.max() <= 1.0 / (1.0 - 0.7) + 6 * np.sqrt(var_pix.max())  # bounded by kd + ks
    (a, sa), (b, sb) = out
    assert_mean_within(a, b, np.hypot(sa, sb), 5.0, what="NEE vs BSDF sampling")


@pytest.mark.parametrize("nee", [True, False])
@pytest.mark.parametrize("wall", ["diffuse", "mirror"])
def test_box_room(device_spec, wall, nee):
    r = clpt.Renderer(furnace(WALLS[wall], room="box"), device=device_spec, nee=nee)
    res = r.render(512, max_depth=1000, rr_depth=2, seed=4)
    check_uniform(res, 2.0, per_pixel=False)


@pytest.mark.parametrize("nee", [True, False])
def test_depth_limits(device_spec, nee):
    r = clpt.Renderer(furnace(WALLS["diffuse"]), device=device_spec, nee=nee)
    for d in (0, 1, 2, 5):
        res = r.render(128, max_depth=d, rr_depth=1, seed=2)
        check_uniform(res, sum(0.5 ** k for k in range(d + 1)))


@pytest.mark.parametrize("obj", [
    clpt.Sphere(center=(0.4, 0.2, 0.5), radius=0.4, material=clpt.Material(kt=(1, 1, 1), ior=1.5)),
    clpt.Sphere(center=(0.4, 0.2, 0.5), radius=0.4, material=clpt.Material(kt=(1, 1, 1), ior=2.4)),
    clpt.Sphere(center=(0.4, 0.2, 0.5), radius=0.4, material=clpt.Material(kr=(1, 1, 1))),
    clpt.Box(center=(0.3, 0.1, 0.6), size=(0.5, 0.4, 0.3), rotation=(10, 30, 0),
             material=clpt.Material(kr=(0.4, 0.4, 0.4), kt=(0.6, 0.6, 0.6), ior=1.5)),
], ids=["glass", "diamond", "mirror", "dual_glass_box"])
def test_lossless_objects_are_invisible(device_spec, obj):
    """A lossless object in a furnace whose radiance is uniform is invisible."""
    r = clpt.Renderer(furnace(WALLS["diffuse"], obj), device=device_spec)
    res = r.render(256, max_depth=1000, rr_depth=2, seed=3)
    check_uniform(res, 2.0)
