"""The denoisers: the cone filter's kernels against their numpy twins, the
properties a denoiser must keep (constant images, edges, energy, caustics),
the feature buffers they are fed, and OIDN when pyoidn is installed."""

import time
from dataclasses import replace

import numpy as np
import pyopencl as cl
import pytest

import clpt
from clpt import program
from clpt.denoise import LUMA, FilterSettings, OidnSettings, apply_denoiser, reference_cone_filter, reference_firefly
from clpt.engine.passes import FilterPass
from clpt.errors import SettingsError
from clpt.features import Features
from clpt.tools.metrics import relmse


@pytest.fixture(scope="module")
def cone(probes):
    probe = probes(1)
    return FilterPass(probe.dctx, probe.program)


def guides(h, w, normal=(0, 0, 1), albedo=0.5, depth=2.0):
    n = np.zeros((h, w, 3), np.float32)
    n[...] = normal
    return n, np.full((h, w, 3), albedo, np.float32), np.full((h, w), depth, np.float32)


def noisy(rng, h, w, level=0.3, sigma=0.05):
    img = (level + rng.normal(0, sigma, (h, w, 3))).astype(np.float32)
    return img, np.full((h, w), sigma ** 2, np.float32)


@pytest.mark.parametrize("settings", [FilterSettings(), FilterSettings(width=1, iterations=1),
                                      FilterSettings(width=3, iterations=3, sigma_luminance=1.0, guide_floor=0.0),
                                      FilterSettings(firefly_k=0.0, guide_floor=0.5),
                                      FilterSettings(confirm_k=0.0), FilterSettings(confirm_k=1e6),
                                      FilterSettings(fit_last=False), FilterSettings(width=2, iterations=2,
                                                                                     fit_guide_floor=0.3)])
def test_kernel_matches_numpy_twin(cone, settings):
    rng = np.random.default_rng(0)
    h, w = 20, 23
    img, var = noisy(rng, h, w)
    var *= rng.uniform(0.5, 2.0, (h, w)).astype(np.float32)
    n, a, d = guides(h, w)
    n[:, 12:] = (1, 0, 0)               # a crease
    a[5:9] = (0.8, 0.2, 0.1)            # a painted stripe
    d += rng.uniform(0, 0.5, (h, w)).astype(np.float32)
    img[:, 17:] *= 3                    # a shadow edge
    img[3, 4] *= 40                     # a firefly
    img[10, 20] *= 40                   # a highlight its samples confirm (var unchanged)
    emitter = np.zeros((h, w), np.float32)
    emitter[14:17, 2:6] = 1.0           # a light
    got = cone(img, var, n, a, d, settings, emitter=emitter)
    ref = reference_cone_filter(img, var, n, a, d, settings, emitter=emitter)
    assert np.allclose(got, ref, rtol=2e-4, atol=1e-6)


def test_eight_or_sixteen_pixels_per_work_item_give_the_same_bits(dctx):
    """kernels/filter.cl's work-items take 8 or 16 pixels (CLPT_FILTER_PIXELS,
    set by the device): the same operations per pixel either way. Ragged
    images, every kernel (the clamp, the smoothing, the averaging and fitting
    passes) and a wide cone."""
    src = program.stitch(["filter.cl"])
    opts = Features(lanes=1, mode="generic").options() + ["-w"]
    passes = {p: FilterPass(dctx, cl.Program(dctx.context, src).build(options=opts + [f"-DCLPT_FILTER_PIXELS={p}"]),
                            pixels=p) for p in (8, 16)}
    rng = np.random.default_rng(5)
    for h, w in ((13, 23), (40, 37)):
        img, var, n, a, d = _scene(rng, h, w)
        emitter = np.zeros((h, w), np.float32)
        emitter[2:5, 3:7] = 1.0  # a light
        for settings in (FilterSettings(), FilterSettings(width=2, fit_last=False)):
            out = [passes[p](img, var, n, a, d, settings, emitter=emitter) for p in (8, 16)]
            assert np.array_equal(out[0], out[1]), (h, w, settings)
            assert not np.array_equal(out[0], img)  # it filtered


def test_cpus_build_the_filter_sixteen_pixels_a_work_item():
    """CPU devices (Oclgrind too: it reports every type) get
    -DCLPT_FILTER_PIXELS=16 and FilterPass launches 16 pixels a work-item;
    GPUs keep the kernels' 8 and no option."""
    import types

    def fake(kind):
        return types.SimpleNamespace(is_cpu=bool(kind & cl.device_type.CPU))
    assert program.filter_pixels(fake(cl.device_type.CPU)) == 16
    assert program.filter_options(fake(cl.device_type.CPU)) == ["-DCLPT_FILTER_PIXELS=16"]
    assert program.filter_pixels(fake(cl.device_type.ALL)) == 16
    assert program.filter_pixels(fake(cl.device_type.GPU)) == 8
    assert program.filter_options(fake(cl.device_type.GPU)) == []


def _scene(rng, h, w):
    img, var = noisy(rng, h, w)
    img[rng.random((h, w)) < 0.02] *= 30  # fireflies
    var *= rng.uniform(0.5, 2.0, (h, w)).astype(np.float32)
    n, a, d = guides(h, w)
    n[:, w // 2:] = (1, 0, 0)
    d += rng.uniform(0, 0.5, (h, w)).astype(np.float32)
    return img, var, n, a, d


def test_kept_buffers_give_the_same_image(cone, probes):
    # The buffers kept between images of one size (and the padding of a width
    # that is not a multiple of 16) carry nothing from one image to the next.
    rng = np.random.default_rng(5)
    x, y = _scene(rng, 21, 29), _scene(rng, 21, 29)
    s = FilterSettings(width=2)
    first = cone(*x, s)
    cone(*y, s)
    cone(*y, replace(s, firefly_k=0.0))
    assert np.array_equal(cone(*x, s), first)
    fresh = FilterPass(probes(1).dctx, probes(1).program)
    assert np.array_equal(fresh(*x, s), first)


def test_a_nan_variance_changes_only_the_pixels_it_reaches(cone):
    # With a NaN variance the clamp takes its medians by rank, elsewhere by a
    # selection network: the same medians wherever the 3x3 has no NaN. Every
    # third pixel a firefly (its standard error its value: clamped to a bound
    # from the median, which becomes its variance).
    rng = np.random.default_rng(6)
    h, w = 40, 45
    img, var, n, a, d = _scene(rng, h, w)
    img[::3, ::3] *= 30
    var[::3, ::3] = (img[::3, ::3] @ LUMA.astype(np.float32)) ** 2
    s = FilterSettings(width=1, iterations=1, fit_last=False)
    clean = cone(img, var, n, a, d, s)
    assert np.mean(clean[3:-3:3, 3:-3:3] < 0.5 * img[3:-3:3, 3:-3:3]) > 0.5  # most fireflies were clamped
    var = var.copy()
    var[0, 0] = np.nan
    got = cone(img, var, n, a, d, s)
    reach = 1 + sum(1 + (1 << k) * s.width for k in range(s.passes(w, h)))  # clamp, then smoothing and taps per pass
    assert np.array_equal(got[reach + 1:], clean[reach + 1:])
    assert np.array_equal(got[:, reach + 1:], clean[:, reach + 1:])


def test_constant_region_stays_exactly_constant(cone):
    h, w = 16, 16
    img = np.full((h, w, 3), (0.3, 0.5, 0.7), np.float32)
    var = np.random.default_rng(1).uniform(0, 0.1, (h, w)).astype(np.float32)  # whatever the noise estimate
    out = cone(img, var, *guides(h, w), FilterSettings(width=3, iterations=4))
    assert np.array_equal(out, img)


def test_width_zero_is_the_identity(cone):
    rng = np.random.default_rng(2)
    img, var = noisy(rng, 9, 11)
    assert np.array_equal(cone(img, var, *guides(9, 11), FilterSettings(width=0)), img)


@pytest.mark.parametrize("edge", ["normal", "luminance", "emitter"])
def test_a_sharp_edge_stays_sharp(cone, edge):
    """Two flat regions side by side: each stays flat and the step stays a step."""
    h, w = 12, 20
    img = np.full((h, w, 3), 0.2, np.float32)
    img[:, 10:] = 0.8
    var = np.full((h, w), 1e-6, np.float32)
    n, a, d = guides(h, w)
    emitter = None
    if edge == "normal":
        n[:, 10:] = (1, 0, 0)  # perpendicular surfaces: the guide weight across is exactly 0
    if edge == "emitter":
        emitter = np.zeros((h, w), np.float32)
        emitter[:, 10:] = 1.0  # a light beside a wall: never mixed, whatever the values
        var[:] = 10.0
    out = cone(img, var, n, a, d, FilterSettings(width=3, iterations=3, guide_floor=0.0), emitter=emitter)
    if edge in ("normal", "emitter"):
        assert np.array_equal(out, img)
    else:  # a step of 0.6 where the noise is 0.001: weight e^-(0.6 / 0.005) across
        assert np.abs(out - img).max() < 1e-6


def test_a_step_in_the_guides_is_not_blurred_across(cone):
    """A crease with a step in brightness of a few standard errors (which the
    value term alone would let through): with the default guide floor, each
    side's columns next to the crease stay within a tenth of the step."""
    rng = np.random.default_rng(5)
    h, w = 40, 40
    sigma = 0.04
    truth = np.where(np.arange(w) < 20, 0.3, 0.42)[None, :, None].repeat(h, 0).repeat(3, 2)
    img = (truth + rng.normal(0, sigma, (h, w, 3))).astype(np.float32)
    var = np.full((h, w), sigma ** 2, np.float32)
    n, a, d = guides(h, w)
    n[:, 20:] = (1, 0, 0)
    out = cone(img, var, n, a, d, FilterSettings())
    for col, want in ((19, 0.3), (20, 0.42)):
        got = float(out[:, col].mean())
        assert abs(got - want) < 0.1 * 0.12 + 3 * sigma / np.sqrt(h), (col, got)


def test_the_last_pass_fits_a_plane(cone):
    """A brightness gradient (a lit wall's falloff) with little noise: the
    fitting pass (alone here: one pass) returns it as it is, the corners and
    edges of the image included, where the taps are one-sided; averaging
    (fit_last off) pulls those towards the inside. In the twin too."""
    h, w = 12, 14
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    ramp = 0.3 + 0.01 * xs + 0.006 * ys
    img = np.repeat(ramp[..., None], 3, -1).astype(np.float32)
    var = np.full((h, w), 1e-4, np.float32)  # a step is 0.3 to 0.4 of the value term's scale: weights ~ 0.75
    g = guides(h, w)
    fit = FilterSettings(width=2, iterations=1)
    for out in (cone(img, var, *g, fit), reference_cone_filter(img, var, *g, fit)):
        assert np.abs(out - img).max() < 2e-4  # the slopes' ridge: 1e-4 at the corners
    avg = cone(img, var, *g, replace(fit, fit_last=False))
    assert abs(avg[0, 0, 0] - img[0, 0, 0]) > 5e-3 and abs(avg[-1, -1, 0] - img[-1, -1, 0]) > 5e-3


def test_zero_variance_and_black_pixels(cone):
    h, w = 10, 10
    img = np.zeros((h, w, 3), np.float32)
    img[3:6, 3:6] = 1.0
    var = np.zeros((h, w), np.float32)
    n, a, d = guides(h, w)
    a[:, :5] = 0.0  # black surfaces: no albedo to divide by
    n[0] = 0.0      # pixels that saw no surface
    out = cone(img, var, n, a, d, FilterSettings())
    assert np.isfinite(out).all() and out.min() >= 0
    assert np.array_equal(out[7:], img[7:])  # flat black region with no noise: untouched


def test_firefly_clamp_cuts_outliers_and_leaves_gaussian_noise(cone):
    rng = np.random.default_rng(3)
    h, w = 64, 64
    img, var = noisy(rng, h, w, level=1.0, sigma=0.05)
    c, v = reference_firefly(img, var, 3.0)
    assert np.mean(np.any(c != img, axis=-1)) < 2e-3  # Gaussian noise: (almost) never clamped
    img[30, 30] = 50.0                                  # a firefly
    var[30, 30] = 400.0
    c, v = reference_firefly(img, var, 3.0)
    around = np.delete(img[29:32, 29:32].reshape(9, 3), 4, axis=0) @ LUMA
    assert c[30, 30] @ LUMA <= around.max() + 3 * 0.05 + 1e-5 and v[30, 30] == pytest.approx(0.05 ** 2)


def test_unbounded_settings_are_refused_or_bounded(cone):
    with pytest.raises(clpt.SceneError, match="width"):
        FilterSettings(width=1000000).check()
    with pytest.raises(clpt.SceneError, match="iterations"):
        FilterSettings(iterations=0).check()
    s = FilterSettings(iterations=1000).check()
    assert s.passes(64, 48) == 7  # steps 1 ... 64: the ones that reach inside the image
    rng = np.random.default_rng(4)
    img, var = noisy(rng, 24, 24)
    t0 = time.perf_counter()
    a = cone(img, var, *guides(24, 24), s)
    assert time.perf_counter() - t0 < 5.0
    assert np.array_equal(a, cone(img, var, *guides(24, 24), replace(s, iterations=s.passes(24, 24))))
    # A cone wider than the image: clipped to it, still a smoothing.
    wide = cone(img, var, *guides(24, 24), FilterSettings(width=16, iterations=1))
    assert np.isfinite(wide).all() and wide.std() < img.std()


def test_caustics_and_emission_are_kept_exactly(cone):
    """What the filter leaves out comes back untouched: an image that is only
    caustic and emission is returned as it is."""
    rng = np.random.default_rng(6)
    h, w = 16, 16
    n, a, d = guides(h, w)
    caustic = np.zeros((h, w, 3), np.float32)
    caustic[5:9, 5:9] = rng.uniform(1, 4, (4, 4, 3))
    emission = np.zeros((h, w, 3), np.float32)
    emission[0:2, 6:10] = 17.0
    aux = {"normal": n, "albedo": a, "depth": d, "emission": emission, "emitter": (emission[..., 0] > 0) * 1.0,
           "caustic": caustic, "caustic_var": np.zeros((h, w), np.float32)}
    img = caustic + emission
    out = apply_denoiser(cone, img, np.full((h, w), 0.3, np.float32), np.full((h, w), 16.0), aux, FilterSettings())
    assert np.array_equal(out, img)


def test_only_concentrated_caustics_are_kept_out(cone):
    """The photon map's caustic is kept out of the cone filter where it is a
    large share of the 3x3's luminance (a ramp from 0.1 to 0.3 at the
    default 0.2), and filtered with the rest where a few photons are scattered
    over a wall; caustic_share=0 keeps all of it out, as before."""
    from clpt.denoise import kept_caustic_share
    h, w = 16, 16
    n, a, d = guides(h, w)
    wall = np.full((h, w, 3), 1.0, np.float32)
    caustic = np.zeros((h, w, 3), np.float32)
    caustic[4, 4] = 0.5                 # one photon on the wall: under 5% of its 3x3
    caustic[9:15, 9:15] = 4.0           # a caustic's core
    img = wall + caustic
    share = kept_caustic_share(caustic, img, 0.2)
    assert share[4, 4] == 0 and (share[10:14, 10:14] == 1).all()
    # the ramp: a uniform caustic bringing a fraction s of the light keeps (s - 0.1) / 0.2 of it
    for s_, want in ((0.05, 0.0), (0.15, 0.25), (0.2, 0.5), (0.35, 1.0)):
        c = np.full((h, w, 3), s_ / (1 - s_), np.float32)
        assert np.allclose(kept_caustic_share(c, 1 + c, 0.2), want, atol=1e-5)
    assert kept_caustic_share(np.zeros_like(caustic), img, 0.2) is None  # no caustic: nothing to weigh
    aux = {"normal": n, "albedo": a, "depth": d, "emission": np.zeros_like(img),
           "emitter": np.zeros((h, w), np.float32), "caustic": caustic, "caustic_var": np.zeros((h, w), np.float32)}
    var, count = np.full((h, w), 0.3, np.float32), np.full((h, w), 16.0)
    out = apply_denoiser(cone, img, var, count, aux, FilterSettings())
    assert np.allclose(out[10:14, 10:14], img[10:14, 10:14], rtol=1e-3)  # the core as it was (the photon: 1e-4)
    assert out[4, 4, 0] < 1.1  # the photon spread over the wall
    # its light stays on the wall but for the filter's bias on a lone bright pixel
    # (the firefly clamp's, and its weights': 25% at this contrast, 3.7 of the pixel's standard errors)
    kept_light = 1 + (out - img).sum() / (img[:9, :9] - 1).sum()
    assert 0.6 < kept_light < 1.0, kept_light
    kept = apply_denoiser(cone, img, var, count, aux, FilterSettings(caustic_share=0.0))
    assert np.allclose(kept[:8, :8], img[:8, :8], rtol=1e-6)
    with pytest.raises(SettingsError):
        FilterSettings(caustic_share=1.5).check()


@pytest.fixture(scope="module")
def caustic_renders(device_spec):
    r = clpt.Renderer("cornell_box_caustics", device=device_spec, aux=True)
    return [r.render(8, width=64, height=64, max_depth=16, seed=s) for s in (1, 2)], r


def test_filter_keeps_region_means_and_the_caustic(caustic_renders):
    """Energy: over the whole image, a wall, and the caustic's core (the photon
    map's part at least half its peak), the filtered mean equals the raw mean
    within 4 standard errors of the raw mean (per-pixel variances summed)."""
    results, r = caustic_renders
    for res in results:
        out = apply_denoiser(r.states[0].filter, res.image, res.lum_var, res.sample_count, res.aux, FilterSettings())
        cl = res.aux["caustic"] @ LUMA
        core = cl >= 0.5 * cl.max()
        wall = np.zeros(cl.shape, bool)
        wall[8:40, 20:44] = True  # the back wall, above the spheres
        assert core.sum() >= 3
        se_pix = res.lum_var / res.sample_count
        for region in (np.ones(cl.shape, bool), wall, core):
            raw_m, f_m = float((res.image[region] @ LUMA).mean()), float((out[region] @ LUMA).mean())
            se = float(np.sqrt(se_pix[region].sum()) / region.sum())
            assert abs(f_m - raw_m) < 4 * se + 1e-3 * raw_m, (region.sum(), raw_m, f_m, se)


def test_filter_cuts_error_on_a_noisy_render(device_spec):
    r = clpt.Renderer("cornell_box", device=device_spec, aux=True)
    ref = r.render(2048, width=48, height=48, seed=1).image
    res = r.render(8, width=48, height=48, seed=2, filter=FilterSettings())
    raw, filt = relmse(res.image, ref), relmse(res.filtered, ref)
    assert filt < raw / 4, (raw, filt)
    assert res.aux["normal"].shape == (48, 48, 3) and np.isfinite(res.filtered).all()


def test_feature_buffers_of_a_directly_seen_light(device_spec):
    """The lamp's pixels carry the emitter flag and its own colour as albedo
    (its emission over its largest component); the ceiling's do not."""
    r = clpt.Renderer("cornell_box", device=device_spec, aux=True)
    res = r.render(4, width=32, height=32, seed=3)
    aux = res.aux
    lamp = aux["emitter"] == 1.0
    le = np.array([18.387, 13.9873, 6.75357])
    assert 4 <= lamp.sum() < 40
    assert np.allclose(aux["albedo"][lamp], le / le.max(), atol=1e-5)
    assert np.allclose(aux["emission"][lamp], le, rtol=1e-5)
    seen = aux["emitter"] > 0
    assert (aux["emission"][~seen] == 0).all() and (aux["emitter"][aux["emission"][..., 0] == 0] == 0).all()
    assert not np.allclose(aux["albedo"][lamp][0], aux["albedo"][1, 16])  # the ceiling beside it


def test_feature_buffers_see_through_glass_or_stop_at_it(device_spec):
    """aux_specular="surface" describes the glass and mirror balls by their own
    surfaces (nearer than what is seen through them), "through" by what lies
    behind them."""
    r = clpt.Renderer("cornell_box_caustics", device=device_spec, aux=True)
    through = r.render(2, width=32, height=32, seed=4, photons=clpt.PhotonSettings(count=10_000),
                       aux_specular="through").aux
    surface = r.render(2, width=32, height=32, seed=4, photons=clpt.PhotonSettings(count=10_000),
                       aux_specular="surface").aux
    nearer = surface["depth"] < through["depth"] - 1e-3
    assert 10 < nearer.sum() < 400 and (surface["depth"] <= through["depth"] + 1e-4).all()
    # "glass" (the default): the mirror ball as a surface, what is seen through the glass ball
    glass = r.render(2, width=32, height=32, seed=4, photons=clpt.PhotonSettings(count=10_000)).aux
    as_surface = nearer & np.isclose(glass["depth"], surface["depth"], rtol=1e-5)
    as_through = nearer & np.isclose(glass["depth"], through["depth"], rtol=1e-5)
    assert as_surface.sum() > 5 and as_through.sum() > 5
    assert (as_surface | as_through).sum() >= 0.8 * nearer.sum()  # the rest: rims, where both balls' samples mix
    xs = np.nonzero(nearer)[1]
    # the two balls sit side by side: the pixels described as surfaces and as seen through are apart
    assert abs(np.nonzero(as_surface)[1].mean() - np.nonzero(as_through)[1].mean()) > 0.2 * (xs.max() - xs.min())
    with pytest.raises(clpt.SceneError, match="aux_specular"):
        r.render(1, width=8, height=8, aux_specular="mirror")


def test_oidn_denoises_with_our_buffers(caustic_renders):
    pytest.importorskip("pyoidn", reason="pyoidn is not installed (pip install 'clpt[oidn]')")
    results, r = caustic_renders
    res = results[0]
    ref = r.render(128, width=64, height=64, max_depth=16, seed=9).image
    outs = {aux: apply_denoiser(None, res.image, res.lum_var, res.sample_count, res.aux, OidnSettings(aux=aux).check())
            for aux in ("clean", "noisy", "none")}
    for aux, out in outs.items():
        assert out.shape == res.image.shape and out.dtype == np.float32 and np.isfinite(out).all()
        assert relmse(out, ref) < relmse(res.image, ref), aux
    res2 = r.render(2, width=16, height=16, seed=5, filter=OidnSettings())
    assert res2.filtered is not None and res2.filtered.shape == (16, 16, 3)


def test_oidn_settings_are_checked():
    with pytest.raises(clpt.SceneError, match="aux"):
        OidnSettings(aux="bright").check()


def _mirror_facing_a_lamp():
    """The camera looks at a mirror (kr 0.9) and, behind the camera, a lamp
    faces the mirror: every pixel sees the lamp, through the mirror only."""
    lamp = clpt.Material(kd=(0.5, 0.5, 0.5), emission=(2.0, 3.0, 4.0))
    return clpt.Scene(
        camera=clpt.Camera(origin=(0, 0, 0), target=(0, 0, -1), fov=40),
        shapes=[clpt.Quad(corner=(-4, -4, -1), edge_u=(8, 0, 0), edge_v=(0, 8, 0),
                          material=clpt.Material(kr=(0.9, 0.9, 0.9))),
                clpt.Quad(corner=(-4, -4, 1), edge_u=(0, 8, 0), edge_v=(8, 0, 0), material=lamp)])


@pytest.mark.parametrize("mode", ["surface", "through"])
def test_a_lamp_seen_in_a_mirror_is_kept_out_in_both_modes(device_spec, mode):
    """The emission reached through mirrors and glass alone is the denoisers'
    to keep out, and counted as seen, whatever describes the mirror itself."""
    r = clpt.Renderer(_mirror_facing_a_lamp(), device=device_spec, aux=True, photons=False)
    res = r.render(4, width=8, height=8, max_depth=1, seed=1, aux_specular=mode)
    assert np.allclose(res.image, 0.9 * np.array([2.0, 3.0, 4.0]), rtol=1e-5)
    assert np.allclose(res.aux["emission"], res.image, rtol=1e-5)
    assert (res.aux["emitter"] == 1.0).all()
    mirror = mode == "surface"  # the mirror as a surface (albedo kr, its normal), or the lamp seen in it
    assert np.allclose(res.aux["normal"], (0, 0, 1) if mirror else (0, 0, -1), atol=1e-5)
    assert np.allclose(res.aux["albedo"], 0.9 if mirror else 0.9 * np.array([0.5, 0.75, 1.0]), rtol=1e-5)
    from clpt.denoise import kept_emission
    assert np.array_equal(kept_emission(res.aux, res.sample_count, FilterSettings().confirm_k), res.aux["emission"])


def test_kept_emission_needs_the_pixels_samples_to_confirm_it():
    """Emission is kept out of the filtering where the share f of a pixel's n
    samples that see it has a relative standard error under 1 / k (f n >=
    k^2 (1 - f)): at n = 16 and k = 2, four hits and more, not three; and
    at the edge of such a pixel (a lamp's image, or its reflection's)."""
    from clpt.denoise import kept_emission
    f = np.zeros((16, 16), np.float32)
    f[2, 2], f[2, 8], f[8, 2], f[8, 8], f[8, 9] = 1 / 16, 3 / 16, 4 / 16, 1.0, 1 / 16
    aux = {"emission": np.repeat(f[..., None], 3, -1) * 10, "emitter": f}
    n = np.full(f.shape, 16.0)
    kept = kept_emission(aux, n, 2.0)[..., 0] > 0
    assert np.argwhere(kept).tolist() == [[8, 2], [8, 8], [8, 9]]  # isolated hits are noise; (8, 9) is an edge
    assert np.array_equal(kept_emission(aux, n, 0.0), aux["emission"])   # k = 0: all of it
    kept64 = kept_emission(aux, np.full(f.shape, 64.0), 2.0)[..., 0] > 0
    assert kept64[2, 2] and kept64[2, 8]  # 4 and 12 hits of 64


def test_firefly_clamp_spares_what_the_pixels_own_samples_confirm():
    """A pixel far above its neighbours is clamped when its own standard
    error is as large as its excess (a firefly: one sample among n), and
    kept when its samples agree (a highlight most of them see)."""
    rng = np.random.default_rng(5)
    img, var = noisy(rng, 32, 32, level=1.0, sigma=0.05)
    img[10, 10] = 20.0
    var[10, 10] = 20.0 ** 2          # its standard error is its value: one sample's outlier
    img[20, 20] = 20.0
    var[20, 20] = 2.0 ** 2           # 10% relative error: its samples agree
    c, _ = reference_firefly(img, var, 3.0, 2.0)
    assert c[10, 10] @ LUMA < 2.0 and np.array_equal(c[20, 20], img[20, 20])
    c, _ = reference_firefly(img, var, 3.0, 12.0)  # demanding more than 10 standard errors: clamped too
    assert c[20, 20] @ LUMA < 2.0


def test_value_term_compares_3x3_smoothed_luminance():
    """smooth3: (1 2 1) x (1 2 1) weights over the pixels in the image; a corner
    pixel averages its 2x2 with weights 4, 2, 2, 1."""
    from clpt.denoise import smooth3
    x = np.zeros((4, 5), np.float32)
    x[0, 0] = 9.0
    s = smooth3(x)
    assert s[0, 0] == pytest.approx(4 * 9 / 9)
    assert s[0, 1] == pytest.approx(2 * 9 / 12)
    assert s[1, 1] == pytest.approx(9 / 16)
    assert s[2, 2] == 0
    c = np.full((6, 7), 0.25, np.float32)
    assert np.allclose(smooth3(c), 0.25)


def test_dilate_is_a_square_of_radius_r():
    from clpt.denoise import dilate
    rng = np.random.default_rng(3)
    m = rng.random((23, 29)) > 0.97
    for r in (1, 2):
        pad = np.pad(m, r)
        want = np.zeros_like(m)
        for dy in range(2 * r + 1):
            for dx in range(2 * r + 1):
                want |= pad[dy:dy + 23, dx:dx + 29]
        assert (dilate(m, r) == want).all()
