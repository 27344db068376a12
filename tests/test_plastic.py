"""Mitsuba's `roughplastic` and `plastic` (kernels/bsdf.h plastic_*,
clpt/coating.py): eval and pdf against Mitsuba 3's values, sampling against
bsdf_pdf (chi-square), sample weights against eval / pdf, energy."""

import json
import math
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

import clpt
from clpt import coating
from clpt.pack import _material_records

from stats import ALPHA, assert_matches_reference, chi2_test, sidak

pytestmark = pytest.mark.portability

DATA = Path(__file__).parent / "data" / "roughplastic_mitsuba.json"


def material_of(case):
    """clpt's Material for a Mitsuba case (tests/mitsuba_roughplastic.py)."""
    kw = {k: tuple(v) if isinstance(v, list) else v for k, v in case.items() if k != "type"}
    if case["type"] == "plastic":
        return clpt.Material.smooth_plastic(**kw)
    return clpt.Material.rough_plastic(**kw)


def lobe(probe, m, d, u1, u2, uf, w):
    """probe_plastic for material m over incoming directions d (N, 3),
    uniforms u1, u2, uf and evaluation directions w (N, 3); normal +z."""
    rec = _material_records([m])[0]
    r4 = cl.cltypes.make_double4 if probe.real is np.float64 else cl.cltypes.make_float4
    tab = np.zeros((16, 4), dtype=probe.real)
    if m.alpha > 0:
        tab[:] = np.reshape(coating.rough_tables(m.alpha, m.distribution, m.plastic_eta)[0], (16, 4))
    buf = cl.Buffer(probe.dctx.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=tab)
    c = rec["coat"]
    cols = [d[:, 0], d[:, 1], d[:, 2], u1, u2, uf, w[:, 0], w[:, 1], w[:, 2]]
    o = probe.run("probe_plastic", cols, 13, prefix=(buf,),
                  scalars=(r4(*c), r4(*m.kp, float(m.nonlinear)), r4(*m.kps, rec["kps_w"][3])))
    return {"wi": np.stack(o[0:3], 1), "weight": np.stack(o[3:6], 1), "spdf": o[6], "chosen": o[7] > 0,
            "delta": o[8] > 0, "f": np.stack(o[9:12], 1), "pdf": o[12]}


def incoming(theta_deg, n):
    t = math.radians(theta_deg)
    return np.tile([-math.sin(t), 0.0, -math.cos(t)], (n, 1))


def mitsuba_cases():
    return json.loads(DATA.read_text())["cases"]


# --- the host's tables against Mitsuba's ------------------------------------------------------------

def test_fdr_fit_is_mitsubas():
    """Mitsuba's fitted diffuse Fresnel reflectance against the exact
    cosine-weighted average of Fresnel (its papers' stated accuracy)."""
    from clpt.mitsuba import fresnel_diffuse_reflectance as exact
    for eta in (1.2, 1.49, 1.7):
        assert coating.fresnel_diffuse_reflectance(eta) == pytest.approx(exact(eta), rel=2e-3, abs=1e-3)
        assert coating.fresnel_diffuse_reflectance(1 / eta) == pytest.approx(exact(1 / eta), rel=6e-3)


def test_transmittance_table_limits():
    """t(mu) of a nearly smooth coating is 1 - F(mu) (away from grazing), and
    every table lies in [0, 1]."""
    from clpt.mitsuba import fresnel_dielectric
    t, r = coating.rough_tables(0.001, "ggx", 1.5)
    mu = np.linspace(0, 1, coating.TABLE_RES)
    for i in range(20, coating.TABLE_RES):
        assert t[i] == pytest.approx(1 - fresnel_dielectric(mu[i], 1.5), abs=2e-3)
    for alpha in (0.05, 0.5, 1.0):
        t, r = coating.rough_tables(alpha, "beckmann", 1.49)
        assert 0 <= min(t) and max(t) <= 1 and 0 < r < 1


# --- values against Mitsuba 3 ---------------------------------------------------------------------

@pytest.mark.parametrize("double", [False, True])
@pytest.mark.parametrize("case", range(6))
def test_eval_and_pdf_match_mitsuba(probes, case, double):
    """f cos and pdf of each direction pair against Mitsuba 3's (the rough
    coating's tables integrated as Mitsuba integrates them, clpt/coating.py)."""
    c = mitsuba_cases()[case]
    m = material_of(c["bsdf"])
    wi = np.array([r["wi"] for r in c["rows"]])
    wo = np.array([r["wo"] for r in c["rows"]])
    ev = np.array([r["eval"] for r in c["rows"]])
    pdf = np.array([r["pdf"] for r in c["rows"]])
    n = len(wi)
    half = np.full(n, 0.5)
    out = lobe(probes(1, double=double), m, -wi, half, half, half, wo)
    f_cos = out["f"] * wo[:, 2:3]
    assert (ev > 0).all()
    rtol = 1e-3 if m.alpha > 0 or not double else 2e-4
    np.testing.assert_allclose(f_cos, ev, rtol=rtol, atol=1e-6 * ev.max())
    np.testing.assert_allclose(out["pdf"], pdf, rtol=rtol, atol=1e-6 * pdf.max())


# --- sampling against the pdf ---------------------------------------------------------------------

N = 200_000
SAMPLING = [("ggx", 0.1, 30), ("ggx", 0.5, 75), ("beckmann", 0.2, 0), ("beckmann", 0.6, 60), ("smooth", 0.0, 45)]


@pytest.mark.parametrize("dist,alpha,theta", SAMPLING)
def test_sampling_matches_pdf(probes, dist, alpha, theta):
    """Histogram of the non-delta sampled directions in (cos theta, phi)
    cells of the hemisphere against bsdf_pdf integrated over each cell
    (midpoint rule, 8 x 8 points a cell), plus one cell: the samples that
    were lost or delta (the smooth coating's reflection, with the
    probability its pdf leaves out)."""
    rng = np.random.default_rng(13)
    probe = probes(8)
    m = clpt.Material.rough_plastic((0.7, 0.4, 0.2), alpha=alpha, distribution="beckmann" if dist == "smooth" else dist,
                                    int_ior=1.5, ext_ior=1.0)
    d = incoming(theta, N)
    out = lobe(probe, m, d, rng.random(N), rng.random(N), rng.random(N), d)
    nd = out["chosen"] & ~out["delta"]
    w = out["wi"][nd]
    n_mu, n_phi, sub = 24, 24, 8
    # The specular peak is narrow: cells in u = cos theta squared near the mirror direction are fine enough.
    h, _, _ = np.histogram2d(w[:, 2], np.arctan2(w[:, 1], w[:, 0]),
                             bins=[np.linspace(0, 1, n_mu + 1), np.linspace(-np.pi, np.pi, n_phi + 1)])
    mu = (np.arange(n_mu * sub) + 0.5) / (n_mu * sub)
    ph = -np.pi + (np.arange(n_phi * sub) + 0.5) * (2 * np.pi / (n_phi * sub))
    M, P = np.meshgrid(mu, ph, indexing="ij")
    s = np.sqrt(1 - M * M)
    dirs = np.stack([s * np.cos(P), s * np.sin(P), M], -1).reshape(-1, 3)
    k = len(dirs)
    pdf = lobe(probe, m, incoming(theta, k), np.full(k, 0.5), np.full(k, 0.5), np.full(k, 0.5), dirs)["pdf"]
    cell = (pdf.astype(np.float64) * (1 / (n_mu * sub)) * (2 * np.pi / (n_phi * sub))).reshape(
        n_mu, sub, n_phi, sub).sum(axis=(1, 3))
    assert 0.3 < cell.sum() <= 1.0 + 2e-3
    expected = np.concatenate([cell.ravel(), [max(1 - cell.sum(), 0.0)]]) * N
    observed = np.concatenate([h.ravel(), [N - nd.sum()]])
    if dist == "smooth":  # the rest is the delta reflection, chosen with exactly that probability
        assert abs(out["delta"].mean() - (1 - cell.sum())) < 5 * math.sqrt((1 - cell.sum()) / N) + 2e-3
    p, stat, dof = chi2_test(observed, expected)
    assert p > sidak(ALPHA, len(SAMPLING)), f"chi2 {stat:.1f} for {dof} dof, p = {p:.3g}"


@pytest.mark.parametrize("lanes", [1, 8])
@pytest.mark.parametrize("alpha", [0.0, 0.05, 0.4])
def test_sample_weight_is_f_cos_over_pdf(probes, lanes, alpha):
    """A non-delta sample's weight f cos / pdf and its pdf agree with
    bsdf_eval and bsdf_pdf of the direction it drew; a delta one's is kps F / q."""
    rng = np.random.default_rng(5)
    n = 4000
    th = rng.uniform(0, 85, n)
    d = np.stack([-np.sin(np.radians(th)), np.zeros(n), -np.cos(np.radians(th))], 1)
    m = clpt.Material.rough_plastic((0.9, 0.5, 0.1), alpha=alpha, distribution="ggx", nonlinear=True,
                                    specular_reflectance=(0.9, 0.8, 0.7))
    probe = probes(lanes)
    out = lobe(probe, m, d, rng.random(n), rng.random(n), rng.random(n), d)
    c = out["chosen"] & ~out["delta"]
    assert c.mean() > 0.5 and (out["delta"].any() == (alpha == 0))
    back = lobe(probe, m, d[c], np.full(c.sum(), 0.5), np.full(c.sum(), 0.5), np.full(c.sum(), 0.5),
                out["wi"][c])
    np.testing.assert_allclose(back["pdf"], out["spdf"][c], rtol=2e-3)
    expect = back["f"] * out["wi"][c][:, 2:3] / back["pdf"][:, None]
    np.testing.assert_allclose(out["weight"][c], expect, rtol=3e-3)


# --- energy ---------------------------------------------------------------------------------------

def albedo(probe, m, n=8192, seed=9):
    """The cosine-weighted hemispherical albedo (RGB): the mean sample weight
    over 64 incidence cosines, n samples each, and its standard error."""
    rng = np.random.default_rng(seed)
    mus = (np.arange(64) + 0.5) / 64
    d = np.concatenate([np.tile([-math.sqrt(1 - x * x), 0.0, -x], (n, 1)) for x in mus])
    out = lobe(probe, m, d, rng.random(len(d)), rng.random(len(d)), rng.random(len(d)), d)
    w = np.where(out["chosen"][:, None], out["weight"], 0.0).astype(np.float64).reshape(64, n, 3)
    a = 2 * (w.mean(axis=1) * mus[:, None]).mean(axis=0)
    se = 2 * np.sqrt(((w.var(axis=1) / n) * mus[:, None] ** 2).sum(axis=0)) / 64
    return a, se, w.mean(axis=1)


@pytest.mark.parametrize("kind", ["plastic", "roughplastic"])
def test_albedo_matches_mitsuba(probes, kind):
    """The albedo of Mitsuba's defaults with diffuse_reflectance (0.8, 0.4,
    0.2), diffuse plus specular, as tests/mitsuba_measure.py --albedo
    measured them in Mitsuba 3.9.1 (tests/test_mitsuba.py MITSUBA_ALBEDOS;
    about 1e-3 noise there)."""
    from test_mitsuba import MITSUBA_ALBEDOS
    m = (clpt.Material.smooth_plastic if kind == "plastic" else clpt.Material.rough_plastic)((0.8, 0.4, 0.2))
    a, se, _ = albedo(probes(8), m)
    diffuse, specular = MITSUBA_ALBEDOS[kind]
    ref = np.add(diffuse, specular)
    assert (np.abs(a - ref) < 4 * se + 2e-3).all(), (a, ref, se)


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
@pytest.mark.parametrize("alpha", [0.0, 0.05, 0.3, 1.0])
def test_white_furnace(probes, dist, alpha):
    """A white plastic (diffuse and specular reflectance 1) reflects at most
    what arrives, at every incidence (no energy is made); smooth, at normal
    incidence nearly all of it (F + (1 - F)(1 - Fdr_ext) / (eta^2 (1 -
    Fdr_int)) = 1 by reciprocity, less the fits' error)."""
    m = clpt.Material.rough_plastic((1.0, 1.0, 1.0), alpha=alpha, distribution=dist)
    _, _, per_mu = albedo(probes(8), m, n=4096, seed=3)
    mu_means = per_mu[:, 0]
    se = 1.0 / math.sqrt(4096)  # weights stay below about 1.5 here
    assert (mu_means <= 1.0 + 4 * se).all(), mu_means.max()
    if alpha == 0:
        assert mu_means[-1] > 0.97


# --- scene API and loader -------------------------------------------------------------------------

@pytest.mark.parametrize("kw,msg", [
    ({"alpha": -1.0}, "alpha: must be >= 0.0001"),
    ({"alpha": 11.0}, "alpha: must be <= 10"),
    ({"distribution": "phong"}, "distribution: must be one of ggx, beckmann"),
    ({"kp": (1.2, 0.5, 0.5)}, "plastic reflectances must be at most 1"),
    ({"kp": (-0.1, 0.5, 0.5)}, "kp"),
    ({"kp": (0, 0, 0), "kps": (0, 0, 0)}, "needs kp or kps above 0"),
    ({"plastic_eta": 1.0}, "plastic_eta: must differ from 1"),
    ({"plastic_eta": math.inf}, "plastic_eta: must be finite"),
    ({"kd": (0.5, 0.5, 0.5)}, "a plastic is the material's only lobe"),
])
def test_bad_plastic_is_one_line_error(kw, msg):
    m = clpt.Material(**{"plastic": True, **kw})
    scene = clpt.Scene(shapes=[clpt.Sphere(material=m)])
    with pytest.raises(clpt.SceneError) as e:
        clpt.scene.check_scene(scene)
    assert msg in str(e.value) and "\n" not in str(e.value)


def test_plastic_constructors_and_types():
    m = clpt.Material.rough_plastic((0.2, 0.3, 0.4), alpha=0.2, distribution="ggx", int_ior=1.6, ext_ior=1.1,
                                    specular_reflectance=(0.5, 0.6, 0.7), nonlinear=True)
    assert (m.plastic, m.kp, m.kps, m.alpha, m.distribution, m.nonlinear, m.one_sided) == (
        True, (0.2, 0.3, 0.4), (0.5, 0.6, 0.7), 0.2, "ggx", True, True)
    assert m.plastic_eta == pytest.approx(1.6 / 1.1)
    assert clpt.Material.smooth_plastic().alpha == 0 and clpt.Material.smooth_plastic().kp == (0.5, 0.5, 0.5)
    with pytest.raises(clpt.SceneError, match="int_ior must be a number"):
        clpt.Material.rough_plastic(int_ior="pvc")
    with pytest.raises(TypeError, match="Material.nonlinear must be True or False"):
        clpt.Material(plastic=True, nonlinear="yes")
    with pytest.raises(TypeError, match="Material.kp must be 3 numbers"):
        clpt.Material(plastic=True, kp=0.5)


def _xml(bsdf):
    return f"""<scene version="3.0.0"><shape type="sphere">{bsdf}</shape>
        <shape type="sphere"><point name="center" x="0" y="3" z="0"/><emitter type="area">
        <rgb name="radiance" value="1"/></emitter></shape></scene>"""


def test_loader_maps_plastics(tmp_path):
    p = tmp_path / "s.xml"
    p.write_text(_xml('<bsdf type="roughplastic"><string name="distribution" value="ggx"/>'
                      '<float name="alpha" value="0.3"/><string name="int_ior" value="water"/>'
                      '<float name="ext_ior" value="1.0"/><boolean name="nonlinear" value="true"/>'
                      '<rgb name="specular_reflectance" value="0.9, 0.8, 0.7"/>'
                      '<rgb name="diffuse_reflectance" value="0.1, 0.2, 0.3"/></bsdf>'))
    m = clpt.load_scene(p).shapes[0].material
    assert (m.plastic, m.distribution, m.alpha, m.kps, m.kp, m.nonlinear) == (
        True, "ggx", 0.3, (0.9, 0.8, 0.7), (0.1, 0.2, 0.3), True)
    assert m.plastic_eta == pytest.approx(1.333) and max(m.kd) == max(m.ks) == 0
    p.write_text(_xml('<bsdf type="roughplastic"/>'))
    m = clpt.load_scene(p).shapes[0].material  # Mitsuba 3's defaults
    assert (m.distribution, m.alpha, m.kp, m.kps) == ("beckmann", 0.1, (0.5, 0.5, 0.5), (1, 1, 1))
    assert m.plastic_eta == pytest.approx(1.49 / 1.000277)
    p.write_text(_xml('<bsdf type="plastic"><float name="int_ior" value="1.7"/></bsdf>'))
    m = clpt.load_scene(p).shapes[0].material
    assert m.plastic and m.alpha == 0 and m.plastic_eta == pytest.approx(1.7 / 1.000277)
    p.write_text(_xml('<bsdf type="roughplastic"><string name="distribution" value="phong"/></bsdf>'))
    with pytest.raises(clpt.SceneError, match="unknown distribution 'phong'"):
        clpt.load_scene(p)
    p.write_text(_xml('<bsdf type="plastic"><float name="int_ior" value="1.0"/><float name="ext_ior" value="1.0"/>'
                      '</bsdf>'))
    with pytest.raises(clpt.SceneError, match="int_ior and ext_ior must differ"):
        clpt.load_scene(p)


@pytest.mark.parametrize("given", [
    '<texture type="checkerboard" name="alpha"><float name="color0" value="0.1"/></texture>',
    '<ref name="alpha" id="t"/>'])
def test_loader_refuses_a_textured_roughplastic_alpha(tmp_path, given):
    """Mitsuba 3 refuses a texture as roughplastic's alpha ("The property
    "alpha" has the wrong type (expected float, got object)", at the BSDF's
    line): so does clpt, in one line naming the element and its line."""
    p = tmp_path / "s.xml"
    p.write_text(_xml('<texture type="checkerboard" id="t"/>\n<bsdf type="roughplastic">' + given + '</bsdf>'))
    with pytest.raises(clpt.SceneError) as e:
        clpt.load_scene(p)
    msg = str(e.value)
    assert msg.startswith(f'{p}:2: <bsdf type="roughplastic">: \'alpha\' must be a float'), msg
    assert "texture" in msg and "\n" not in msg
    p.write_text(_xml('<bsdf type="roughconductor"><texture type="checkerboard" name="alpha"/></bsdf>'))
    clpt.load_scene(p)  # a rough conductor's alpha may be a texture (in Mitsuba 3 as well)


def test_scene_without_plastic_compiles_without_it():
    from clpt.features import scene_features
    from clpt.pack import pack_scene
    plain = pack_scene(clpt.load_scene("cornell_box"))
    assert not plain.has_plastic and scene_features(plain).defines()["CLPT_HAS_PLASTIC"] == 0
    packed = pack_scene(clpt.load_scene(Path(__file__).parent / "data" / "plastic_spheres.xml"))
    assert packed.has_plastic and scene_features(packed).defines()["CLPT_HAS_PLASTIC"] == 1
    # Five rough plastics (the floor and four spheres) with a table of their own, last of the records.
    tab = [m for m in packed.materials if m.plastic and m.alpha > 0]
    assert len(tab) == 5
    t = np.asarray(coating.rough_tables(tab[-1].alpha, tab[-1].distribution, tab[-1].plastic_eta)[0])
    assert np.array_equal(packed.records[-16:].ravel(), t)


# --- a scene against Mitsuba 3 --------------------------------------------------------------------

SPHERES = Path(__file__).parent / "data" / "plastic_spheres.xml"


def test_plastic_spheres_render_as_in_mitsuba(device_spec):
    """tests/data/plastic_spheres.xml (five plastic spheres, smooth and
    rough, GGX and Beckmann, one nonlinear, on a rough plastic floor under a
    large and a small light) path traced at 2048 spp: the mean colour within
    0.5% of Mitsuba 3's and no 16x16 block beyond 4 sigma of both renders'
    noise (tests/stats.py assert_matches_reference)."""
    ref = json.loads((Path(__file__).parent / "data" / "plastic_spheres_mitsuba.json").read_text())
    res = clpt.Renderer(clpt.load_scene(SPHERES), device=device_spec, photons=False).render(spp=2048, seed=1)
    assert res.stats.nonfinite == 0
    assert_matches_reference(res, ref)


@pytest.mark.portability
def test_rough_plastic_scene_agrees_across_lane_widths(device_spec):
    """Each lane's path is its own: the Beckmann inversion stops a lane at
    its own tolerance (the loop once every lane has), and next event
    estimation samples the lanes' sphere lights in one gathered pass beside
    the quad light's, so the scalar and the 16-lane kernels make the
    same image (Beckmann roughplastics, a sphere and a quad light), but for
    the last bits: the runtimes' scalar and vector exp and log (the
    Beckmann lobe's) may differ by an ulp, which moved 0-4 of these 384
    pixels by 1e-7 relative in 12 seeds, on Intel's runtime and PoCL, with
    either sampler. A lane that traced another lane's path, or stopped at
    another tolerance, would be wrong by far more."""
    kw = dict(spp=2, seed=7, width=24, height=16)
    sc = clpt.load_scene(SPHERES)
    ref = clpt.Renderer(sc, device=device_spec, photons=False, lanes=1).render(**kw).image
    img = clpt.Renderer(sc, device=device_spec, photons=False, lanes=16).render(**kw).image
    assert np.allclose(img, ref, rtol=1e-6, atol=1e-9)
    assert (np.abs(img - ref).max(-1) > 0).sum() <= 8
