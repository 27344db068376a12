"""End-to-end renders: determinism, scheduling independence, finite output on
every shipped scene, the API's overrides, and direct light on a diffuse
plane against the analytic irradiance."""

import math

import numpy as np
import pytest

import clpt
from clpt.pack import camera_frame
from clpt.resources import shipped_scenes

from analytic import sphere_light_on_floor
from stats import assert_mean_within
from test_shapes import lambert_irradiance


@pytest.fixture(scope="module")
def cbox(device_spec):
    return clpt.Renderer("cornell_box", device=device_spec)


def test_render_api_returns_linear_float_image(device_spec):
    img = clpt.render("cornell_box", spp=2, width=24, height=16, device=device_spec)
    assert img.dtype == np.float32 and img.shape == (16, 24, 3)
    assert np.isfinite(img).all() and img.min() >= 0 and img.mean() > 0.05


@pytest.mark.portability
def test_same_seed_same_image_other_seed_other_image(cbox):
    ra = cbox.render(4, seed=7, width=32, height=32)
    rb = cbox.render(4, seed=7, width=32, height=32)  # on the sums' buffers of the first, zeroed
    c = cbox.render(4, seed=8, width=32, height=32).image
    a, b = ra.image, rb.image
    assert np.array_equal(a, b) and np.array_equal(ra.lum_var, rb.lum_var)
    assert np.array_equal(ra.sample_count, rb.sample_count) and ra.sample_count.max() == 4
    assert not np.array_equal(a, c)


@pytest.mark.portability
def test_pass_splits_and_work_group_sizes_do_not_change_a_bit(cbox):
    """Samples are added to a pixel one by one, in sample order, whatever the
    launches; the RNG is keyed by (pixel, sample), so any schedule gives the
    same bits."""
    one_pass = cbox.render(12, seed=3, width=40, height=24, pass_seconds=1e9)
    many = cbox.render(12, seed=3, width=40, height=24, pass_seconds=1e-9)
    assert len(many.stats.passes) == 12 and len(one_pass.stats.passes) == 2  # 1-sample probe, then the rest
    assert np.array_equal(one_pass.image, many.image)
    st = cbox.states[0]
    local = st.local
    try:
        st.local = 1
        small_groups = cbox.render(12, seed=3, width=40, height=24)
    finally:
        st.local = local
    assert np.array_equal(one_pass.image, small_groups.image)


@pytest.mark.portability
@pytest.mark.parametrize("scene", ["cornell_box", "cornell_box_caustics"])
def test_lane_widths_and_kernel_builds_agree_bit_for_bit(device_spec, scene):
    """The scalar, 4-, 8- and 16-lane kernels, generic and specialized, run
    the same IEEE operations per path in the same order."""
    ref = clpt.render(scene, spp=3, width=26, height=23, device=device_spec)
    for lanes, kernel in ((1, "specialized"), (4, "generic"), (8, "generic"), (16, "specialized")):
        img = clpt.render(scene, spp=3, width=26, height=23, device=device_spec, lanes=lanes, kernel=kernel)
        assert np.array_equal(img, ref), (lanes, kernel)


@pytest.mark.parametrize("name", shipped_scenes())
def test_shipped_scenes_render_finite(device_spec, name):
    res = clpt.Renderer(name, device=device_spec).render(8, width=32, height=32)
    assert np.isfinite(res.image).all() and res.stats.nonfinite == 0
    assert res.image.mean() > 0.01
    assert (res.sample_count == 8).all()


@pytest.mark.parametrize("w,h", [(1, 1), (1, 37), (37, 1), (13, 7)])
def test_odd_image_sizes(cbox, w, h):
    res = cbox.render(2, width=w, height=h)
    assert res.image.shape == (h, w, 3) and (res.sample_count == 2).all() and np.isfinite(res.image).all()


def test_bad_render_arguments_are_scene_errors(cbox):
    for kw in ({"spp": 0}, {"width": 0}, {"max_depth": -1}, {"seed": -2}, {"spp": 1.5}):
        with pytest.raises(clpt.SceneError):
            cbox.render(**{"spp": 1, **kw})


@pytest.mark.portability
def test_quad_light_over_diffuse_plane(device_spec):
    """Direct light only (max depth 1): a diffuse floor of albedo rho under a
    one-sided quad light of radiance Le shows L = rho / pi * Le * E(x) with E
    the analytic irradiance of the quad at the floor point x."""
    rho, le = 0.6, 5.0
    verts = [(-0.4, 1.0, -0.3), (0.4, 1.0, -0.3), (0.4, 1.0, 0.5), (-0.4, 1.0, 0.5)]  # faces down
    floor = clpt.Quad(corner=(-3, 0, -3), edge_u=(0, 0, 6), edge_v=(6, 0, 0), material=clpt.Material(kd=(rho,) * 3))
    lamp = clpt.Quad.from_vertices(verts, material="black", emission=(le, le, le))
    w = h = 20
    cam = clpt.Camera(origin=(0.0, 0.5, 1.2), target=(0.0, 0.0, -0.2), fov=50, width=w, height=h)
    res = clpt.Renderer(clpt.Scene(camera=cam, shapes=[floor, lamp]), device=device_spec).render(256, max_depth=1)
    fr = camera_frame(cam, w, h)
    o = np.array(cam.origin)
    expected = np.zeros((h, w))
    sub = (np.arange(4) + 0.5) / 4
    for y in range(h):
        for x in range(w):
            vals = []
            for sy in sub:
                for sx in sub:
                    d = fr.corner + (x + sx) * fr.dx + (y + sy) * fr.dy
                    t = -o[1] / d[1]
                    p = o + t * d
                    on_floor = t > 0 and abs(p[0]) < 3 and abs(p[2]) < 3  # else the ray escapes
                    vals.append(rho / math.pi * le * lambert_irradiance(p, np.array([0, 1.0, 0]), verts)
                                if on_floor else 0.0)
            expected[y, x] = np.mean(vals)
    var_pix = res.lum_var / res.sample_count
    z = np.abs(res.image[..., 0] / rho - expected / rho) / np.sqrt(var_pix / rho ** 2 + 1e-12)
    # Pixels across the light's shadow-free penumbra edge average a kink: the
    # 4x4 sub-pixel reference is good to ~1e-3 there.
    assert np.all((z < 6) | (np.abs(res.image[..., 0] - expected) < 2e-3 * expected.max()))
    sigma = np.sqrt(var_pix.sum()) / var_pix.size
    assert_mean_within(res.image[..., 0].mean(), expected.mean(), sigma + 1e-4 * expected.mean())


@pytest.mark.portability
def test_sphere_light_over_diffuse_plane(device_spec):
    """Direct light only: a sphere light of radius r and radiance Le whose centre
    is at distance D from a floor point, seen at angle theta from the floor's
    normal (and wholly above its horizon), gives E = pi Le (r/D)^2 cos(theta)."""
    rho, le, r, c = 0.7, 40.0, 0.15, np.array([0.2, 0.8, -0.1])
    floor = clpt.Quad(corner=(-3, 0, -3), edge_u=(0, 0, 6), edge_v=(6, 0, 0), material=clpt.Material(kd=(rho,) * 3))
    bulb = clpt.Sphere(center=tuple(c), radius=r, material="black", emission=(le, le, le))
    w = h = 16
    cam = clpt.Camera(origin=(0.0, 0.5, 1.2), target=(0.0, 0.0, -0.2), fov=50, width=w, height=h)
    res = clpt.Renderer(clpt.Scene(camera=cam, shapes=[floor, bulb]), device=device_spec).render(512, max_depth=1)
    expected = sphere_light_on_floor(cam, w, h, 6, c, r, le, rho)
    var_pix = res.lum_var / res.sample_count
    z = np.abs(res.image[..., 0] - expected) / np.sqrt(var_pix + 1e-12)
    assert z.max() < 6, f"pixel off by {z.max():.1f} sigma"
    sigma = np.sqrt(var_pix.sum()) / var_pix.size
    assert_mean_within(res.image[..., 0].mean(), expected.mean(), sigma + 1e-4 * expected.mean())


def test_kahan_sums_match_double_sums(device_spec):
    """Devices without fp64 keep Kahan-compensated float sums: same image to float precision."""
    a = clpt.Renderer("cornell_box", device=device_spec, accumulate="double").render(32, width=16, height=16)
    b = clpt.Renderer("cornell_box", device=device_spec, accumulate="kahan").render(32, width=16, height=16)
    assert not b.features.accum_double
    assert np.allclose(a.image, b.image, rtol=1e-6, atol=1e-7)
    assert np.allclose(a.lum_var, b.lum_var, rtol=1e-5, atol=1e-7)


@pytest.mark.portability
def test_two_devices_render_one_image(device_spec):
    """Two contexts (here on the same device) pull sample ranges from one
    render; the sums add up to the single-device image, photons included."""
    dev = clpt.device.select_devices(device_spec)[0]
    one = clpt.Renderer("cornell_box_caustics", device=dev).render(16, width=16, height=16, seed=9)
    two_r = clpt.Renderer("cornell_box_caustics", device=[dev, dev])
    two = two_r.render(16, width=16, height=16, seed=9)
    assert len(two_r.states) == 2 and all(st.launches.get("trace_paths", 0) > 0 for st in two_r.states)
    assert (two.sample_count == 16).all()
    # Only the order of additions differs: equal to float precision.
    assert np.allclose(one.image, two.image, rtol=1e-5, atol=1e-6)
