"""The rough dielectric (kernels/bsdf.h rough_dielectric_*): values against
Mitsuba 3's `roughdielectric`, sampling against bsdf_pdf (chi-square) over
both hemispheres, sample weights against eval / pdf, energy (white furnace),
the limit alpha -> 0 against the smooth dielectric, and a rough glass sphere
against a Mitsuba 3 reference."""

import json
import math
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

import clpt

from stats import ALPHA, chi2_test, sidak

pytestmark = pytest.mark.portability

DATA = Path(__file__).parent / "data"


def lobe(probe, alpha, dist, eta, d, u1, u2, uf, w, kr=(1, 1, 1), kt=(1, 1, 1), visible=True, importance=False,
         alpha_v=0.0):
    """probe_rough_dielectric over incoming directions d (N, 3; towards the
    surface, from above: outside, or below: inside), uniforms u1, u2, uf and
    evaluation directions w (N, 3); eta inside over outside; normal +z, alpha
    along x, alpha_v along y (0: alpha)."""
    r4 = cl.cltypes.make_double4 if probe.real is np.float64 else cl.cltypes.make_float4
    cols = [d[:, 0], d[:, 1], d[:, 2], u1, u2, uf, w[:, 0], w[:, 1], w[:, 2]]
    o = probe.run("probe_rough_dielectric", cols, 13,
                  scalars=(r4(alpha, 1.0 if dist == "beckmann" else 0.0, eta, 1.0 if visible else 0.0),
                           r4(*kr, alpha_v), r4(*kt, 1.0 if importance else 0.0)))
    return {"wi": np.stack(o[0:3], 1).astype(np.float64), "weight": np.stack(o[3:6], 1).astype(np.float64),
            "spdf": o[6].astype(np.float64), "chosen": o[7] > 0, "up": o[8] > 0,
            "f": np.stack(o[9:12], 1).astype(np.float64), "pdf": o[12].astype(np.float64)}


def incoming(theta_deg, n, inside=False):
    t = math.radians(theta_deg)
    return np.tile([-math.sin(t), 0.0, math.cos(t) if inside else -math.cos(t)], (n, 1))


# --- values against Mitsuba 3 ---------------------------------------------------------------------

def mitsuba_cases():
    return json.loads((DATA / "roughdielectric_mitsuba.json").read_text())["cases"]


@pytest.mark.parametrize("double", [False, True])
@pytest.mark.parametrize("case", range(10))
def test_eval_and_pdf_match_mitsuba(probes, case, double):
    """f |cos| and pdf against Mitsuba 3.9.1's eval and pdf (radiance
    transport; tests/mitsuba_roughdielectric.py): reflection and transmission,
    from outside and inside, GGX and Beckmann, tinted reflectance and
    transmittance, visible-normal and plain sampling, anisotropic roughness
    (alpha_u along the shading frame's x)."""
    c = mitsuba_cases()[case]
    b = c["bsdf"]
    wi = np.array([r["wi"] for r in c["rows"]])    # Mitsuba's: towards the viewer
    wo = np.array([r["wo"] for r in c["rows"]])
    ev = np.array([r["eval"] for r in c["rows"]])  # f |cos_o|
    pdf = np.array([r["pdf"] for r in c["rows"]])
    n = len(wi)
    h = np.full(n, 0.5)
    out = lobe(probes(1, double=double), b.get("alpha_u", b.get("alpha")), b["distribution"],
               b["int_ior"] / b["ext_ior"], -wi, h, h, h, wo, b.get("specular_reflectance", (1, 1, 1)),
               b.get("specular_transmittance", (1, 1, 1)), b.get("sample_visible", True), alpha_v=b.get("alpha_v", 0.0))
    f_cos = out["f"] * np.abs(wo[:, 2:3])
    through = wi[:, 2] * wo[:, 2] < 0
    assert (ev[:, 0] > 0).sum() >= 48 and (ev[through, 0] > 0).sum() >= 6
    np.testing.assert_allclose(f_cos, ev, rtol=2e-3, atol=1e-5 * ev.max())
    np.testing.assert_allclose(out["pdf"], pdf, rtol=2e-3, atol=1e-5 * pdf.max())


# --- sampling against the pdf ---------------------------------------------------------------------

def refracted(d, eta):
    """The smooth refraction of unit incoming d (towards the surface) through the
    z = 0 plane, eta inside over outside (d from below: inside); None at total
    internal reflection."""
    inside = d[2] > 0
    e = 1 / eta if inside else eta
    c = abs(d[2])
    s2 = (1 - c * c) / (e * e)
    if s2 >= 1:
        return None
    t = np.array([d[0] / e, d[1] / e, 0.0])
    t[2] = math.copysign(math.sqrt(1 - s2), d[2])
    return t


def axes(c):
    a = np.cross(c, [0.0, 1.0, 0.0]) if abs(c[1]) < 0.9 else np.cross(c, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    return a, np.cross(c, a)


N = 200_000
# (distribution, alpha, eta, incidence in degrees, from inside, sample_visible)
SAMPLING = [("ggx", 0.08, 1.5, 30, False, True), ("ggx", 0.08, 1.5, 30, True, True),
            ("beckmann", 0.1, 1.5, 45, False, True), ("beckmann", 0.1, 1.33, 20, True, True),
            ("ggx", 0.5, 1.5, 0, False, True), ("ggx", 0.5, 1.5, 60, True, True),
            ("beckmann", 0.5, 2.4, 70, False, True), ("beckmann", 0.3, 1.5, 45, True, True),
            ("ggx", 0.3, 1.5, 30, False, False), ("beckmann", 0.3, 1.5, 50, True, False)]


@pytest.mark.parametrize("dist,alpha,eta,theta,inside,visible", SAMPLING)
def test_sampling_matches_pdf(probes, dist, alpha, eta, theta, inside, visible):
    """Histogram of sampled directions over both hemispheres against
    bsdf_pdf integrated over each cell (midpoint rule), plus one cell for
    everything else and the lost samples. Narrow lobes (alpha < 0.2): cells in
    (angle from the centre, azimuth) of a cone around the mirror direction
    and one around the smooth refraction, each kept clear of the horizon;
    wide ones: cells in (theta, phi) over the whole sphere (the horizon a
    cell edge). The cones' sizes are the 95% quantiles of their samples' angles."""
    rng = np.random.default_rng(13)
    probe = probes(8)
    d = incoming(theta, N, inside)
    out = lobe(probe, alpha, dist, eta, d, rng.random(N), rng.random(N), rng.random(N), d, visible=visible)
    w = out["wi"][out["chosen"]]
    side = 1.0 if inside else -1.0  # the side d comes from is -side... the viewer's side sign of z
    up = -side                      # z sign of the viewer's hemisphere

    def pdf_of(dirs):
        m = len(dirs)
        h = np.full(m, 0.5)
        return lobe(probe, alpha, dist, eta, incoming(theta, m, inside), h, h, h, dirs, visible=visible)["pdf"]

    if alpha < 0.2:
        centres = [d[0] * np.array([1.0, 1.0, -1.0])]
        t = refracted(d[0], eta)
        centres.append(t if t is not None else np.array([0.0, 0.0, -up]))
        n_psi, n_phi, sub = 16, 12, 10
        observed, expected = [], []
        for k, c in enumerate(centres):
            hemi = up if k == 0 else -up
            a, b = axes(c)
            sel = w[(w[:, 2] * hemi > 0)]
            psi = np.arccos(np.clip(sel @ c, -1, 1))
            # The refracted lobe is narrower or wider than the reflected one by
            # the refraction's Jacobian: the cone holds most of each lobe's samples.
            psi_max = min(np.quantile(psi, 0.95) if len(psi) > 1000 else 2.0 * math.atan(3.5 * alpha),
                          math.asin(min(1.0, abs(c[2]))) - 0.02)
            phi = np.arctan2(sel @ b, sel @ a)
            h, _, _ = np.histogram2d(psi, phi, bins=[np.linspace(0, psi_max, n_psi + 1),
                                                     np.linspace(-np.pi, np.pi, n_phi + 1)])
            ps = (np.arange(n_psi * sub) + 0.5) * (psi_max / (n_psi * sub))
            ph = -np.pi + (np.arange(n_phi * sub) + 0.5) * (2 * np.pi / (n_phi * sub))
            P, F = np.meshgrid(ps, ph, indexing="ij")
            dirs = (np.cos(P)[..., None] * c + (np.sin(P) * np.cos(F))[..., None] * a
                    + (np.sin(P) * np.sin(F))[..., None] * b).reshape(-1, 3)
            mass = pdf_of(dirs) * np.sin(P).ravel() * (psi_max / (n_psi * sub)) * (2 * np.pi / (n_phi * sub))
            observed.append(h.ravel())
            expected.append(mass.reshape(n_psi, sub, n_phi, sub).sum(axis=(1, 3)).ravel())
        observed, expected = np.concatenate(observed), np.concatenate(expected)
    else:
        n_t, n_phi, sub = 32, 24, 8
        h, _, _ = np.histogram2d(np.arccos(np.clip(w[:, 2], -1, 1)), np.arctan2(w[:, 1], w[:, 0]),
                                 bins=[np.linspace(0, np.pi, n_t + 1), np.linspace(-np.pi, np.pi, n_phi + 1)])
        ts = (np.arange(n_t * sub) + 0.5) * (np.pi / (n_t * sub))
        ph = -np.pi + (np.arange(n_phi * sub) + 0.5) * (2 * np.pi / (n_phi * sub))
        TH, F = np.meshgrid(ts, ph, indexing="ij")
        dirs = np.stack([np.sin(TH) * np.cos(F), np.sin(TH) * np.sin(F), np.cos(TH)], -1).reshape(-1, 3)
        mass = pdf_of(dirs) * np.sin(TH).ravel() * (np.pi / (n_t * sub)) * (2 * np.pi / (n_phi * sub))
        observed = h.ravel()
        expected = mass.reshape(n_t, sub, n_phi, sub).sum(axis=(1, 3)).ravel()
    total = expected.sum()
    assert 0.5 < total <= 1.0 + 2e-3, f"pdf mass in the cells {total:.4f}"
    observed = np.concatenate([observed, [N - observed.sum()]])
    expected = np.concatenate([expected, [max(1.0 - total, 0.0)]]) * N
    p, stat, dof = chi2_test(observed, expected)
    assert p > sidak(ALPHA, len(SAMPLING)), f"chi2 {stat:.1f} for {dof} dof, p = {p:.3g}"


@pytest.mark.parametrize("lanes", [1, 8])
@pytest.mark.parametrize("dist,visible", [("ggx", True), ("beckmann", True), ("ggx", False)])
def test_sample_weight_is_f_cos_over_pdf(probes, lanes, dist, visible):
    """A sample's weight f |cos| / pdf (radiance: the transmitted one includes
    1 / eta^2), and its pdf, agree with bsdf_eval and bsdf_pdf of the
    direction it drew, from both sides; refracted samples leave below."""
    rng = np.random.default_rng(5)
    n = 4000
    th = rng.uniform(0, 85, n)
    inside = rng.random(n) < 0.5
    d = np.stack([-np.sin(np.radians(th)), np.zeros(n), np.where(inside, 1, -1) * np.cos(np.radians(th))], 1)
    kr, kt = (0.9, 0.8, 0.7), (0.6, 0.7, 0.95)
    probe = probes(lanes)
    out = lobe(probe, 0.3, dist, 1.5, d, rng.random(n), rng.random(n), rng.random(n), d, kr, kt, visible=visible)
    c = out["chosen"]
    assert c.mean() > 0.8
    wi = out["wi"][c]
    through = wi[:, 2] * d[c][:, 2] > 0
    assert 0.1 < through.mean() < 0.95
    np.testing.assert_array_equal(out["up"][c], ~through)
    h = np.full(c.sum(), 0.5)
    back = lobe(probe, 0.3, dist, 1.5, d[c], h, h, h, wi, kr, kt, visible=visible)
    np.testing.assert_allclose(back["pdf"], out["spdf"][c], rtol=2e-3)
    expect = back["f"] * np.abs(wi[:, 2:3]) / back["pdf"][:, None]
    np.testing.assert_allclose(out["weight"][c], expect, rtol=3e-3)
    e = np.where(inside[c], 1 / 1.5, 1.5)[:, None]
    bound = np.where(through[:, None], np.array(kt) / (e * e), np.array(kr))
    if visible:
        assert (out["weight"][c] <= bound * 1.0001).all()


# --- energy ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
@pytest.mark.parametrize("alpha", [0.02, 0.3, 1.0])
def test_white_furnace(probes, dist, alpha):
    """With specular_reflectance = specular_transmittance = 1, the albedo (the
    mean importance-transport weight, f |cos| / pdf without the radiance's
    1 / eta^2, over both hemispheres) is <= 1 from outside and inside, and at
    alpha 0.02 within 1% of 1 up to 60 degrees (what Smith masking loses)."""
    rng = np.random.default_rng(3)
    n = 50_000
    for inside in (False, True):
        for theta in (0, 30, 60, 80):
            d = incoming(theta, n, inside)
            out = lobe(probes(8), alpha, dist, 1.5, d, rng.random(n), rng.random(n), rng.random(n), d,
                       importance=True)
            wgt = np.where(out["chosen"], out["weight"][:, 0], 0.0)
            mean, se = wgt.mean(), wgt.std() / math.sqrt(n)
            assert mean <= 1.0 + 4 * se + 1e-5, f"albedo {mean:.5f} > 1 at {theta} deg (inside {inside})"
            if alpha == 0.02 and theta <= 60:
                assert mean > 0.99, f"albedo {mean:.5f} at {theta} deg (inside {inside})"


# --- alpha -> 0: the smooth dielectric ------------------------------------------------------------

@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
def test_small_alpha_is_the_smooth_dielectric(probes, dist):
    """At alpha 1e-4 a sample reflects with the smooth interface's Fresnel
    probability, within 1e-2 rad of the mirror or refracted direction, with
    weight 1 (reflection) or 1 / eta^2 (refraction, radiance), 99 in 100
    (directions) and 999 in 1000 (weights) of them: the smooth dielectric's (bsdf.h dielectric_sample), from outside
    and inside."""
    from clpt.mitsuba import fresnel_dielectric

    rng = np.random.default_rng(8)
    n = 20_000
    for inside in (False, True):
        for theta in (0, 25, 40, 70):
            d = incoming(theta, n, inside)
            out = lobe(probes(8), 1e-4, dist, 1.5, d, rng.random(n), rng.random(n), rng.random(n), d)
            e = 1 / 1.5 if inside else 1.5
            F = fresnel_dielectric(math.cos(math.radians(theta)), e)
            assert out["chosen"].mean() > 0.999
            refl = out["up"]
            assert abs(refl.mean() - F) < 4 * math.sqrt(max(F * (1 - F), 1e-12) / n) + 1e-4, \
                f"P(reflect) {refl.mean():.4f}, F {F:.4f} at {theta} deg (inside {inside})"
            mirror = d[0] * np.array([1.0, 1.0, -1.0])
            # (GGX's long tail: a few in 10^4 samples lie farther out.)
            assert np.quantile(np.arccos(np.clip(out["wi"][refl] @ mirror, -1, 1)), 0.99) < 1e-2
            assert np.quantile(np.abs(out["weight"][refl] - 1.0), 0.999) < 2e-3
            if F < 1:
                t = refracted(d[0], 1.5)
                assert np.quantile(np.arccos(np.clip(out["wi"][~refl] @ t, -1, 1)), 0.99) < 1e-2
                assert np.quantile(np.abs(out["weight"][~refl] * e * e - 1.0), 0.999) < 2e-3


# --- loading, features ----------------------------------------------------------------------------

GLASS = DATA / "rough_glass.xml"


def test_loader_and_flag(tmp_path):
    """The XML loader reads roughdielectric as the lobe itself (Mitsuba's
    defaults and named indices), and only scenes with one compile it in."""
    from clpt.features import scene_features
    from clpt.pack import pack_scene

    plain = pack_scene(clpt.load_scene("fig11_glass_ball"))
    assert not plain.has_rough_dielectric and scene_features(plain).defines()["CLPT_HAS_ROUGH_DIELECTRIC"] == 0
    packed = pack_scene(clpt.load_scene(GLASS))
    assert packed.has_rough_dielectric and scene_features(packed).defines()["CLPT_HAS_ROUGH_DIELECTRIC"] == 1
    a, b = [m for m in packed.materials if m.rough_dielectric_lobe]
    assert (a.distribution, a.alpha, b.distribution, b.alpha) == ("ggx", 0.1, "beckmann", 0.3)
    assert a.ior == pytest.approx(1.5046 / 1.000277) and b.ior == pytest.approx(1.33 / 1.000277)
    assert b.kgt == pytest.approx((0.95, 0.75, 0.5)) and b.kgr == (1.0, 1.0, 1.0)
    xml = ('<scene version="3.0.0"><shape type="sphere"><bsdf type="roughdielectric">'
           '<string name="int_ior" value="water"/><string name="ext_ior" value="bk7"/>'
           '<boolean name="sample_visible" value="false"/></bsdf></shape>'
           '<emitter type="point"><point name="position" value="0, 3, 0"/></emitter></scene>')
    (tmp_path / "s.xml").write_text(xml)
    m = clpt.load_scene(tmp_path / "s.xml").shapes[0].material
    assert m.rough_dielectric_lobe and not m.sample_visible and m.ior == pytest.approx(1.333 / 1.5046)
    assert (m.alpha, m.distribution) == (0.1, "beckmann")  # Mitsuba's defaults


def test_toml_rough_dielectric(tmp_path):
    """A TOML material with rough_dielectric = true is the same material as Material.rough_dielectric."""
    p = tmp_path / "s.toml"
    p.write_text('[camera]\norigin = [0, 0, 5]\ntarget = [0, 0, 0]\nfov = 40\nwidth = 8\nheight = 8\n\n[materials.frost]\nrough_dielectric = true\nalpha = 0.2\ndistribution = "ggx"\nior = 1.33\n'
                 'kgt = [0.9, 0.8, 0.7]\nsample_visible = false\n\n'
                 '[[shapes]]\ntype = "sphere"\nmaterial = "frost"\ncenter = [0, 0, 0]\nradius = 1\n\n'
                 '[[shapes]]\ntype = "sphere"\nmaterial = "black"\ncenter = [0, 3, 0]\nradius = 0.5\n'
                 'emission = [1, 1, 1]\n')
    m = clpt.load_scene(p).materials["frost"]
    assert m == clpt.Material.rough_dielectric(alpha=0.2, distribution="ggx", int_ior=1.33, ext_ior=1.0,
                                               specular_transmittance=(0.9, 0.8, 0.7), sample_visible=False)


def test_bad_rough_dielectrics_fail_in_one_line(tmp_path):
    def load(bsdf):
        p = tmp_path / "s.xml"
        p.write_text(f'<scene version="3.0.0"><shape type="sphere">{bsdf}</shape>'
                     '<emitter type="point"><point name="position" value="0, 3, 0"/></emitter></scene>')
        return clpt.load_scene(p)

    with pytest.raises(clpt.SceneError, match="int_ior and ext_ior must differ"):
        load('<bsdf type="roughdielectric"><float name="int_ior" value="1.3"/>'
             '<float name="ext_ior" value="1.3"/></bsdf>')
    with pytest.raises(clpt.SceneError, match="unknown distribution 'phong'"):
        load('<bsdf type="roughdielectric"><string name="distribution" value="phong"/></bsdf>')
    with pytest.raises(clpt.SceneError, match="only lobe"):
        clpt.Renderer(clpt.Scene(shapes=[clpt.Sphere(material=clpt.Material.rough_dielectric(kd=(0.5, 0.5, 0.5)))]))
    with pytest.raises(clpt.SceneError, match="at most 1"):
        clpt.Renderer(clpt.Scene(shapes=[clpt.Sphere(material=clpt.Material.rough_dielectric(
            specular_transmittance=(1.5, 1, 1)))]))
    with pytest.raises(clpt.SceneError, match="int_ior"):
        clpt.Material.rough_dielectric(int_ior=-1)


# --- a scene against Mitsuba 3 --------------------------------------------------------------------

def test_rough_glass_renders_as_in_mitsuba(device_spec):
    """tests/data/rough_glass.xml (two rough glass spheres, GGX and Beckmann,
    one tinted, on a diffuse floor under an area light) path traced at 2048
    spp: the mean colour within 0.5% of Mitsuba 3's and no 16x16 block
    beyond 4 sigma of both renders' noise (tests/stats.py assert_matches_reference)."""
    from stats import assert_matches_reference

    ref = json.loads((DATA / "rough_glass_mitsuba.json").read_text())
    res = clpt.Renderer(clpt.load_scene(GLASS), device=device_spec, photons=False).render(spp=2048, seed=1)
    assert res.stats.nonfinite == 0
    assert_matches_reference(res, ref)
