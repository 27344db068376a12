"""The rough conductor's microfacet lobe (kernels/microfacet.h, bsdf.h):
values against Mitsuba 3's `roughconductor`, visible-normal sampling against
bsdf_pdf (chi-square), sample weights against eval / pdf, and furnaces."""

import json
import math
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

import clpt
from clpt.mitsuba import conductor_ior
from clpt.scene import check_scene

from stats import ALPHA, assert_matches_reference, chi2_test, sidak

pytestmark = pytest.mark.portability

DATA = Path(__file__).parent / "data" / "roughconductor_mitsuba.json"


def lobe(probe, alpha, dist, d, u1, u2, w, eta=(0, 0, 0), k=(1, 1, 1), km=(1, 1, 1), alpha_v=0.0):
    """probe_microfacet over incoming directions d (N, 3; towards the surface),
    uniforms u1, u2 and evaluation directions w (N, 3); normal +z, alpha along
    x, alpha_v along y (0: alpha)."""
    r4 = cl.cltypes.make_double4 if probe.real is np.float64 else cl.cltypes.make_float4
    cols = [d[:, 0], d[:, 1], d[:, 2], u1, u2, w[:, 0], w[:, 1], w[:, 2]]
    o = probe.run("probe_microfacet", cols, 12,
                  scalars=(r4(alpha, 1.0 if dist == "beckmann" else 0.0, alpha_v, 0), r4(*eta, 0), r4(*k, 0),
                           r4(*km, 0)))
    return {"wi": np.stack(o[0:3], 1), "weight": np.stack(o[3:6], 1), "spdf": o[6], "chosen": o[7] > 0,
            "f": np.stack(o[8:11], 1), "pdf": o[11]}


def incoming(theta_deg, n, phi_deg=0.0):
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.tile([-math.sin(t) * math.cos(p), -math.sin(t) * math.sin(p), -math.cos(t)], (n, 1))


# --- values against Mitsuba 3 ---------------------------------------------------------------------

def mitsuba_cases():
    return json.loads(DATA.read_text())["cases"]


@pytest.mark.parametrize("double", [False, True])
@pytest.mark.parametrize("case", range(9))
def test_eval_and_pdf_match_mitsuba(probes, case, double):
    """f cos and pdf against Mitsuba 3's (tests/mitsuba_roughconductor.py):
    GGX and Beckmann, isotropic and anisotropic (alpha_u along the shading
    frame's x, alpha_v along y)."""
    c = mitsuba_cases()[case]
    b = c["bsdf"]
    eta, k = (b["eta"], b["k"]) if "eta" in b else conductor_ior(b["material"])
    km = b.get("specular_reflectance", (1.0, 1.0, 1.0))
    wi = np.array([r["wi"] for r in c["rows"]])    # Mitsuba's: towards the viewer
    wo = np.array([r["wo"] for r in c["rows"]])
    ev = np.array([r["eval"] for r in c["rows"]])  # f cos_o
    pdf = np.array([r["pdf"] for r in c["rows"]])
    n = len(wi)
    out = lobe(probes(1, double=double), b.get("alpha_u", b.get("alpha")), b["distribution"], -wi, np.full(n, 0.5),
               np.full(n, 0.5), wo, eta, k, km, alpha_v=b.get("alpha_v", 0.0))
    f_cos = out["f"] * wo[:, 2:3]
    assert (ev > 0).sum() >= 32
    # Float rounding of the half vector near a narrow peak: relative 1e-3, and
    # an absolute floor far below the values that matter.
    np.testing.assert_allclose(f_cos, ev, rtol=2e-3, atol=1e-5 * ev.max())
    np.testing.assert_allclose(out["pdf"], pdf, rtol=2e-3, atol=1e-5 * pdf.max())


# --- sampling against the pdf ---------------------------------------------------------------------

def mirror_frame(d):
    """Unit mirror direction r of incoming d about +z and two axes around it."""
    r = d[0] * np.array([1.0, 1.0, -1.0])
    a = np.cross(r, [0.0, 1.0, 0.0]) if abs(r[1]) < 0.9 else np.cross(r, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    return r, a, np.cross(r, a)


N = 200_000
SAMPLING = [("ggx", 0.1, 30), ("ggx", 0.5, 0), ("ggx", 0.5, 75), ("ggx", 0.9, 60),
            ("beckmann", 0.1, 30), ("beckmann", 0.5, 0), ("beckmann", 0.5, 75), ("beckmann", 0.9, 60)]


@pytest.mark.parametrize("dist,alpha,theta", SAMPLING)
def test_visible_normal_sampling_matches_pdf(probes, dist, alpha, theta):
    """Histogram of sampled directions in (angle psi from the mirror
    direction, azimuth about it) against bsdf_pdf integrated over each cell
    (midpoint rule, 12 x 12 points a cell), plus two cells: the directions
    beyond psi_max (the pdf integrated there on a coarser grid) and the
    samples lost below the surface (the pdf's missing mass)."""
    _sampling_chi2(probes, dist, alpha, theta, 0.0, 0.0, len(SAMPLING) + len(ANISO_SAMPLING))


# Anisotropic: (distribution, alpha_u, alpha_v, theta, azimuth of incidence from the tangent).
ANISO_SAMPLING = [("ggx", 0.05, 0.5, 45, 30), ("ggx", 0.6, 0.1, 70, 60), ("beckmann", 0.1, 0.4, 30, 120),
                  ("beckmann", 0.5, 0.15, 60, 10)]


@pytest.mark.parametrize("dist,alpha,alpha_v,theta,phi", ANISO_SAMPLING)
def test_anisotropic_sampling_matches_pdf(probes, dist, alpha, alpha_v, theta, phi):
    """As test_visible_normal_sampling_matches_pdf, for anisotropic lobes
    seen from azimuths off the frame's axes."""
    _sampling_chi2(probes, dist, alpha, theta, alpha_v, phi, len(SAMPLING) + len(ANISO_SAMPLING))


def _sampling_chi2(probes, dist, alpha, theta, alpha_v, azimuth, trials):
    rng = np.random.default_rng(11)
    probe = probes(8)
    d = incoming(theta, N, azimuth)
    out = lobe(probe, alpha, dist, d, rng.random(N), rng.random(N), d * np.array([-1, -1, 1]), alpha_v=alpha_v)
    r, a, b = mirror_frame(d)
    psi_max = min(2.0 * math.atan(3.5 * max(alpha, alpha_v)), 0.999 * math.pi)
    n_psi, n_phi, sub = 24, 16, 12
    w = out["wi"][out["chosen"]]
    psi = np.arccos(np.clip(w @ r, -1, 1))
    phi = np.arctan2(w @ b, w @ a)
    h, _, _ = np.histogram2d(psi, phi, bins=[np.linspace(0, psi_max, n_psi + 1), np.linspace(-np.pi, np.pi, n_phi + 1)])

    def pdf_mass(lo, hi, n_ps, n_ph):
        """The pdf integrated over psi in [lo, hi] on an n_ps x n_ph midpoint grid."""
        ps = lo + (np.arange(n_ps) + 0.5) * ((hi - lo) / n_ps)
        ph = -np.pi + (np.arange(n_ph) + 0.5) * (2 * np.pi / n_ph)
        P, F = np.meshgrid(ps, ph, indexing="ij")
        dirs = (np.cos(P)[..., None] * r + (np.sin(P) * np.cos(F))[..., None] * a
                + (np.sin(P) * np.sin(F))[..., None] * b).reshape(-1, 3)
        m = len(dirs)
        pdf = lobe(probe, alpha, dist, incoming(theta, m, azimuth), np.full(m, 0.5), np.full(m, 0.5), dirs,
                   alpha_v=alpha_v)["pdf"]
        return (pdf.astype(np.float64) * np.sin(P).ravel() * ((hi - lo) / n_ps) * (2 * np.pi / n_ph)).reshape(n_ps, n_ph)

    cell = pdf_mass(0.0, psi_max, n_psi * sub, n_phi * sub).reshape(n_psi, sub, n_phi, sub).sum(axis=(1, 3))
    tail = pdf_mass(psi_max, math.pi, 600, 192).sum()
    assert 0.5 < cell.sum() + tail <= 1.0 + 1e-3
    expected = np.concatenate([cell.ravel(), [tail, 1 - cell.sum() - tail]]) * N
    observed = np.concatenate([h.ravel(), [len(w) - h.sum(), N - len(w)]])
    p, stat, dof = chi2_test(observed, expected)
    assert p > sidak(ALPHA, trials), f"chi2 {stat:.1f} for {dof} dof, p = {p:.3g}"


@pytest.mark.parametrize("lanes", [1, 8])
@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
def test_sample_weight_is_f_cos_over_pdf(probes, lanes, dist):
    """A sample's weight f cos / pdf, and its pdf, agree with bsdf_eval and
    bsdf_pdf of the direction it drew (a gold conductor)."""
    rng = np.random.default_rng(5)
    n = 4000
    th = rng.uniform(0, 85, n)
    d = np.stack([-np.sin(np.radians(th)), np.zeros(n), -np.cos(np.radians(th))], 1)
    eta, k = conductor_ior("Au")
    probe = probes(lanes)
    out = lobe(probe, 0.3, dist, d, rng.random(n), rng.random(n), d, eta, k, (0.9, 0.8, 0.7))
    c = out["chosen"]
    assert c.mean() > 0.8
    back = lobe(probe, 0.3, dist, d[c], np.full(c.sum(), 0.5), np.full(c.sum(), 0.5), out["wi"][c], eta, k,
                (0.9, 0.8, 0.7))
    np.testing.assert_allclose(back["pdf"], out["spdf"][c], rtol=2e-3)
    expect = back["f"] * out["wi"][c][:, 2:3] / back["pdf"][:, None]
    np.testing.assert_allclose(out["weight"][c], expect, rtol=3e-3)
    assert (out["weight"][c] <= np.array([0.9, 0.8, 0.7]) * 1.0001).all()


# --- furnaces -------------------------------------------------------------------------------------

@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
def test_albedo_at_most_one(probes, dist, alpha):
    """A perfect reflector's directional albedo E[weight] is <= 1 at every
    incidence and, at alpha 0.05, within 1% of 1 up to 60 degrees (what the
    Smith masking loses there is smaller)."""
    rng = np.random.default_rng(3)
    n = 50_000
    for theta in (0, 30, 60, 80):
        out = lobe(probes(8), alpha, dist, incoming(theta, n), rng.random(n), rng.random(n), incoming(theta, n))
        wgt = np.where(out["chosen"], out["weight"][:, 0], 0.0).astype(np.float64)
        mean, se = wgt.mean(), wgt.std() / math.sqrt(n)
        assert mean <= 1.0 + 4 * se + 1e-6, f"albedo {mean:.5f} > 1 at {theta} deg"
        if alpha == 0.05 and theta <= 60:
            assert mean > 0.99, f"albedo {mean:.5f} at {theta} deg"


def test_gold_albedo_matches_mitsuba(probes):
    """The cosine-weighted hemispherical albedo of roughconductor(material=Au)
    (Mitsuba's defaults: Beckmann, alpha 0.1) as tests/mitsuba_measure.py --albedo measures it in
    Mitsuba 3.9.1 (0.9598, 0.8044, 0.3623; 2^24 samples): the mean sample
    weight over 64 incidence cosines, 8192 samples each here."""
    rng = np.random.default_rng(9)
    mus = (np.arange(64) + 0.5) / 64
    n = 8192
    d = np.concatenate([np.tile([-math.sqrt(1 - m * m), 0.0, -m], (n, 1)) for m in mus])
    eta, k = conductor_ior("Au")
    out = lobe(probes(8), 0.1, "beckmann", d, rng.random(len(d)), rng.random(len(d)), d, eta, k)
    w = np.where(out["chosen"][:, None], out["weight"], 0.0).reshape(64, n, 3).mean(axis=1)
    albedo = 2 * (w * mus[:, None]).mean(axis=0)
    np.testing.assert_allclose(albedo, [0.9598, 0.8044, 0.3623], rtol=3e-3)


@pytest.mark.parametrize("dist,alpha_v", [("ggx", None), ("beckmann", None), ("ggx", 0.12), ("beckmann", 0.12)])
def test_furnace_render(device_spec, dist, alpha_v):
    """Inside a black sphere that emits 1, a perfectly reflecting rough
    sphere shows the emission times its albedo: no pixel above 1 (within its
    noise), and at alpha 0.05 the image mean is within 1% of 1 (light
    sampling and BSDF sampling weighted by MIS); anisotropic (0.05 along
    dp/du, 0.12 across) within 2.5% (the masking's loss at an isotropic 0.12
    is 2.0% here with GGX, 0.4% with Beckmann; at 0.05, 0.5% and 0.1%)."""
    room = clpt.Sphere(center=(0, 0, 0), radius=1.5, material=clpt.Material(), emission=(1, 1, 1), two_sided=True)
    ball = clpt.Sphere(center=(0, 0, 0.6), radius=0.5, material=clpt.Material.rough_conductor(
        alpha=0.05, distribution=dist, alpha_v=alpha_v))
    cam = clpt.Camera(origin=(0, 0, -1.2), target=(0, 0, 1), fov=40, width=16, height=16)
    res = clpt.Renderer(clpt.Scene(camera=cam, shapes=[room, ball]), device=device_spec).render(
        256, max_depth=4, seed=2)
    n = res.sample_count.astype(np.float64)
    se = np.sqrt(res.lum_var / n)
    img = res.image[..., 0].astype(np.float64)
    assert res.stats.nonfinite == 0
    assert (img <= 1.0 + 5 * se + 1e-5).all(), f"max {img.max():.5f}"
    sigma = math.sqrt((se ** 2).sum()) / img.size
    floor = 0.99 if alpha_v is None else 0.975
    assert floor - 4 * sigma < img.mean() <= 1.0 + 4 * sigma, f"image mean {img.mean():.5f} (sigma {sigma:.2g})"


# --- Veach's plates against Mitsuba 3 -------------------------------------------------------------

PLATES = Path(__file__).parent / "data" / "plates.xml"
def test_plates_render_as_in_mitsuba(device_spec):
    """tests/data/plates.xml (four GGX plates from alpha 0.02 to 0.35, four
    sphere lights of equal power from radius 0.03 to 0.9) path traced at 4096
    spp: the mean colour within 0.5% of Mitsuba 3's (about 5 sigma of both
    renders' noise) and no 16x16 block beyond 4 sigma. With the plates as
    Phong lobes (the mapping clpt had before) the mean was 29% low and every
    block beyond 4 sigma, the worst by 620."""
    ref = json.loads((Path(__file__).parent / "data" / "plates_mitsuba.json").read_text())
    scene = clpt.load_scene(PLATES)
    res = clpt.Renderer(scene, device=device_spec, photons=False).render(spp=4096, seed=1)
    assert res.stats.nonfinite == 0
    assert_matches_reference(res, ref)


# --- scene API and loader -------------------------------------------------------------------------

@pytest.mark.parametrize("kw,msg", [
    ({"alpha": 0.0}, "alpha: must be >= 0.0001"),
    ({"alpha": -1.0}, "alpha: must be >= 0.0001"),
    ({"alpha": 11.0}, "alpha: must be <= 10"),
    ({"distribution": "phong"}, "distribution: must be one of ggx, beckmann"),
    ({"eta": (-1.0, 0.2, 0.2)}, "eta"),
    ({"km": (0.8, 0.8, 0.8), "kd": (0.5, 0.5, 0.5)}, "not energy conserving"),
])
def test_bad_rough_conductor_is_one_line_error(kw, msg):
    m = clpt.Material(**{"km": (1.0, 1.0, 1.0), **kw})
    scene = clpt.Scene(shapes=[clpt.Sphere(material=m)])
    with pytest.raises(clpt.SceneError) as e:
        check_scene(scene)
    assert msg in str(e.value) and "\n" not in str(e.value)


def test_rough_conductor_presets_and_types():
    m = clpt.Material.rough_conductor("Au", alpha=0.2, distribution="beckmann", specular_reflectance=(0.5, 0.6, 0.7))
    assert m.km == (0.5, 0.6, 0.7) and m.alpha == 0.2 and m.distribution == "beckmann" and m.one_sided
    assert m.eta == conductor_ior("Au")[0] and m.k == conductor_ior("Au")[1]
    with pytest.raises(clpt.SceneError, match="unknown conductor 'Gold'"):
        clpt.Material.rough_conductor("Gold")
    with pytest.raises(TypeError, match="Material.distribution"):
        clpt.Material(km=(1, 1, 1), distribution=3)


def _xml(bsdf):
    return f"""<scene version="3.0.0"><shape type="sphere">{bsdf}</shape>
        <shape type="sphere"><point name="center" x="0" y="3" z="0"/><emitter type="area">
        <rgb name="radiance" value="1"/></emitter></shape></scene>"""


def test_loader_maps_roughconductor(tmp_path):
    p = tmp_path / "s.xml"
    p.write_text(_xml('<bsdf type="roughconductor"><string name="distribution" value="beckmann"/>'
                      '<float name="alpha" value="0.3"/><string name="material" value="Cu"/>'
                      '<rgb name="specular_reflectance" value="0.9, 0.8, 0.7"/></bsdf>'))
    s = clpt.load_scene(p)
    m = s.shapes[0].material
    assert (m.distribution, m.alpha, m.km) == ("beckmann", 0.3, (0.9, 0.8, 0.7))
    assert m.eta == conductor_ior("Cu")[0] and max(m.ks) == 0
    # Mitsuba 3 gives an emitter without a BSDF a black one.
    assert max(s.shapes[1].material.kd) == 0
    p.write_text(_xml('<bsdf type="roughconductor"><float name="alpha" value="0.1"/>'
                      '<rgb name="eta" value="0.2, 0.9, 1.1"/><rgb name="k" value="3.9, 2.4, 1.9"/></bsdf>'))
    m = clpt.load_scene(p).shapes[0].material
    assert (m.distribution, m.eta, m.k) == ("beckmann", (0.2, 0.9, 1.1), (3.9, 2.4, 1.9))  # Mitsuba's default
    p.write_text(_xml('<bsdf type="roughconductor"><string name="distribution" value="phong"/></bsdf>'))
    with pytest.raises(clpt.SceneError, match="unknown distribution 'phong'"):
        clpt.load_scene(p)
