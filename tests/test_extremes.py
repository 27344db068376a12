"""Numerical stability at the extremes: scene scale and position, light
intensity, Phong exponents, indices of refraction, tiny and huge lights, path
depths, sample counts, image shapes, photon-map settings and odd cameras.

Every render here must be finite (no NaN or inf pixel, no sample dropped as
non-finite, a finite variance) and must also show a property that holds at the
extreme: an analytic value, an exact relation between two renders with the
same seed, or agreement with a reference render within noise. Noise is
measured, never guessed: RenderResult.lum_var / sample_count is the variance
of a pixel's mean luminance, so the sigma of a mean over pixels is
sqrt(sum(lum_var / n)) / pixels, and two estimates must agree within K = 5 of
their combined sigma (6 per pixel, as in test_furnace, for the 256 pixels of
an image).

Tests marked xfail(strict=True) show real bugs; their reasons name the cause.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

import clpt
from clpt.constants import LUMA
from clpt.pack import camera_frame

from analytic import pixel_average, sphere_light_on_floor, sub_pixel_rays
from stats import assert_mean_within
from test_furnace import furnace

K = 5.0        # sigmas allowed for a mean over an image or a block of pixels
K_PIXEL = 6.0  # sigmas allowed for one pixel among a few hundred
W = 16         # default image side


# --- helpers -----------------------------------------------------------------------


def lum(img):
    return np.asarray(img, dtype=np.float64) @ LUMA


def pixel_var(res):
    """Variance of each pixel's mean luminance."""
    return res.lum_var.astype(np.float64) / np.maximum(res.sample_count, 1)


def image_sigma(res):
    v = pixel_var(res)
    return math.sqrt(v.sum()) / v.size


def assert_finite(res):
    assert np.isfinite(res.image).all(), f"{int((~np.isfinite(res.image)).sum())} non-finite pixel values"
    assert res.stats.nonfinite == 0, f"{res.stats.nonfinite} non-finite samples were dropped"
    assert np.isfinite(res.lum_var).all(), "non-finite per-pixel variance"


def assert_same_image(la, va, lb, vb, what, block=4, k=K, k_pixel=K_PIXEL, rel_floor=1e-6):
    """Luminance images la and lb (per-pixel variances of their means va, vb)
    estimate the same image: the image means, the means of block x block
    tiles and every pixel agree within noise. rel_floor adds float rounding
    (relative) to the sigmas, for pixels without any variance."""
    la, lb, va, vb = (np.asarray(a, dtype=np.float64) for a in (la, lb, va, vb))
    n = la.size
    assert_mean_within(la.mean(), lb.mean(), math.sqrt(va.sum() + vb.sum()) / n + rel_floor * abs(lb.mean()), k,
                       what=f"{what}: image mean")
    h, w = la.shape
    if h % block == 0 and w % block == 0 and h > block:
        tiles = lambda a: a.reshape(h // block, block, w // block, block).sum(axis=(1, 3))  # noqa: E731
        d = tiles(la) - tiles(lb)
        s = np.sqrt(tiles(va) + tiles(vb)) + rel_floor * np.abs(tiles(lb))
        z = np.abs(d) / np.maximum(s, 1e-300)
        i = np.unravel_index(z.argmax(), z.shape)
        assert z.max() <= k, f"{what}: {block}x{block} block {i} differs by {z.max():.1f} sigma"
    s = np.sqrt(va + vb) + rel_floor * np.abs(lb)
    z = np.abs(la - lb) / np.maximum(s, 1e-300)
    i = np.unravel_index(z.argmax(), z.shape)
    assert z.max() <= k_pixel, (f"{what}: pixel {i} is {la[i]:.4g} vs {lb[i]:.4g}, {z.max():.1f} sigma apart "
                                f"(acne, a leak or a bias)")


def assert_same_render(a, b, what, **kw):
    assert_same_image(lum(a.image), pixel_var(a), lum(b.image), pixel_var(b), what, **kw)


def transform(scene, s=1.0, t=(0.0, 0.0, 0.0)):
    """The scene scaled by s about the origin, then moved by t: every point and
    edge, the camera's origin and target, sphere radii; radiance unchanged."""
    t = np.asarray(t, dtype=np.float64)
    pt = lambda p: tuple(float(x) for x in np.asarray(p, dtype=np.float64) * s + t)  # noqa: E731
    vec = lambda v: tuple(float(x) for x in np.asarray(v, dtype=np.float64) * s)  # noqa: E731
    shapes = []
    for sh in scene.shapes:
        if isinstance(sh, clpt.Quad):
            shapes.append(replace(sh, corner=pt(sh.corner), edge_u=vec(sh.edge_u), edge_v=vec(sh.edge_v)))
        elif isinstance(sh, clpt.Sphere):
            shapes.append(replace(sh, center=pt(sh.center), radius=sh.radius * s))
        elif isinstance(sh, clpt.Triangle):
            shapes.append(replace(sh, vertices=tuple(pt(v) for v in sh.vertices)))
        else:
            raise NotImplementedError(type(sh).__name__)
    cam = replace(scene.camera, origin=pt(scene.camera.origin), target=pt(scene.camera.target))
    return replace(scene, shapes=shapes, camera=cam)


def scale_emission(scene, k):
    return replace(scene, shapes=[replace(sh, emission=tuple(k * e for e in sh.emission))
                                  if sh.emission is not None else sh for sh in scene.shapes])


# --- shared scenes and renderers ------------------------------------------------------


@pytest.fixture(scope="module")
def cbox_scene():
    return clpt.load_scene("cornell_box")


@pytest.fixture(scope="module")
def cbox(cbox_scene, device_spec):
    return clpt.Renderer(cbox_scene, device=device_spec)


_REF = {}


@pytest.fixture(scope="module")
def cbox_ref(cbox):
    """Reference Cornell box renders (16x16, 256 spp, seed 1) by max depth."""
    def get(max_depth):
        if max_depth not in _REF:
            _REF[max_depth] = cbox.render(256, width=W, height=W, seed=1, max_depth=max_depth)
        return _REF[max_depth]
    return get


# --- scale and position -------------------------------------------------------------------


@pytest.mark.parametrize("max_depth", [1, 8])
@pytest.mark.parametrize("s,t,precision", [
    (1e-4, (0, 0, 0), "float"),
    (1e4, (0, 0, 0), "float"),
    (1.0, (1e4, 1e4, 1e4), "float"),
    (1e-4, (0, 0, 0), "double"),
    (1.0, (1e4, 1e4, 1e4), "double"),
], ids=["x1e-4", "x1e4", "moved1e4", "x1e-4-double", "moved1e4-double"])
def test_cornell_box_scaled_or_moved_renders_the_same(device_spec, cbox_scene, cbox_ref, s, t, precision, max_depth):
    """The Cornell box scaled by 1e-4 or 1e4, or moved 1e4 away from the
    origin, with radiance unchanged, is the same image: its mean, its 4x4
    blocks and every pixel agree with the unscaled render within noise. Self
    intersection would show as dark speckles (acne) and gaps at the walls'
    edges as light leaks, both as pixels many sigma off; max depth 1 (direct
    light: shadow rays) is where acne shows most."""
    ref = cbox_ref(max_depth)
    r = clpt.Renderer(transform(cbox_scene, s, t), device=device_spec, precision=precision)
    res = r.render(256, width=W, height=W, seed=1, max_depth=max_depth)
    assert_finite(res)
    assert res.image.min() >= 0.0
    assert_same_render(res, ref, f"scale {s}, offset {t}, {precision}")


# --- intensity ----------------------------------------------------------------------------------


@pytest.mark.parametrize("k", [1e-25, 1e-6, 1e6, 1e25])
def test_emission_scales_linearly(device_spec, cbox_scene, k):
    """Light emission scaled by k, from 1e-25 to 1e25: with the same seed
    every path is the same, so every pixel scales by exactly k (to float
    rounding, checked at 1e-4 relative) and its variance by k^2 (the kernels
    square luminance scaled to the brightest emission, so neither overflows
    nor goes subnormal)."""
    ref = clpt.Renderer(cbox_scene, device=device_spec).render(16, width=W, height=W, seed=3)
    res = clpt.Renderer(scale_emission(cbox_scene, k), device=device_spec).render(16, width=W, height=W, seed=3)
    assert_finite(res)
    lit = ref.image > 0
    assert (res.image[~lit] == 0).all()
    ratio = res.image[lit].astype(np.float64) / k / ref.image[lit]
    assert np.abs(ratio - 1).max() < 1e-4, f"image / k differs from the reference by {np.abs(ratio - 1).max():.3g}"
    noisy = ref.lum_var > 0
    vr = res.lum_var[noisy].astype(np.float64) / k ** 2 / ref.lum_var[noisy]
    assert np.abs(vr - 1).max() < 1e-3, f"lum_var / k^2 differs from the reference by {np.abs(vr - 1).max():.3g}"


@pytest.mark.parametrize("k", [1e-40, 1e31, 1e39])
def test_emission_beyond_float_range_is_rejected(device_spec, cbox_scene, k):
    """An emission of 1e39 cannot be represented in float32 (max 3.4e38), one
    of 1e31 leaves no room for sums of samples, and 1e-40 is subnormal: the
    scene is rejected with a SceneError naming the emission rather than
    rendered black or infinite."""
    with pytest.raises(clpt.SceneError, match="emission"):
        r = clpt.Renderer(scale_emission(cbox_scene, k), device=device_spec)
        r.render(4, width=8, height=8, seed=1)


# --- Phong exponents ------------------------------------------------------------------------------


@pytest.mark.parametrize("nee", [True, False])
@pytest.mark.parametrize("n", [0.0, 1.0, 1e3, 1e6])
def test_phong_furnace_energy_bounded(device_spec, n, nee):
    """A closed sphere whose walls emit Le and reflect by a Phong lobe of ks
    (directional albedo at most ks for every n) shows Le <= L <= Le / (1 - ks):
    every sample sees Le directly, and the image mean stays below the bound
    within noise, for exponents from 0 to 1e6."""
    ks, le = 0.5, 1.0
    r = clpt.Renderer(furnace(clpt.Material(ks=(ks,) * 3, shininess=n), le=le), device=device_spec, nee=nee)
    res = r.render(256, max_depth=1000, seed=1)
    assert_finite(res)
    assert res.image.min() >= le * (1 - 1e-6), f"a pixel is below the emission: {res.image.min()}"
    sigma = image_sigma(res)
    for c in range(3):
        m = float(res.image[..., c].mean())
        assert m <= le / (1 - ks) + K * sigma, f"channel {c}: {m:.5g} > Le / (1 - ks) = {le / (1 - ks)} + {K} sigma"


def _ball_in_lit_void(ball: clpt.Material):
    """A ball of radius 0.5 inside a large black sphere that emits 1 on both
    sides (and reflects nothing): a mirror ball shows 1 everywhere."""
    env = clpt.Sphere(center=(0, 0, 0), radius=5.0, material=clpt.Material(), emission=(1, 1, 1), two_sided=True)
    cam = clpt.Camera(origin=(0, 0, 2.0), target=(0, 0, 0), fov=30, width=W, height=W)
    return clpt.Scene(camera=cam, shapes=[env, clpt.Sphere(center=(0, 0, 0), radius=0.5, material=ball)])


def _ball_cosine(cam, ss):
    """cos(theta_i) of each sub-pixel ray at the ball (radius 0.5 at the origin), or NaN for a miss."""
    d = sub_pixel_rays(cam, W, W, ss)
    o = np.array(cam.origin, dtype=np.float64)
    b = d @ o
    disc = b * b - (o @ o - 0.25)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    p = o + t[..., None] * d
    return np.where(disc > 0, np.abs((p / 0.5 * d).sum(-1)), np.nan)


@pytest.mark.parametrize("nee", [False, True])
def test_phong_ball_of_huge_exponent_approaches_mirror_ball(device_spec, nee):
    """A Phong ball of ks = 1 and n = 1e6 reflects like a mirror ball, but the
    modified Phong BRDF (f = ks (n+2)/(2 pi) cos^n) has directional albedo
    ks (n+2)/(n+1) cos(theta_i) for a narrow lobe, not the mirror's kr: in a
    uniform environment of radiance 1 the mirror ball shows exactly 1 and the
    Phong ball cos(theta_i), pixel by pixel, within noise plus the error of
    the sub-pixel quadrature of the reference."""
    n = 1e6
    mirror = clpt.Renderer(_ball_in_lit_void(clpt.Material(kr=(1, 1, 1))), device=device_spec, photons=False)
    m = mirror.render(64, seed=1, max_depth=8)
    assert_finite(m)
    assert np.allclose(m.image, 1.0, rtol=1e-6, atol=0), "a lossless mirror in a uniform environment must vanish"
    scene = _ball_in_lit_void(clpt.Material(ks=(1, 1, 1), shininess=n))
    res = clpt.Renderer(scene, device=device_spec, nee=nee).render(256, seed=1, max_depth=8)
    assert_finite(res)
    albedo = lambda c: np.where(np.isnan(c), 1.0, c * (n + 2) / (n + 1))  # noqa: E731  (miss: the environment)
    exp_fine = pixel_average(albedo(_ball_cosine(scene.camera, 32)), W, W, 32)
    exp_coarse = pixel_average(albedo(_ball_cosine(scene.camera, 16)), W, W, 16)
    quad_err = 2 * np.abs(exp_fine - exp_coarse)
    expected = exp_fine * m.image[..., 0]  # the mirror ball's image times cos(theta_i)
    v = pixel_var(res)
    img = res.image[..., 0].astype(np.float64)
    assert_mean_within(img.mean(), expected.mean(), math.sqrt(v.sum()) / v.size + quad_err.mean(), K,
                       what="Phong n=1e6 ball vs mirror ball x cos(theta_i)")
    # A pixel the silhouette barely crosses may draw no sample on the ball and
    # show no variance: allow it one sample's worth (samples lie in [0, 1]).
    z = np.abs(img - expected) / (np.sqrt(v) + quad_err + 1.0 / res.sample_count)
    assert z.max() <= K_PIXEL, f"pixel {np.unravel_index(z.argmax(), z.shape)} off by {z.max():.1f} sigma"


# --- index of refraction ------------------------------------------------------------------------------


def test_glass_of_ior_one_is_invisible(device_spec, cbox_scene, cbox_ref):
    """A lossless ball of ior 1.0 in the Cornell box is no interface at all
    (Fresnel 0, no bending): the image equals the box without it within noise
    (at unlimited depth: each crossing counts as a scattering event). The
    ball's photon-map caustic is direct light through it; it sits away from the
    walls, where the gather radius would blur it."""
    ball = clpt.Sphere(center=(0.45, -0.45, -0.45), radius=0.15, material=clpt.Material(kt=(1, 1, 1), ior=1.0))
    r = clpt.Renderer(replace(cbox_scene, shapes=[*cbox_scene.shapes, ball]), device=device_spec,
                      photons=clpt.PhotonSettings(pilot=False))
    assert r.features.photons
    res = r.render(256, width=W, height=W, seed=2, max_depth=1000)
    assert_finite(res)
    assert res.stats.photon_maps[0]["stored"] > 0
    assert_same_render(res, cbox_ref(1000), "ior 1.0 ball vs no ball")


@pytest.mark.parametrize("ior", [1.0, 1.0001, 1.5, 2.4, 10.0, 0.5, 100.0])
def test_glass_of_any_ior_vanishes_in_a_furnace(device_spec, ior):
    """A lossless glass ball in a furnace of uniform radiance 2 is invisible
    for any ior, from none (1.0) through nearly none (1.0001), glass, diamond,
    10 and 100 (strong reflection, tiny critical angle) to a bubble (0.5):
    every pixel is 2 within noise."""
    obj = clpt.Sphere(center=(0.4, 0.2, 0.5), radius=0.4, material=clpt.Material(kt=(1, 1, 1), ior=ior))
    res = clpt.Renderer(furnace(clpt.Material(kd=(0.5,) * 3), obj), device=device_spec).render(
        128, max_depth=1000, seed=3)
    assert_finite(res)
    expected = np.full((res.image.shape[0], res.image.shape[1]), 2.0)
    assert_same_image(res.image[..., 0], pixel_var(res), expected, np.zeros_like(expected), f"ior {ior}")


def _tir_scene(ior):
    """A camera inside a glass ball (radius 0.8) of a sphere furnace (walls kd
    0.5, Le 1), 0.9 radii from the ball's centre, looking along the direction
    whose rays meet the ball at the critical angle."""
    R, c = 0.8, 0.72
    glass = clpt.Sphere(center=(0, 0, 0), radius=R, material=clpt.Material(kt=(1, 1, 1), ior=ior))
    scene = furnace(clpt.Material(kd=(0.5,) * 3), glass)
    # |o x d| / R = sin(theta_i) = 1 / ior for the view direction d.
    a = math.asin(R / (ior * c))
    d = (math.cos(a), 0.0, math.sin(a))
    scene.camera = clpt.Camera(origin=(c, 0, 0), target=(c + d[0], d[1], d[2]), fov=30, width=W, height=W)
    return scene, R


@pytest.mark.parametrize("precision", ["float", "double"])
def test_total_internal_reflection_inside_a_glass_ball(device_spec, precision):
    """Seen from inside a lossless glass ball in a furnace of radiance
    Le / (1 - rho) = 2, a ray meeting the surface below the critical angle
    escapes (after Fresnel reflections that keep its angle) and brings the
    outside radiance times ior^2 (radiance is n^2 L inside a dielectric: the
    kernel's 1/eta^2), while a ray beyond it is totally reflected forever: in
    a sphere every reflection meets the surface at the same angle, so it never
    leaves and sees nothing. Pixel means are ior^2 * 2 * (fraction of the
    pixel's rays below the critical angle), the view straddling it."""
    ior = 1.5
    scene, R = _tir_scene(ior)
    res = clpt.Renderer(scene, device=device_spec, photons=False, precision=precision).render(
        64, max_depth=1000, seed=4)
    assert_finite(res)
    o = np.array(scene.camera.origin)

    def expected(ss):
        d = sub_pixel_rays(scene.camera, W, W, ss)
        sin_i = np.linalg.norm(np.cross(o, d), axis=-1) / R
        return pixel_average(np.where(sin_i < 1 / ior, ior ** 2 * 2.0, 0.0), W, W, ss)

    fine, coarse = expected(32), expected(16)
    assert 0.2 < (fine > 0).mean() < 0.8, "the view should straddle the critical angle"
    img = res.image[..., 0].astype(np.float64)
    v = pixel_var(res)
    quad_err = 2 * np.abs(fine - coarse)
    assert_mean_within(img.mean(), fine.mean(), math.sqrt(v.sum()) / v.size + quad_err.mean(), K,
                       what=f"camera inside glass, {precision}")
    # A pixel barely reaching below the critical angle may draw no escaping
    # ray and show no variance: allow it one sample's worth (ior^2 * 2 / n).
    z = np.abs(img - fine) / (np.sqrt(v) + quad_err + ior ** 2 * 2.0 / res.sample_count)
    assert z.max() <= K_PIXEL, f"pixel {np.unravel_index(z.argmax(), z.shape)} off by {z.max():.1f} sigma"


@pytest.mark.parametrize("material", [
    clpt.Material(kt=(1, 1, 1), ior=1.5),
    clpt.Material(kt=(1, 1, 1), ior=10.0),
    clpt.Material(kr=(1, 1, 1)),
], ids=["glass", "ior10", "mirror"])
def test_rays_grazing_a_sphere_silhouette(device_spec, material):
    """Every camera ray grazes the silhouette of a lossless ball in a furnace:
    the camera looks along a tangent of the ball with a field of view of 0.01
    degrees, so the rays pass within ~1e-4 radii of it, hitting it at grazing
    incidence or missing it by a hair. The ball must stay invisible (2 within
    noise). Photon mapping is off: all pixels see the same spot, so the photon
    map's own noise, which lum_var does not measure, would be shared by all."""
    r, D = 0.4, 1.2
    o = np.array([0.0, 0.0, D])
    a = math.asin(r / D)
    scene = furnace(clpt.Material(kd=(0.5,) * 3), clpt.Sphere(center=(0, 0, 0), radius=r, material=material))
    scene.camera = clpt.Camera(origin=tuple(o), target=tuple(o + np.array([math.sin(a), 0.0, -math.cos(a)])),
                               fov=0.01, width=8, height=8)
    res = clpt.Renderer(scene, device=device_spec, photons=False).render(256, max_depth=1000, seed=5)
    assert_finite(res)
    expected = np.full((8, 8), 2.0)
    assert_same_image(res.image[..., 0], pixel_var(res), expected, np.zeros_like(expected), "grazing rays")


def test_camera_in_the_plane_of_a_quad(device_spec, cbox_scene, cbox):
    """A two-sided quad light lying in the plane of the camera's origin (and
    containing it), reaching from behind the camera to the box's open front:
    every camera ray starts in its plane (t = 0) and runs along or away from
    it, so none may hit it. Emitters only (max depth 0), with the same seed,
    the image is exactly the box's: a single camera ray hitting the quad would
    add its Le = 1e3 to a pixel."""
    le = 1e3
    blade = clpt.Quad(corner=(-1, 0, 1.2), edge_u=(2, 0, 0), edge_v=(0, 0, 3.3), material="black",
                      emission=(le, le, le), two_sided=True)
    assert cbox_scene.camera.origin[1] == 0.0
    r = clpt.Renderer(replace(cbox_scene, shapes=[*cbox_scene.shapes, blade]), device=device_spec)
    res = r.render(64, width=W, height=W, seed=7, max_depth=0)
    ref = cbox.render(64, width=W, height=W, seed=7, max_depth=0)
    assert_finite(res)
    assert res.image.max() < le / 64, "a camera ray hit the quad in its own plane"
    assert np.array_equal(res.image, ref.image)


# --- lights -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("radius,precision", [(1e-4, "float"), (1e-8, "float"), (1e-4, "double")])
def test_tiny_sphere_light_is_a_point_light(device_spec, radius, precision):
    """Direct light from a sphere light of radius r and radiance Le = 1/r^2
    (a point light of intensity pi) on a diffuse floor: E = pi Le (r/D)^2
    cos(theta), pixel by pixel (sub-pixel quadrature) and for the image mean,
    as test_render's 0.15 sphere, for r down to 1e-8."""
    rho, c = 0.7, np.array([0.2, 0.8, -0.1])
    le = 1.0 / radius ** 2
    floor = clpt.Quad(corner=(-3, 0, -3), edge_u=(0, 0, 6), edge_v=(6, 0, 0), material=clpt.Material(kd=(rho,) * 3))
    bulb = clpt.Sphere(center=tuple(c), radius=radius, material="black", emission=(le, le, le))
    cam = clpt.Camera(origin=(0.0, 0.5, 1.2), target=(0.0, 0.0, -0.2), fov=50, width=W, height=W)
    r = clpt.Renderer(clpt.Scene(camera=cam, shapes=[floor, bulb]), device=device_spec, precision=precision)
    res = r.render(256, max_depth=1, seed=1)
    assert_finite(res)
    expected = sphere_light_on_floor(cam, W, W, 6, c, radius, le, rho)
    v = pixel_var(res)
    img = res.image[..., 0].astype(np.float64)
    z = np.abs(img - expected) / np.sqrt(v + (1e-6 * expected.max()) ** 2)
    assert z.max() <= K_PIXEL, f"pixel off by {z.max():.1f} sigma"
    assert_mean_within(img.mean(), expected.mean(), math.sqrt(v.sum()) / v.size + 1e-4 * expected.mean(), K)


def test_quad_light_filling_the_ceiling(device_spec, cbox_scene):
    """The Cornell box lit by its whole ceiling (one-sided, black, Le = 5): the
    light's edges meet the walls, where light sampling's weights cos cos / d^2
    grow without bound. Without light sampling every sample is at most Le (one
    emitter hit, throughput <= 1); with it, the image mean must agree within
    noise (a heavy-tailed estimator: only means are compared)."""
    le = 5.0
    shapes = []
    for s in cbox_scene.shapes:
        if s.name == "ceiling":
            s = replace(s, material="black", emission=(le, le, le), two_sided=False)
        elif s.name == "light":  # the old lamp, not emitting, lies on the floor as a white rug
            s = replace(s, emission=None, corner=(s.corner[0], -0.995, s.corner[2]))
        shapes.append(s)
    scene = replace(cbox_scene, shapes=shapes)
    bsdf = clpt.Renderer(scene, device=device_spec, nee=False).render(512, width=W, height=W, seed=1)
    nee = clpt.Renderer(scene, device=device_spec).render(512, width=W, height=W, seed=2)
    for res in (bsdf, nee):
        assert_finite(res)
    assert bsdf.image.max() <= le * (1 + 1e-6), f"a pixel exceeds the light's radiance: {bsdf.image.max()}"
    assert np.isclose(bsdf.image[1, W // 2], le).all(), "this pixel sees only the ceiling light"
    assert_mean_within(lum(nee.image).mean(), lum(bsdf.image).mean(), math.hypot(image_sigma(nee), image_sigma(bsdf)),
                       K, what="NEE vs BSDF sampling under a full-ceiling light")


@pytest.mark.parametrize("shape", [
    clpt.Sphere(center=(0, 0.5, 0), radius=0.0),
    clpt.Quad(corner=(-0.2, 0.9, -0.2), edge_u=(0.4, 0, 0), edge_v=(0, 0, 0)),
    clpt.Quad(corner=(-0.2, 0.9, -0.2), edge_u=(0.4, 0, 0), edge_v=(0.8, 0, 0)),
    clpt.Triangle(vertices=((0, 0.9, 0), (0.5, 0.9, 0), (1.0, 0.9, 0))),
    clpt.Triangle(vertices=((0, 0.9, 0), (0, 0.9, 0), (0.3, 0.9, 0.3))),
], ids=["sphere-r0", "quad-zero-edge", "quad-parallel-edges", "triangle-collinear", "triangle-repeated-vertex"])
def test_degenerate_lights_are_rejected(device_spec, cbox_scene, shape):
    """A light of zero area cannot be sampled (its pdf is infinite): the scene
    checker rejects it with a SceneError naming the shape."""
    lamp = replace(shape, material="black", emission=(10.0, 10.0, 10.0), name="lamp")
    scene = replace(cbox_scene, shapes=[*cbox_scene.shapes, lamp])
    with pytest.raises(clpt.SceneError, match="lamp"):
        clpt.Renderer(scene, device=device_spec)


# --- depth --------------------------------------------------------------------------------------------------


def _light_footprint_pixels(scene, w, h):
    """Area, in pixels, of the Cornell light's projection (a planar quad)."""
    cam = scene.camera
    fr = camera_frame(cam, w, h)
    light = next(s for s in scene.shapes if s.name == "light")
    o = np.array(cam.origin)
    f = np.array(cam.target) - o
    f /= np.linalg.norm(f)
    pts = []
    for p in light.vertices():
        v = p - o
        v = v / (v @ f)  # on the image plane at distance 1, like fr.corner + px dx + py dy
        q = v - fr.corner
        px = q @ fr.dx / (fr.dx @ fr.dx)
        py = q @ fr.dy / (fr.dy @ fr.dy)
        pts.append((px, py))
    x, y = np.array(pts).T
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def test_max_depth_zero_shows_only_emitters(cbox_scene, cbox):
    """max_depth 0: a pixel is Le times the fraction of its area that sees the
    light and exactly 0 elsewhere; the fractions add up to the light's
    projected area in pixels within noise."""
    res = cbox.render(256, width=W, height=W, seed=1, max_depth=0)
    assert_finite(res)
    le = np.array(next(s for s in cbox_scene.shapes if s.name == "light").emission)
    cover = res.image.astype(np.float64) / le
    assert np.allclose(cover, cover[..., :1], rtol=1e-6, atol=0), "pixel colours must be multiples of Le"
    cover = cover[..., 0]
    assert ((cover >= 0) & (cover <= 1 + 1e-6)).all()
    assert 0 < (cover > 0).sum() < 0.1 * cover.size, "only the light's few pixels may be lit"
    var_cover = pixel_var(res) / (le @ LUMA) ** 2
    area = _light_footprint_pixels(cbox_scene, W, W)
    assert_mean_within(cover.sum(), area, math.sqrt(var_cover.sum()), K, what="light footprint in pixels")


def test_depth_limits_are_monotone_and_roulette_converges(cbox, cbox_ref):
    """With one seed the paths are the same whatever the depth limit, and
    deeper limits only add light: each pixel of depth 0 <= 1 <= 2 <= 64 (float
    sums are monotone). Depth 1000 with Russian roulette (other seed) agrees
    with depth 64 within noise."""
    imgs = {}
    for d in (0, 1, 2, 64):
        res = cbox.render(64, width=W, height=W, seed=2, max_depth=d)
        assert_finite(res)
        imgs[d] = res.image
    for a, b in ((0, 1), (1, 2), (2, 64)):
        assert (imgs[b] >= imgs[a]).all(), f"depth {b} is darker than depth {a} somewhere"
    assert lum(imgs[1]).mean() > lum(imgs[0]).mean() * 1.2
    deep = cbox.render(256, width=W, height=W, seed=11, max_depth=1000)
    assert_finite(deep)
    assert_same_render(deep, cbox_ref(64), "depth 1000 vs 64")


def test_roulette_from_first_bounce_on_nearly_black_walls(device_spec, cbox_scene, cbox):
    """rr_depth 0 with kd = 1e-6: a path goes on with probability 1e-6 and
    weight kd / p = 1. The image is the emitters-only image plus reflected
    light of at most kd Le / (1 - kd) ~ 2e-5 (within noise), never less, and
    no weight blows up: every non-emitter pixel's per-sample standard
    deviation stays below 1e-4 (a weight of 1/p = 1e6 on an ordinary path
    would give samples of order Le and a deviation above 1e-2)."""
    kd = 1e-6
    dark = replace(cbox_scene, materials={k: clpt.Material(kd=(kd,) * 3) for k in ("white", "red", "green")})
    le = max(next(s for s in cbox_scene.shapes if s.name == "light").emission)
    res = clpt.Renderer(dark, device=device_spec).render(256, width=W, height=W, seed=1, max_depth=1000, rr_depth=0)
    assert_finite(res)
    emit = cbox.render(256, width=W, height=W, seed=1, max_depth=0).image
    refl = res.image.astype(np.float64) - emit
    assert (refl >= -1e-6 * emit.max()).all(), "darker than the emitters alone"
    bound = kd * le / (1 - kd)
    v = pixel_var(res)
    assert (lum(refl) <= bound + K_PIXEL * np.sqrt(v)).all(), f"reflected light above {bound:.3g}"
    dark_pix = lum(emit) == 0
    assert np.sqrt(res.lum_var[dark_pix]).max() < 1e-4, f"per-sample deviation {np.sqrt(res.lum_var.max()):.3g}"


# --- samples and image sizes -------------------------------------------------------------------------------------


def test_one_sample_per_pixel(cbox, cbox_ref):
    """1 spp: every pixel has one sample; the image mean is that of the 256-spp
    reference within the noise of one sample per pixel (the reference's
    lum_var estimates one sample's variance)."""
    res = cbox.render(1, width=W, height=W, seed=21)
    assert_finite(res)
    assert (res.sample_count == 1).all() and res.image.shape == (W, W, 3)
    ref = cbox_ref(8)
    one_sample_var = ref.lum_var.astype(np.float64)
    assert one_sample_var.sum() > 0
    sigma = math.sqrt(one_sample_var.sum()) / one_sample_var.size
    assert_mean_within(lum(res.image).mean(), lum(ref.image).mean(), math.hypot(sigma, image_sigma(ref)), K)


@pytest.mark.parametrize("w,h", [(1, 1), (1, 4096), (4096, 1), (7, 3), (33, 17)])
def test_extreme_image_shapes(cbox, cbox_ref, w, h):
    """Tiny, one-pixel-wide and odd images render finite and the right shape.
    A 4096-pixel line with fov along its short side spans nearly 180 degrees
    the other way (camera rays almost parallel to the image plane). A 1x1
    image covers the same square view as the 16x16 reference: the same mean
    within noise."""
    spp = 256 if w * h == 1 else 2
    res = cbox.render(spp, width=w, height=h, seed=5)
    assert_finite(res)
    assert res.image.shape == (h, w, 3) and res.sample_count.shape == (h, w)
    assert (res.sample_count == spp).all()
    assert res.image.min() >= 0 and res.image.max() > 0
    if w * h == 1:
        ref = cbox_ref(8)
        assert_mean_within(lum(res.image).mean(), lum(ref.image).mean(), math.hypot(image_sigma(res), image_sigma(ref)),
                           K, what="1x1 vs 16x16")


def test_too_large_an_image_is_a_device_error(cbox):
    """60000 x 60000 pixels need ~140 GiB of sums: a DeviceError that says how
    many pixels need how much memory, not a crash; the renderer still works."""
    with pytest.raises(clpt.DeviceError) as e:
        cbox.render(1, width=60000, height=60000)
    msg = str(e.value)
    assert "3600000000 pixels" in msg and "MiB" in msg and "smaller image" in msg, msg
    res = cbox.render(2, width=8, height=8, seed=1)
    assert_finite(res)
    assert (res.sample_count == 2).all()


# --- caustic photons ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def caustics_scene():
    """cornell_box_caustics seen from low in front of the glass ball, where
    the caustic under the ball fills much of the view."""
    base = clpt.load_scene("cornell_box_caustics")
    cam = replace(base.camera, origin=(0.33, -0.55, 1.0), target=(0.33, -1.0, 0.25), fov=40)
    return replace(base, camera=cam)


@pytest.fixture(scope="module")
def caustics(caustics_scene, device_spec):
    return clpt.Renderer(caustics_scene, device=device_spec)


@pytest.fixture(scope="module")
def caustics_pt(caustics_scene, device_spec):
    """The same scene path traced (photon mapping off): an independent, unbiased reference."""
    r = clpt.Renderer(caustics_scene, device=device_spec, photons=False)
    return r.render(256, width=W, height=W, seed=1)


_PHOTON_RENDERS = {}


def _photon_render(r, settings, seed):
    key = (settings, seed)
    if key not in _PHOTON_RENDERS:
        _PHOTON_RENDERS[key] = r.render(256, width=W, height=W, seed=seed, photons=settings)
    return _PHOTON_RENDERS[key]


def test_photon_mapping_agrees_with_path_tracing(caustics, caustics_pt):
    """The default photon map (the baseline of the photon tests) and pure path
    tracing estimate the same image."""
    res = _photon_render(caustics, clpt.PhotonSettings(), 3)
    assert_finite(res)
    assert_finite(caustics_pt)
    assert_mean_within(lum(res.image).mean(), lum(caustics_pt.image).mean(),
                       math.hypot(image_sigma(res), image_sigma(caustics_pt)), K, what="photons vs path tracing")


def test_zero_photons_is_photon_mapping_off(caustics, caustics_pt):
    """count=0 emits no photons; the caustics must then come from path tracing
    (as photons=False, or the CLI's --photons 0), not vanish."""
    res = _photon_render(caustics, clpt.PhotonSettings(count=0), 2)
    assert_finite(res)
    assert res.stats.photon_maps[0]["stored"] == 0
    assert_mean_within(lum(res.image).mean(), lum(caustics_pt.image).mean(),
                       math.hypot(image_sigma(res), image_sigma(caustics_pt)), K, what="count=0 vs photons off")


# A map whose gathers find nothing: the path-traced part of the image alone.
# The owned photon map (mode "online"): the path-traced part of the image is
# the same whatever the map, so a gather can only add light.
NOTHING_FOUND = clpt.PhotonSettings(count=1, radius=1e-7, mode="online")


@pytest.mark.parametrize("settings", [
    clpt.PhotonSettings(count=1, mode="online"),
    clpt.PhotonSettings(radius=1e-7, mode="online"),
    clpt.PhotonSettings(radius=1e-18, mode="online"),
    clpt.PhotonSettings(radius=10.0, mode="online"),
    clpt.PhotonSettings(radius=1e30, count=100_000, mode="online"),
], ids=["one-photon", "radius-1e-7", "radius-1e-18", "radius-10", "radius-1e30"])
def test_photon_extremes_only_add_caustics(caustics, settings):
    """With one seed the path-traced part of the image is the same whatever
    the photon map, and a gather only adds light: every pixel is at least
    the count=0 image's. One photon, a radius of 1e-7 scene sizes (no photon
    within reach: exactly the count=0 image), 10 scene sizes (every photon in
    reach of every gather, in the 2x2x2 grid cells around the origin) and
    1e30 (r^2 = inf: nothing) are all finite and never brighter than the
    default map within noise (a huge radius spreads the caustic over pi r^2)."""
    seed = 2
    base = _photon_render(caustics, NOTHING_FOUND, seed)
    res = _photon_render(caustics, settings, seed)
    assert_finite(res)
    assert res.stats.photon_maps[0]["stored"] <= res.photons.count
    assert (res.image >= base.image * (1 - 1e-6)).all(), "a gather took light away"
    if settings.radius < 1e-3 or settings.radius > 1e20:
        assert np.allclose(res.image, base.image, rtol=1e-6, atol=0), "no photon may be found"
    default = _photon_render(caustics, clpt.PhotonSettings(mode="online"), seed)
    if res.photons.count > 1:  # one photon carries the whole caustic's power into one bright spot
        m, m_default = lum(res.image).mean(), lum(default.image).mean()
        sigma = math.hypot(image_sigma(res), image_sigma(default))
        assert m <= m_default + K * sigma, f"brighter than the default photon map: {m:.5g} > {m_default:.5g} + {K} sigma"


def test_vanishing_photon_radius(caustics_scene, caustics, device_spec):
    """A radius of 1e-30 scene sizes: its square underflows in float, so a
    float renderer rejects it with a SceneError saying so; in double it is
    representable, finds no photon and gives exactly the image of a map
    whose gathers find nothing, never 0 / 0."""
    tiny = clpt.PhotonSettings(radius=1e-30, count=100_000, mode="online")
    with pytest.raises(clpt.SceneError, match="too small"):
        caustics.render(4, width=W, height=W, seed=2, photons=tiny)
    r = clpt.Renderer(caustics_scene, device=device_spec, precision="double")
    res = r.render(64, width=W, height=W, seed=2, photons=tiny)
    base = r.render(64, width=W, height=W, seed=2, photons=NOTHING_FOUND)
    assert_finite(res)
    assert np.array_equal(res.image, base.image)


@pytest.mark.slow  # about 100 s on 2 cores: in the slow tier (pytest -m slow)
def test_ten_million_photons(caustics, caustics_pt):
    """10^7 photons (about 1.1 GB of photon buffers): the same fraction is
    stored as with 10^6 (within binomial noise: the same photon streams) and
    the image agrees with path tracing within noise."""
    big = clpt.PhotonSettings(count=10_000_000)
    res = _photon_render(caustics, big, 3)
    assert_finite(res)
    small = _photon_render(caustics, clpt.PhotonSettings(), 3)
    f_big = res.stats.photon_maps[0]["stored"] / big.count
    f_small = small.stats.photon_maps[0]["stored"] / small.photons.count
    sigma = math.sqrt(f_small * (1 - f_small) / small.photons.count)
    assert_mean_within(f_big, f_small, sigma, K, what="stored fraction")
    assert 0.5 < f_big <= 1.0
    assert_mean_within(lum(res.image).mean(), lum(caustics_pt.image).mean(),
                       math.hypot(image_sigma(res), image_sigma(caustics_pt)), K, what="10M photons vs path tracing")


# --- cameras --------------------------------------------------------------------------------------------------------


def test_camera_inside_a_closed_sphere_with_a_light(device_spec):
    """An integrating sphere: a closed diffuse sphere (radius R, albedo rho)
    with a sphere light (radius r, Le) at its centre, the camera inside
    looking at the wall. The wall's radiance is uniform:
    L = rho Le s / (1 - rho (1 - s)) with s = (r/R)^2 (direct irradiance
    pi Le s; the light, black, hides a cone of s of each wall point's
    cosine-weighted view). Every pixel and the image mean must match."""
    rho, le, r, R = 0.5, 10.0, 0.1, 1.5
    room = clpt.Sphere(center=(0, 0, 0), radius=R, material=clpt.Material(kd=(rho,) * 3))
    bulb = clpt.Sphere(center=(0, 0, 0), radius=r, material="black", emission=(le, le, le))
    cam = clpt.Camera(origin=(0.3, -0.2, 0.1), target=(1.0, 0.3, 0.8), fov=90, width=W, height=W)
    res = clpt.Renderer(clpt.Scene(camera=cam, shapes=[room, bulb]), device=device_spec).render(
        256, max_depth=1000, seed=1)
    assert_finite(res)
    s = (r / R) ** 2
    expected = np.full((W, W), rho * le * s / (1 - rho * (1 - s)))
    assert_same_image(res.image[..., 0], pixel_var(res), expected, np.zeros_like(expected), "integrating sphere")


@pytest.mark.parametrize("precision", ["float", "double"])
def test_camera_on_a_wall(device_spec, cbox_scene, precision):
    """The camera's origin exactly on the back wall's plane, looking into the
    box: it sees what a camera 1e-4 in front of the wall sees (within noise;
    the wall itself is never hit at t = 0). 1e-4 behind the wall it sees only
    the wall's unlit back: exactly black, no light leaking through."""
    def render(z, seed):
        cam = replace(cbox_scene.camera, origin=(0.0, 0.0, z), target=(0.0, 0.0, 1.0), fov=90)
        r = clpt.Renderer(replace(cbox_scene, camera=cam), device=device_spec, precision=precision)
        res = r.render(64, width=W, height=W, seed=seed)
        assert_finite(res)
        return res

    on, front, behind = render(-1.0, 1), render(-1.0 + 1e-4, 2), render(-1.0 - 1e-4, 3)
    assert lum(on.image).mean() > 0.1
    assert_same_render(on, front, f"camera on the wall ({precision})")
    assert (behind.image == 0).all(), "light leaks through the back wall"


def test_camera_looking_straight_down(device_spec, cbox_scene):
    """Looking straight down with up = +y (parallel to the view) is a
    SceneError saying so, also 1e-7 off; up = -z or +z works, and the two
    images are each other turned by 180 degrees; 1e-5 off vertical, up = +y
    is accepted and is the up = +z view."""
    def scene(up, target=(0.0, -1.0, 0.0)):
        return replace(cbox_scene, camera=replace(cbox_scene.camera, origin=(0.0, 0.5, 0.0), target=target,
                                                  up=up, fov=90))

    for target in ((0.0, -1.0, 0.0), (0.0, -1.0, 1e-7)):
        with pytest.raises(clpt.SceneError, match="parallel"):
            clpt.Renderer(scene((0.0, 1.0, 0.0), target), device=device_spec)
    minus_z = clpt.Renderer(scene((0.0, 0.0, -1.0)), device=device_spec).render(256, width=W, height=W, seed=1)
    plus_z = clpt.Renderer(scene((0.0, 0.0, 1.0)), device=device_spec).render(256, width=W, height=W, seed=2)
    tilted = clpt.Renderer(scene((0.0, 1.0, 0.0), (0.0, -1.0, 1e-5)), device=device_spec).render(
        256, width=W, height=W, seed=3)
    for res in (minus_z, plus_z, tilted):
        assert_finite(res)
    assert lum(minus_z.image).mean() > 0.05
    rot = lambda a: a[::-1, ::-1]  # noqa: E731
    assert_same_image(lum(minus_z.image), pixel_var(minus_z), rot(lum(plus_z.image)), rot(pixel_var(plus_z)),
                      "up -z vs up +z turned 180 degrees")
    assert_same_render(tilted, plus_z, "1e-5 off vertical with up +y vs up +z")
