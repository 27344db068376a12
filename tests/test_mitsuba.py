"""Mitsuba 3 XML import: spectra and transforms against numbers measured with
Mitsuba itself (tests/mitsuba_measure.py), the BSDF mappings, parameters,
includes and references, one-line errors, reported approximations, one-sided
surfaces in the kernels, and the Cornell box written as Mitsuba XML rendering
like the native scene within noise."""

import dataclasses
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import clpt
from clpt.cli import main
from clpt.mitsuba import (DISK_SEGMENTS, UNLIMITED_DEPTH, conductor_albedo, fresnel_conductor, fresnel_dielectric,
                          fresnel_diffuse_reflectance, load_mitsuba, look_at_matrix, phong_exponent,
                          plastic_approximation, rotation_matrix)
from clpt.scene import Material, PixelFilter, Quad, SceneError, SceneWarning, Sphere
from clpt.spectrum import constant_spectrum_to_rgb, parse_spectrum_pairs, spectrum_to_rgb

from stats import ALPHA, assert_matches_reference, compare_to_reference, ring_z, sidak

DATA = Path(__file__).resolve().parent / "data"

# Measured with Mitsuba 3.9.1, scalar_rgb: `python tests/mitsuba_measure.py` ("spectra").
MITSUBA_SPECTRA = {
    "refl_ramp": ("400:0.343, 404:0.445, 500:0.5, 600:0.6, 700:0.65", False, (0.63009, 0.542001, 0.460777)),
    "refl_narrow": ("550:0.2, 560:0.9, 570:0.2", False, (0.041888, 0.133844, 0.0)),
    "refl_gamut": ("450:0.9, 460:0.05, 600:0.05, 610:0.9", False, (0.110967, 0.04881, 0.109301)),
    "emit_ramp": ("400:1, 500:8, 600:15.6, 700:18.4", True, (20.741684, 10.815638, 3.25938)),
    "emit_line": ("500:0, 550:10, 600:0", True, (0.440363, 5.825714, 0.0)),
    "emit_const": ("3", True, (3.614382, 2.844873, 2.726748)),
}
# Same command: "conductor_spectra" (eta 400:0.2, 700:1.3; k 400:3.5, 700:2.0; specular_reflectance 400:0.5, 700:1).
MITSUBA_CONDUCTOR = {"eta": (1.083631, 0.724052, 0.348628), "k": (2.277475, 2.784464, 3.278119),
                     "specular_reflectance": (0.899745, 0.738106, 0.565476)}
# Same command: "rect_to_world" (scale x 2, translate x 1, rotate z 90, in that order), and the sensors' x_fov.
MITSUBA_RECT_TO_WORLD = [[0, -1, 0, 0], [2, 0, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]]
MITSUBA_X_FOV_DIAGONAL_40_200x100 = 36.06479
MITSUBA_X_FOV_50MM_300x200 = 39.59775


def scene_xml(body, version="3.0.0", camera=True, light=True):
    cam = ('<sensor type="perspective"><float name="fov" value="45"/><transform name="to_world">'
           '<lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>'
           '<film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>'
           '</sensor>') if camera else ""
    lamp = ('<shape type="rectangle" id="lamp"><transform name="to_world"><translate z="-2"/></transform>'
            '<emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>') if light else ""
    return f'<?xml version="1.0"?>\n<scene version="{version}">\n{cam}\n{lamp}\n{body}\n</scene>\n'


def load(tmp_path, body, name="s.xml", **kw):
    p = tmp_path / name
    p.write_text(scene_xml(body, **{k: kw.pop(k) for k in ("version", "camera", "light") if k in kw}))
    return load_mitsuba(p, **kw)


def shape(scene, name):
    return next(s for s in scene.shapes if s.name == name)


def material(scene, name):
    return scene.surface(shape(scene, name))


# --- spectra ---------------------------------------------------------------------------


@pytest.mark.parametrize("key", sorted(MITSUBA_SPECTRA))
def test_spectrum_to_rgb_matches_mitsuba(key):
    text, emitter, expected = MITSUBA_SPECTRA[key]
    if ":" in text:
        rgb = spectrum_to_rgb(*parse_spectrum_pairs(text), emitter=emitter)
    else:
        rgb = constant_spectrum_to_rgb(float(text), emitter=emitter)
    assert np.allclose(rgb, expected, rtol=1e-3, atol=1e-5), (rgb, expected)


def test_spectra_in_xml(tmp_path):
    s = load(tmp_path, '''
        <shape type="rectangle" id="a"><bsdf type="diffuse">
            <spectrum name="reflectance" value="400:0.343, 404:0.445, 500:0.5, 600:0.6, 700:0.65"/></bsdf>
            <emitter type="area"><spectrum name="radiance" value="400:1, 500:8, 600:15.6, 700:18.4"/></emitter>
        </shape>
        <shape type="rectangle" id="b"><bsdf type="diffuse"><spectrum name="reflectance" value="0.25"/></bsdf>
            <emitter type="area"><spectrum name="radiance" value="3"/></emitter></shape>
        <shape type="rectangle" id="c"><bsdf type="diffuse"><float name="reflectance" value="0.75"/></bsdf></shape>''')
    a, b, c = (material(s, k) for k in "abc")
    assert np.allclose(a.kd, MITSUBA_SPECTRA["refl_ramp"][2], rtol=1e-3)
    assert np.allclose(a.emission, MITSUBA_SPECTRA["emit_ramp"][2], rtol=1e-3)
    assert b.kd == (0.25, 0.25, 0.25) and np.allclose(b.emission, MITSUBA_SPECTRA["emit_const"][2], rtol=1e-3)
    assert c.kd == (0.75, 0.75, 0.75)


def test_conductor_spectra_unbounded(tmp_path):
    s = load(tmp_path, '<shape type="rectangle" id="a"><bsdf type="conductor">'
                       '<spectrum name="eta" value="400:0.2, 700:1.3"/><spectrum name="k" value="400:3.5, 700:2.0"/>'
                       '<spectrum name="specular_reflectance" value="400:0.5, 700:1.0"/></bsdf></shape>')
    eta, k, spec = (np.array(MITSUBA_CONDUCTOR[x]) for x in ("eta", "k", "specular_reflectance"))
    assert np.allclose(material(s, "a").kr, spec * np.array(conductor_albedo(eta, k)), rtol=1e-4)


def test_spectrum_file_and_gamut_warning(tmp_path):
    (tmp_path / "s.spd").write_text("# wavelength value\n500 0\n550 10\n600 0\n")
    with pytest.warns(SceneWarning, match=r"s.xml:\d+: <spectrum name=\"radiance\">: spectrum out of the sRGB"):
        s = load(tmp_path, '<shape type="rectangle" id="a"><emitter type="area">'
                           '<spectrum name="radiance" filename="s.spd"/></emitter></shape>')
    assert np.allclose(material(s, "a").emission, MITSUBA_SPECTRA["emit_line"][2], rtol=1e-3)


# --- transforms and the camera ------------------------------------------------------------


def test_transform_order_and_forms(tmp_path):
    s = load(tmp_path, '''
        <shape type="rectangle" id="r"><transform name="to_world">
            <scale x="2"/><translate x="1"/><rotate z="1" angle="90"/></transform></shape>
        <shape type="rectangle" id="r2"><transform name="to_world">
            <matrix value="0 -1 0 0  2 0 0 1  0 0 1 0  0 0 0 1"/></transform></shape>
        <shape type="rectangle" id="r3"><transform name="to_world">
            <scale value="2, 1, 1"/><translate value="1 0 0"/><rotate value="0, 0, 3" angle="90"/></transform></shape>''')
    m = np.array(MITSUBA_RECT_TO_WORLD, dtype=np.float64)
    corners = [np.array(p, dtype=np.float64) for p in ((-1, -1, 0), (1, -1, 0), (-1, 1, 0))]
    want = [m[:3, :3] @ p + m[:3, 3] for p in corners]
    # Hand-computed: (-1,-1,0) -> scale (-2,-1,0) -> translate (-1,-1,0) -> rotate z 90 (1,-1,0).
    assert np.allclose(want[0], (1, -1, 0))
    for name in ("r", "r2", "r3"):
        q = shape(s, name)
        assert np.allclose(q.corner, want[0], atol=1e-12)
        assert np.allclose(q.edge_u, want[1] - want[0], atol=1e-12)
        assert np.allclose(q.edge_v, want[2] - want[0], atol=1e-12)


def test_rotation_and_look_at():
    # A right-handed rotation of 90 degrees about z takes x to y; about x, y to z.
    assert np.allclose(rotation_matrix((0, 0, 1), 90)[:3, :3] @ (1, 0, 0), (0, 1, 0))
    assert np.allclose(rotation_matrix((1, 0, 0), 90)[:3, :3] @ (0, 1, 0), (0, 0, 1))
    assert np.allclose(rotation_matrix((1, 1, 1), 120)[:3, :3] @ (1, 0, 0), (0, 1, 0))
    m = look_at_matrix((1, 2, 3), (1, 2, 0), (0, 1, 0))
    # Columns: left (up x forward), up, forward, origin.
    assert np.allclose(m[:3, 2], (0, 0, -1)) and np.allclose(m[:3, 1], (0, 1, 0))
    assert np.allclose(m[:3, 0], (-1, 0, 0)) and np.allclose(m[:3, 3], (1, 2, 3))


def test_camera_fov_axes(tmp_path):
    def cam(attrs, w, h):
        p = tmp_path / "c.xml"
        p.write_text(f'''<scene version="3.0.0"><sensor type="perspective">{attrs}
            <transform name="to_world"><lookat origin="0, 1, 5" target="0, 1, 0" up="0, 1, 0"/></transform>
            <film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{h}"/></film>
            </sensor><shape type="sphere"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
            </scene>''')
        return load_mitsuba(p).camera

    c = cam('<float name="fov" value="40"/><string name="fov_axis" value="diagonal"/>', 200, 100)
    assert c.fov_axis == "x" and c.fov == pytest.approx(MITSUBA_X_FOV_DIAGONAL_40_200x100, abs=1e-4)
    c = cam("", 300, 200)  # focal_length 50mm by default
    assert c.fov_axis == "x" and c.fov == pytest.approx(MITSUBA_X_FOV_50MM_300x200, abs=1e-4)
    c = cam('<float name="fov" value="30"/>', 64, 32)  # Mitsuba's default axis is x, not clpt's "smaller"
    assert (c.fov, c.fov_axis, c.width, c.height) == (30.0, "x", 64, 32)
    assert np.allclose(c.origin, (0, 1, 5)) and np.allclose(c.target, (0, 1, 4)) and np.allclose(c.up, (0, 1, 0))


# --- pixel filters (<rfilter>) ----------------------------------------------------------------


def film_scene(tmp_path, film_body="", film=True, sensor=True):
    film_xml = (f'<film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>'
                f'{film_body}</film>') if film else ""
    cam = f'<sensor type="perspective"><float name="fov" value="45"/>{film_xml}</sensor>' if sensor else ""
    p = tmp_path / "f.xml"
    p.write_text(scene_xml(cam, camera=False))
    return p


@pytest.mark.parametrize("body, expected", [
    ('<rfilter type="box"/>', PixelFilter("box")),
    ('<rfilter type="tent"/>', PixelFilter("tent", radius=1.0)),
    ('<rfilter type="tent"><float name="radius" value="2.5"/></rfilter>', PixelFilter("tent", radius=2.5)),
    ('<rfilter type="gaussian"/>', PixelFilter("gaussian", stddev=0.5)),
    ('<rfilter type="gaussian"><float name="stddev" value="0.25"/></rfilter>', PixelFilter("gaussian", stddev=0.25)),
    ('<rfilter type="gaussian"/><boolean name="sample_border" value="true"/>',
     PixelFilter("gaussian", stddev=0.5, sample_border=True)),
    ("", PixelFilter("gaussian")),  # Mitsuba's default filter
])
def test_rfilter_is_read(tmp_path, body, expected):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pf = load_mitsuba(film_scene(tmp_path, body)).camera.pixel_filter
    assert pf == expected
    assert pf.extent == {"box": 0.5, "tent": expected.radius, "gaussian": 4 * (expected.stddev or 0.5)}[pf.kind]


def test_default_film_and_sensor_have_the_gaussian(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_mitsuba(film_scene(tmp_path, film=False)).camera.pixel_filter == PixelFilter("gaussian")
    with pytest.warns(SceneWarning, match="no sensor"):
        assert load_mitsuba(film_scene(tmp_path, sensor=False)).camera.pixel_filter == PixelFilter("gaussian")


@pytest.mark.parametrize("body, message", [
    ('<rfilter type="gaussian"><float name="stddev" value="-1"/></rfilter>',
     r'f.xml:\d+: <float name="stddev">: must be from 0.001 to 64 pixels \(got -1\)$'),
    ('<rfilter type="gaussian"><float name="stddev" value="nan"/></rfilter>', r'<float name="stddev">: .*finite'),
    ('<rfilter type="tent"><float name="radius" value="0"/></rfilter>',
     r'<float name="radius">: must be from 0.001 to 256 pixels \(got 0\)$'),
    ('<rfilter type="tent"><string name="radius" value="1"/></rfilter>', r"'radius' must be float or integer"),
    ('<rfilter type="sinc"/>', r'<rfilter type="sinc">: unknown reconstruction filter \'sinc\''),
    ('<rfilter type="gaussian"/><boolean name="sample_border" value="maybe"/>', "must be true or false"),
])
def test_bad_rfilter_is_one_line(tmp_path, body, message):
    with pytest.raises(SceneError, match=message) as e:
        load_mitsuba(film_scene(tmp_path, body))
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("kind", ["mitchell", "catmullrom", "lanczos"])
def test_negative_lobed_rfilter_is_rendered_with_the_box(tmp_path, kind):
    body = f'<rfilter type="{kind}"><float name="B" value="0.3"/></rfilter>' if kind == "mitchell" else \
        f'<rfilter type="{kind}"/>'
    with pytest.warns(SceneWarning, match=rf"<rfilter type=\"{kind}\">: reconstruction filter '{kind}' has negative "
                                          "lobes, which clpt does not sample: rendered with a box filter") as w:
        assert load_mitsuba(film_scene(tmp_path, body)).camera.pixel_filter == PixelFilter("box")
    assert len([x for x in w if issubclass(x.category, SceneWarning)]) == 1
    with pytest.raises(SceneError, match="strict mode"):
        load_mitsuba(film_scene(tmp_path, body), strict=True)


def test_unknown_rfilter_property_warns(tmp_path):
    """A box has no radius in Mitsuba 3 (it refuses the property); clpt warns and ignores it."""
    with pytest.warns(SceneWarning, match="property 'radius' of rfilter 'box' is not supported; ignored"):
        pf = load_mitsuba(film_scene(tmp_path, '<rfilter type="box"><float name="radius" value="1"/></rfilter>'))
    assert pf.camera.pixel_filter == PixelFilter("box")


def test_pixel_filter_settings_are_checked():
    bad = [(PixelFilter("cone"), "camera.pixel_filter.kind: must be one of box, tent, gaussian"),
           (PixelFilter("box", radius=1.0), "camera.pixel_filter.radius: only the tent filter has a radius"),
           (PixelFilter("tent", stddev=1.0), "camera.pixel_filter.stddev: only the gaussian filter has a stddev"),
           (PixelFilter("gaussian", stddev=0.0), "camera.pixel_filter.stddev: must be > 0"),
           (PixelFilter("tent", radius=1e9), "camera.pixel_filter.radius: must be from 0.001 to 256 pixels"),
           (PixelFilter("tent", sample_border="yes"), "camera.pixel_filter.sample_border: must be true or false")]
    for pf, msg in bad:
        scene = clpt.Scene(camera=clpt.Camera(pixel_filter=pf), shapes=[Sphere(emission=(1, 1, 1))])
        with pytest.raises(SceneError, match=msg.replace(".", r"\.")):
            scene.check()


LAMP_REF = json.loads((DATA / "cbox_lamp_gaussian_mitsuba.json").read_text())


def render_lamp(device, spp, seed=1, **filter_kw):
    """cbox_lamp_gaussian.xml path traced (photons=False: independent samples,
    so the per-pixel variances are the estimate's own), its pixel filter
    changed by filter_kw (dataclasses.replace's fields of PixelFilter)."""
    scene = clpt.load_scene(DATA / "cbox_lamp_gaussian.xml", params={"res": LAMP_REF["width"]})
    pf = dataclasses.replace(scene.camera.pixel_filter, **filter_kw)
    scene = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, pixel_filter=pf))
    return clpt.Renderer(scene, device=device, photons=False).render(spp=spp, seed=seed)


def test_gaussian_filter_renders_as_in_mitsuba(device_spec):
    """A small bright lamp seen through the gaussian filter: the image mean
    within 0.5% of Mitsuba's, no 16x16-pixel block beyond 4 sigma of both
    renders' noise, nor the outermost ring of pixels (where Mitsuba's filter
    is cut at the film's edge)."""
    res = render_lamp(device_spec, spp=1024)
    assert_matches_reference(res, LAMP_REF)
    assert abs(ring_z(res, LAMP_REF)) < 4


def test_box_filter_fails_the_gaussian_reference_near_the_lamp(device_spec):
    """The comparison has the power to see the filter: the same scene through
    the box keeps the lamp's light in its own block, far outside the noise
    there and in the blocks across its edges."""
    _, z = compare_to_reference(render_lamp(device_spec, spp=1024, kind="box", stddev=None), LAMP_REF)
    assert z[1, 1] > 8 and z[1, 2] < -8 and z[2, 1] < -8, np.round(z, 1)


# --- scene structure: parameters, includes, references, the integrator -----------------------


def test_defaults_and_params(tmp_path):
    body = '''<default name="spp" value="16"/><default name="r" value="0.5"/>
        <sensor type="perspective"><float name="fov" value="45"/>
            <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler></sensor>
        <shape type="sphere" id="ball"><float name="radius" value="$r"/></shape>'''
    s = load(tmp_path, body, camera=False)
    assert s.render.spp == 16 and shape(s, "ball").radius == 0.5
    s = load(tmp_path, body, camera=False, params={"spp": 3, "r": "0.25"})
    assert s.render.spp == 3 and shape(s, "ball").radius == 0.25
    assert clpt.load_scene(tmp_path / "s.xml", params={"spp": "5"}).render.spp == 5
    with pytest.raises(SceneError, match=r"parameter 'sp' is not used by the scene \(did you mean 'spp'\?\)"):
        load(tmp_path, body, camera=False, params={"sp": "4"})
    with pytest.raises(SceneError, match=r"s.xml:\d+: <float name=\"radius\">: undefined parameter \$rad"):
        load(tmp_path, '<shape type="sphere"><float name="radius" value="$rad"/></shape>')
    with pytest.raises(SceneError, match="apply to Mitsuba XML scenes only"):
        clpt.load_scene("cornell_box", params={"a": "1"})


def test_include_and_forward_refs(tmp_path):
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "bsdfs.xml").write_text(
        '<scene version="3.0.0"><include filename="more.xml"/>'
        '<bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.3"/></bsdf></scene>')
    (tmp_path / "parts" / "more.xml").write_text(
        '<scene version="3.0.0"><bsdf type="twosided" id="two"><ref id="grey"/></bsdf></scene>')
    s = load(tmp_path, '<shape type="rectangle" id="a"><ref id="two"/></shape>'
                       '<shape type="rectangle" id="b"><ref name="bsdf" id="grey"/></shape>'
                       '<include filename="parts/bsdfs.xml"/>')
    assert material(s, "a") == Material(kd=(0.3, 0.3, 0.3), one_sided=False)
    assert material(s, "b") == Material(kd=(0.3, 0.3, 0.3), one_sided=True)
    assert set(s.materials) == {"grey", "two"}


def test_include_cycle_and_missing_file(tmp_path):
    (tmp_path / "a.xml").write_text('<scene version="3.0.0">\n<include filename="b.xml"/></scene>')
    (tmp_path / "b.xml").write_text('<scene version="3.0.0">\n\n<include filename="a.xml"/></scene>')
    with pytest.raises(SceneError, match=r"b.xml:3: <include>: include cycle: .*a.xml -> .*b.xml -> .*a.xml$"):
        load_mitsuba(tmp_path / "a.xml")
    with pytest.raises(SceneError, match=r"s.xml:\d+: <include>: file not found: 'nope.xml'"):
        load(tmp_path, '<include filename="nope.xml"/>')


def test_max_depth_mapping(tmp_path):
    def depth(v):
        return load(tmp_path, f'<integrator type="path"><integer name="max_depth" value="{v}"/></integrator>'
                    ).render.max_depth

    assert depth(8) == 7 and depth(1) == 0 and depth(-1) == UNLIMITED_DEPTH
    assert load(tmp_path, "").render.max_depth == UNLIMITED_DEPTH  # no integrator: Mitsuba's path, unlimited
    with pytest.raises(SceneError, match=r"<integer name=\"max_depth\">: max_depth 0 renders nothing"):
        depth(0)
    s = load(tmp_path, '<integrator type="path"><integer name="rr_depth" value="5"/></integrator>')
    assert s.render.rr_depth == 4


# --- BSDFs ------------------------------------------------------------------------------


def test_bsdf_mappings(tmp_path):
    s = load(tmp_path, '''
        <shape type="rectangle" id="diffuse"><bsdf type="diffuse"/></shape>
        <shape type="rectangle" id="mirror"><bsdf type="conductor"/></shape>
        <shape type="rectangle" id="gold"><bsdf type="conductor"><string name="material" value="Au"/></bsdf></shape>
        <shape type="rectangle" id="etak"><bsdf type="roughconductor"><float name="alpha" value="0.2"/>
            <rgb name="eta" value="0.2, 0.9, 1.1"/><rgb name="k" value="3.9, 2.4, 1.9"/></bsdf></shape>
        <shape type="rectangle" id="glass"><bsdf type="dielectric"/></shape>
        <shape type="rectangle" id="water"><bsdf type="dielectric"><string name="int_ior" value="water"/>
            <float name="ext_ior" value="1.0"/></bsdf></shape>
        <shape type="rectangle" id="thin"><bsdf type="thindielectric"/></shape>
        <shape type="rectangle" id="plastic"><bsdf type="plastic">
            <rgb name="diffuse_reflectance" value="0.8, 0.4, 0.2"/></bsdf></shape>
        <shape type="rectangle" id="rough"><bsdf type="roughplastic"><float name="alpha" value="0.1"/></bsdf></shape>
        <shape type="rectangle" id="two"><bsdf type="twosided"><bsdf type="conductor"/></bsdf></shape>
    ''')
    assert material(s, "diffuse") == Material(kd=(0.5, 0.5, 0.5), one_sided=True)
    assert material(s, "mirror") == Material(kr=(1.0, 1.0, 1.0), one_sided=True)
    au = material(s, "gold").kr  # normal-incidence reflectance of gold: high red, low blue
    assert 0.85 < au[0] < 1 and au[2] < 0.45 and au[0] > au[1] > au[2]
    e = material(s, "etak")
    assert (e.km, e.alpha, e.distribution, e.eta, e.k) == ((1, 1, 1), 0.2, "beckmann", (0.2, 0.9, 1.1), (3.9, 2.4, 1.9))
    assert e.ks == e.kr == (0, 0, 0)
    g = material(s, "glass")
    assert g.kt == (1, 1, 1) and g.ior == pytest.approx(1.5046 / 1.000277, rel=1e-5) and not g.one_sided
    assert material(s, "water").ior == pytest.approx(1.333)
    t = material(s, "thin")
    assert t.ior == 1.0 and np.allclose(np.add(t.kr, t.kt), 1.0) and 0.08 < t.kr[0] < 0.2
    p = material(s, "plastic")  # Mitsuba's plastic itself (kernels/bsdf.h plastic_*)
    assert p.plastic and p.alpha == 0 and p.kp == (0.8, 0.4, 0.2) and p.kps == (1, 1, 1) and p.one_sided
    assert p.plastic_eta == pytest.approx(1.49 / 1.000277) and not p.nonlinear and p.kd == p.kr == (0, 0, 0)
    r = material(s, "rough")
    assert r.plastic and (r.alpha, r.distribution, r.kp) == (0.1, "beckmann", (0.5, 0.5, 0.5))
    # Its diffuse + Phong approximation (for blendbsdf).
    fdr = fresnel_diffuse_reflectance(1.49 / 1.000277)
    pa = plastic_approximation(p)
    assert np.allclose(pa.kr, fdr) and pa.one_sided and pa.ks == (0, 0, 0)
    assert np.allclose(pa.kd, np.array([0.8, 0.4, 0.2]) * (1 - fdr), rtol=2e-3)  # reciprocity: (1-Fdr_e)/eta^2 = 1-Fdr_i
    ra = plastic_approximation(r)
    assert ra.shininess == pytest.approx(49.5) and np.allclose(ra.ks, fdr) and ra.kr == (0, 0, 0)
    assert material(s, "two") == Material(kr=(1.0, 1.0, 1.0), one_sided=False)


def test_fresnel_helpers():
    assert fresnel_dielectric(1.0, 1.5) == pytest.approx(0.04)
    # A conductor at normal incidence: ((n-1)^2 + k^2) / ((n+1)^2 + k^2); with k = 0 the dielectric's.
    assert fresnel_conductor(1.0, 0.2, 3.9) == pytest.approx((0.8 ** 2 + 3.9 ** 2) / (1.2 ** 2 + 3.9 ** 2))
    for mu in (0.9, 0.5, 0.1):
        assert fresnel_conductor(mu, 1.5, 0.0) == pytest.approx(fresnel_dielectric(mu, 1.5))
    assert fresnel_dielectric(0.1, 1 / 1.5) == 1.0  # total internal reflection
    # Reciprocity of the hemispherical averages: 1 - Fdr(1/eta) = (1 - Fdr(eta)) / eta^2.
    for eta in (1.33, 1.5, 2.4):
        assert 1 - fresnel_diffuse_reflectance(1 / eta) == pytest.approx((1 - fresnel_diffuse_reflectance(eta)) /
                                                                         eta ** 2, rel=1e-3)
    # Half the Phong exponent's width in the mirror direction: n = 1/(2 alpha^2) - 1/2.
    assert phong_exponent(0.1) == pytest.approx(49.5) and phong_exponent(1.0) == 0.0


# --- shapes ------------------------------------------------------------------------------


def test_shapes(tmp_path):
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 0 0 1\nvn 0 0 1\nf 1//1 2//2 3//3\n")
    s = load(tmp_path, '''
        <shape type="sphere" id="ball"><point name="center" x="1" y="0" z="0"/><float name="radius" value="0.5"/>
            <transform name="to_world"><scale value="2"/><translate y="3"/></transform></shape>
        <shape type="disk" id="disk"><transform name="to_world"><scale value="0.5"/></transform></shape>
        <shape type="rectangle" id="flipped"><boolean name="flip_normals" value="true"/></shape>
        <shape type="rectangle" id="mirrored"><transform name="to_world"><scale x="-1"/></transform></shape>
        <shape type="cube" id="cube"><transform name="to_world"><scale x="0.5" y="2" z="1"/>
            <rotate y="1" angle="30"/><translate x="5"/></transform></shape>
        <shape type="obj" id="mesh"><string name="filename" value="tri.obj"/>
            <transform name="to_world"><rotate x="1" angle="90"/><translate z="1"/></transform></shape>
        <shape type="obj" id="flat"><string name="filename" value="tri.obj"/>
            <boolean name="face_normals" value="true"/></shape>''')
    ball = shape(s, "ball")
    assert isinstance(ball, Sphere) and np.allclose(ball.center, (2, 3, 0)) and ball.radius == pytest.approx(1.0)
    disk = shape(s, "disk")
    assert len(disk.triangles) == DISK_SEGMENTS and disk.area() == pytest.approx(math.pi * 0.25, rel=1e-12)
    n = np.cross(disk.vertices[disk.triangles[0, 1]] - disk.vertices[0], disk.vertices[disk.triangles[0, 2]] -
                 disk.vertices[0])
    assert n[2] > 0  # faces +z
    for name, nz in (("flipped", -1), ("mirrored", 1)):
        q = shape(s, name)
        assert isinstance(q, Quad) and np.sign(np.cross(q.edge_u, q.edge_v)[2]) == nz
    faces = [q for q in s.shapes if q.name == "cube"]
    assert len(faces) == 6
    for q in faces:  # every face's normal points away from the centre
        c = np.array(q.corner) + 0.5 * (np.array(q.edge_u) + np.array(q.edge_v))
        assert np.dot(np.cross(q.edge_u, q.edge_v), c - (5, 0, 0)) > 0
    assert sum(abs(np.linalg.norm(np.cross(q.edge_u, q.edge_v))) for q in faces) == pytest.approx(
        2 * (1 * 4 + 4 * 2 + 1 * 2))
    m = shape(s, "mesh")  # rotate x 90: y -> z; then z + 1
    assert np.allclose(m.vertices, [(0, 0, 1), (1, 0, 1), (0, 0, 2)]) and np.allclose(m.normals, (0, -1, 0))
    assert shape(s, "flat").normals is None


# --- errors and warnings ---------------------------------------------------------------


@pytest.mark.parametrize("body, message", [
    ('<shape type="sphere"><float name="radius" value="big"/></shape>',
     r"s.xml:5: <float name=\"radius\">: bad number 'big' in value$"),
    ('<shapes type="sphere"/>', r"s.xml:5: <shapes type=\"sphere\">: unknown tag \(did you mean 'shape'\?\)$"),
    ('<shape type="obj"><string name="filename" value="gone.obj"/></shape>',
     r"s.xml:5: <shape type=\"obj\">: file not found: 'gone.obj'"),
    ('<shape type="rectangle"><ref id="nothing"/></shape>',
     r"s.xml:5: <ref id=\"nothing\">: reference to an undefined id 'nothing'$"),
    ('<bsdf type="diffuse" id="lamp"/>', r"s.xml:5: <bsdf type=\"diffuse\" id=\"lamp\">: duplicate id 'lamp' "
                                         r"\(first defined at .*s.xml:4\)$"),
    ('<shape type="rectangle"><bsdf type="diffuse"><rgb name="reflectance" value="1.5, 0, 0"/></bsdf></shape>',
     r"s.xml:5: <rgb name=\"reflectance\">: a reflectance must be at most 1"),
    ('<shape type="rectangle"><transform name="to_world"><rotate angle="3"/></transform></shape>',
     r"s.xml:5: <rotate>: needs an axis"),
    ('<shape type="sphere"><float name="radius" vlaue="2"/></shape>',
     r"s.xml:5: <float name=\"radius\">: unknown attribute 'vlaue' \(did you mean 'value'\?\); <float> takes name, "
     r"value$"),
    ('<shape type="rectangle">', r"s.xml:6: XML syntax error: mismatched tag \(column 3\)$"),
    ('<shape type="rectangle"><bsdf type="dielectric"><string name="int_ior" value="glas"/></bsdf></shape>',
     r"s.xml:5: <string name=\"int_ior\">: unknown index of refraction 'glas'; known: vacuum, helium"),
])
def test_errors_name_file_and_line(tmp_path, body, message):
    with pytest.raises(SceneError, match=message):
        load(tmp_path, body)


def test_missing_version_and_file(tmp_path):
    p = tmp_path / "v.xml"
    p.write_text("<scene>\n</scene>\n")
    with pytest.raises(SceneError, match=r"v.xml:1: <scene>: missing attribute 'version'"):
        load_mitsuba(p)
    with pytest.raises(SceneError, match=r"none.xml: no such scene file"):
        clpt.load_scene(tmp_path / "none.xml")


def test_unsupported_reported_once_with_count(tmp_path):
    body = ('<shape type="rectangle" id="a"><bsdf type="principled"/></shape>\n'
            '<shape type="rectangle" id="b"><bsdf type="principled"/></shape>\n'
            '<emitter type="sunsky"/>\n<shape type="rectangle" id="c"><bsdf type="diffuse">'
            '<float name="roughness" value="0.2"/></bsdf></shape>')
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        s = load(tmp_path, body)
    msgs = [str(x.message) for x in w if issubclass(x.category, SceneWarning)]
    assert len(msgs) == 3, msgs
    assert any(m.startswith(f"{tmp_path / 's.xml'}:5: <bsdf type=\"principled\">: BSDF 'principled' is not "
                            "supported") and m.endswith("(and 1 more like it)") for m in msgs)
    assert any(":7: <emitter type=\"sunsky\">" in m and "left out" in m for m in msgs)
    assert any("property 'roughness' of bsdf 'diffuse' is not supported; ignored" in m for m in msgs)
    assert material(s, "a").kd == (0.5, 0.5, 0.5)
    with pytest.raises(SceneError, match=r"BSDF 'principled' is not supported.*\(strict mode\)"):
        load(tmp_path, body, strict=True)


# --- rendering -------------------------------------------------------------------------------


def _one_sided_scene(one_sided):
    # A floor facing down (-y), lit from above by a light outside the view: from above
    # the camera sees the floor's back, black when one-sided.
    white = Material(kd=(0.8, 0.8, 0.8), one_sided=one_sided)
    return clpt.Scene(
        camera=clpt.Camera(origin=(0, 3, 0.01), target=(0, 0, 0), fov=40, width=8, height=8),
        shapes=[clpt.Quad(corner=(-1, 0, -1), edge_u=(2, 0, 0), edge_v=(0, 0, 2), material=white),
                clpt.Quad(corner=(2, 1, -0.25), edge_u=(0.5, 0, 0), edge_v=(0, 0, 0.5), material=white,
                          emission=(10, 10, 10))])


def test_one_sided_surface_is_black_from_behind(device_spec):
    back = clpt.render(_one_sided_scene(True), spp=8, device=device_spec)
    both = clpt.render(_one_sided_scene(False), spp=8, device=device_spec)
    assert back.max() == 0.0 and both.min() > 0 and both.mean() > 0.01


def _block_z(a, b, block):
    """z-scores of the differences of block means of luminance between two
    independent renders, from each pixel's estimated variance of its mean."""
    w = np.array([0.2126, 0.7152, 0.0722])
    h, wd = a.image.shape[:2]

    def blocks(res):
        lum = (res.image @ w).reshape(h // block, block, wd // block, block)
        var = (res.lum_var / res.sample_count).reshape(h // block, block, wd // block, block)
        return lum.mean(axis=(1, 3)), var.sum(axis=(1, 3)) / block ** 4

    (ma, va), (mb, vb) = blocks(a), blocks(b)
    return (ma - mb) / np.sqrt(va + vb)


def _z_bound(trials):
    """Two-sided normal quantile at the Sidak-corrected level (bisection on erfc)."""
    p = sidak(ALPHA, trials)
    lo, hi = 0.0, 10.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if math.erfc(mid / math.sqrt(2)) > p else (lo, mid)
    return hi


@pytest.mark.parametrize("xml", ["cbox_mesh.xml", "cbox_shapes.xml"])
def test_cornell_box_xml_renders_like_native(xml, device_spec):
    xml_scene = clpt.load_scene(DATA / xml)
    native = clpt.load_scene("cornell_box")
    # The files leave Mitsuba's default pixel filter, the gaussian: the native scene gets it too.
    assert xml_scene.camera.pixel_filter == PixelFilter("gaussian")
    native = dataclasses.replace(native, camera=dataclasses.replace(native.camera,
                                                                    pixel_filter=xml_scene.camera.pixel_filter))
    assert xml_scene.render.max_depth == 7  # Mitsuba's max_depth 8
    size, block, spp = 24, 4, 64
    kw = dict(spp=spp, width=size, height=size, max_depth=7, device=device_spec)
    a = clpt.Renderer(xml_scene, device=device_spec).render(seed=1, **{k: v for k, v in kw.items() if k != "device"})
    b = clpt.Renderer(native, device=device_spec).render(seed=2, **{k: v for k, v in kw.items() if k != "device"})
    z = _block_z(a, b, block)
    assert np.abs(z).max() < _z_bound(z.size), f"block means differ by up to {np.abs(z).max():.2f} sigma"
    assert abs(a.image.mean() - b.image.mean()) < 0.02 * b.image.mean()


def test_cli_render_xml_with_params_and_overrides(tmp_path, device_spec, capsys):
    dev = ["--device", device_spec] if device_spec else []
    out = tmp_path / "x.exr"
    assert main(["render", str(DATA / "cbox_mesh.xml"), "-D", "res=12", "--param", "spp=2", "--width", "10",
                 "-o", str(out), "-q", *dev]) == 0
    img = clpt.load_image(out)
    assert img.shape == (12, 10, 3) and img.mean() > 0
    assert main(["check", str(DATA / "cbox_mesh.xml"), "-D", "res"]) == 2
    assert "clpt: error: -D res: expected NAME=VALUE" in capsys.readouterr().err
    bad = tmp_path / "w.xml"
    bad.write_text(scene_xml('<shape type="rectangle"><bsdf type="hair"/></shape>'))
    assert main(["check", str(bad)]) == 0
    err = capsys.readouterr().err
    assert err.startswith(f"clpt: warning: {bad}:5: <bsdf type=\"hair\">: BSDF 'hair' is not supported")
    assert main(["check", str(bad), "--strict"]) == 2


def test_instances_aliases_and_texture_means(tmp_path):
    clpt.save_image(tmp_path / "tex.exr", np.array([[[0.2, 0.4, 0.6], [0.4, 0.6, 0.8]]], dtype=np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every texture here is evaluated: no mean colour stands in
        s = load(tmp_path, '''
        <shape type="shapegroup" id="pair">
            <shape type="sphere" id="p1"><float name="radius" value="0.1"/></shape>
            <shape type="rectangle" id="p2"/>
        </shape>
        <shape type="instance" id="i1"><ref id="pair"/>
            <transform name="to_world"><translate x="3"/></transform></shape>
        <bsdf type="diffuse" id="checker">
            <texture type="checkerboard" name="reflectance">
                <rgb name="color0" value="0.1"/><rgb name="color1" value="0.5"/></texture></bsdf>
        <alias id="checker" as="board"/>
        <shape type="rectangle" id="c"><ref id="board"/></shape>
        <shape type="rectangle" id="t"><bsdf type="diffuse"><texture type="bitmap" name="reflectance">
            <string name="filename" value="tex.exr"/></texture></bsdf></shape>
        <shape type="rectangle" id="m"><bsdf type="conductor"><texture type="checkerboard"
            name="specular_reflectance"><rgb name="color0" value="0.2"/><rgb name="color1" value="0.6"/>
            </texture></bsdf></shape>''')
    spheres = [x for x in s.shapes if isinstance(x, Sphere)]
    assert len(spheres) == 1 and np.allclose(spheres[0].center, (3, 0, 0))  # only the instance is rendered
    assert np.allclose(shape(s, "p2").corner, (2, -1, 0))
    # Reflectance textures are evaluated (kd, kr: their largest value, the bound), a smooth conductor's
    # specular reflectance too (times the conductor's albedo, 1 for "none").
    assert np.allclose(material(s, "c").kd, 0.5) and material(s, "c").texture("reflectance").kind == "checkerboard"
    assert np.allclose(material(s, "t").kd, (0.4, 0.6, 0.8)) and material(s, "t").texture("reflectance").texels == 2
    assert np.allclose(material(s, "m").kr, 0.6) and material(s, "m").texture("specular").color1 == (0.6, 0.6, 0.6)


def test_version_0x_names_and_search_path(tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # Mitsuba 3 reads a 0.6 file after the same upgrade, silently
        s = load(tmp_path, '''<path value="meshes"/>
            <shape type="obj" id="t"><string name="filename" value="tri.obj"/>
                <transform name="toWorld"><translate x="2"/></transform>
                <bsdf type="dielectric"><float name="intIOR" value="1.7"/><float name="extIOR" value="1.0"/></bsdf>
            </shape>''', version="0.6.0")
    assert np.allclose(shape(s, "t").vertices[0], (2, 0, 0)) and material(s, "t").ior == pytest.approx(1.7)


def test_one_sided_mirror_absorbs_photons_from_behind(device_spec):
    def stored(one_sided):
        white = Material(kd=(0.8, 0.8, 0.8))
        mirror = Material(kr=(1.0, 1.0, 1.0), one_sided=one_sided)
        scene = clpt.Scene(
            camera=clpt.Camera(origin=(0, 0, 4), target=(0, 0, 0), fov=40, width=8, height=8),
            shapes=[clpt.Quad(corner=(-0.25, 1, -0.25), edge_u=(0.5, 0, 0), edge_v=(0, 0, 0.5), material=white,
                              emission=(10, 10, 10)),  # faces down
                    clpt.Quad(corner=(-0.5, 0, -0.5), edge_u=(1, 0, 0), edge_v=(0, 0, 1), material=mirror),  # faces down
                    clpt.Quad(corner=(-2, -1, -2), edge_u=(0, 0, 4), edge_v=(4, 0, 0), material=white)])  # floor, up
        res = clpt.Renderer(scene, device=device_spec).render(spp=1, photons=clpt.PhotonSettings(count=20000, pilot=False))
        return res.stats.photon_maps[0]["stored"]

    assert stored(True) == 0 and stored(False) > 100


def test_bad_mesh_file_names_the_element(tmp_path):
    (tmp_path / "bad.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n")
    with pytest.raises(SceneError, match=r"s.xml:5: <shape type=\"ply\">: .*bad.ply"):
        load(tmp_path, '<shape type="ply"><string name="filename" value="bad.ply"/></shape>')


def test_cylinder(tmp_path):
    s = load(tmp_path, '''<shape type="cylinder" id="c"><point name="p0" value="0, 0, 0"/>
        <point name="p1" value="0, 2, 0"/><float name="radius" value="0.5"/>
        <transform name="to_world"><translate x="1"/></transform></shape>''')
    c = shape(s, "c")
    assert c.area() == pytest.approx(2 * math.pi * 0.5 * 2, rel=1e-12)  # open tube, as Mitsuba's
    v, t = c.vertices, c.triangles
    centre = v[t].mean(axis=1)
    n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    out = centre - np.stack([np.ones(len(t)), centre[:, 1], np.zeros(len(t))], axis=1)
    assert (np.einsum("ij,ij->i", n, out) > 0).all()  # faces point outwards
    assert np.allclose(np.einsum("ij,ij->i", c.normals, v - np.stack([np.ones(len(v)), v[:, 1], np.zeros(len(v))], 1)),
                       np.linalg.norm(v - np.stack([np.ones(len(v)), v[:, 1], np.zeros(len(v))], 1), axis=1))


# Measured with Mitsuba 3.9.1: `MI_VARIANT=llvm_ad_rgb python tests/mitsuba_measure.py --albedo` (cosine-weighted
# hemispherical albedos of the diffuse and the specular parts; Monte Carlo, about 1e-3 noise).
MITSUBA_ALBEDOS = {"plastic": ((0.7286, 0.3643, 0.1821), 0.0903), "roughplastic": ((0.7056, 0.3528, 0.1764), 0.0846),
                   "thindielectric": ((0.0, 0.0, 0.0), 0.1565), "conductor": ((0.0, 0.0, 0.0), (0.9646, 0.8095, 0.3678)),
                   "roughconductor": ((0.0, 0.0, 0.0), (0.9598, 0.8044, 0.3623))}


@pytest.mark.parametrize("kind, rtol", [("plastic", 3e-3), ("thindielectric", 3e-3), ("conductor", 3e-3),
                                        ("roughplastic", 0.07)])
def test_mapped_albedos_match_mitsuba(tmp_path, kind, rtol):
    """clpt's lobes carry the energy that Mitsuba's BSDF reflects on average
    over directions (roughplastic: less what its microfacet shadowing loses;
    roughconductor is Mitsuba's lobe itself, tests/test_microfacet.py)."""
    extra = {"plastic": '<rgb name="diffuse_reflectance" value="0.8, 0.4, 0.2"/>',
             "conductor": '<string name="material" value="Au"/>'}
    body = extra.get(kind.removeprefix("rough"), "")
    m = material(load(tmp_path, f'<shape type="rectangle" id="a"><bsdf type="{kind}">{body}</bsdf></shape>'), "a")
    m = plastic_approximation(m)  # (plastics are Mitsuba's lobe itself, tests/test_plastic.py; this is for blends)
    diffuse, specular = MITSUBA_ALBEDOS[kind]
    assert np.allclose(m.kd, diffuse, rtol=rtol, atol=1e-9)
    assert np.allclose(np.add(m.ks, m.kr), specular, rtol=rtol)
