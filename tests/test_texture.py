"""Textures (clpt/texture.py, kernels/texture.h): the reference lookup against
values measured with Mitsuba 3, the kernels' lookups against it in renders
with an analytic answer, sRGB decoding, the loader's errors, texture
coordinates read from OBJ, PLY and serialized files, and a textured box
against a Mitsuba 3 reference (tests/data/cbox_textured_mitsuba.json)."""

import json
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import clpt
from clpt.features import scene_features
from clpt.meshio import read_mesh_uv
from clpt.mitsuba import load_mitsuba
from clpt.pack import pack_scene
from clpt.scene import Camera, Material, Quad, Scene, SceneError, Sphere
from clpt.texture import Texture, device_bytes, load_bitmap, srgb_to_linear

import meshgen
import stats
import texgen

DATA = Path(__file__).resolve().parent / "data"

# Mitsuba 3.9.1 (scalar_rgb and llvm_ad_rgb agree) evaluating a 4 x 1 float
# bitmap of texels 0, 1, 2, 3 at v = 0.5 and these u:
MITSUBA_WRAP_U = (-1.2, -0.6, -0.1, 0.05, 0.3, 0.95, 1.1, 1.6, 2.3)
MITSUBA_WRAP = {
    ("repeat", "nearest"): (3.0, 1.0, 3.0, 0.0, 1.0, 3.0, 0.0, 2.0, 1.0),
    ("repeat", "bilinear"): (2.7, 1.1, 2.7, 0.9, 0.7, 2.1, 0.3, 1.9, 0.7),
    ("mirror", "nearest"): (3.0, 2.0, 0.0, 0.0, 1.0, 3.0, 3.0, 1.0, 1.0),
    ("mirror", "bilinear"): (2.7, 1.9, 0.0, 0.0, 0.7, 3.0, 3.0, 1.1, 0.7),
    ("clamp", "nearest"): (0.0, 0.0, 0.0, 0.0, 1.0, 3.0, 3.0, 3.0, 3.0),
    ("clamp", "bilinear"): (0.0, 0.0, 0.0, 0.0, 0.7, 3.0, 3.0, 3.0, 3.0),
}
# ... a 2 x 1 8-bit PNG of (0, 128, 255) and (64, 200, 10), not raw, bilinear,
# at u = 0.25 (texel 0's centre) and 0.5 (between the two): decoded, then filtered.
MITSUBA_SRGB_PNG = (((0, 128, 255), (64, 200, 10)),
                    ((0.0, 0.21586, 1.0), (0.02563, 0.39672, 0.50152)))


@pytest.mark.parametrize("wrap, filt", sorted(MITSUBA_WRAP))
def test_reference_lookup_matches_mitsuba(wrap, filt):
    t = Texture("bitmap", data=np.repeat(np.arange(4.0)[None, :, None], 3, axis=2), wrap=wrap, filter=filt)
    uv = np.stack([np.array(MITSUBA_WRAP_U), np.full(len(MITSUBA_WRAP_U), 0.5)], axis=1)
    assert np.allclose(t.eval(uv)[:, 0], MITSUBA_WRAP[(wrap, filt)], atol=1e-6)


def test_checkerboard_cells_and_to_uv():
    """color0 where both fractional parts are above 1/2 or neither is (Mitsuba's
    rule, also measured: to_uv scale (2, 3) puts (0.3, 0.1) in color1)."""
    t = Texture("checkerboard", color0=(1, 0, 0), color1=(0, 1, 0), to_uv=((2, 0, 0), (0, 3, 0)))
    uv = np.array([(0.1, 0.1), (0.3, 0.1), (0.1, 0.2), (0.3, 0.2), (0.6, 0.6), (0.5, 0.5)])
    assert t.eval(uv)[:, 0].tolist() == [1, 0, 0, 1, 0, 1]


def test_to_uv_from_a_4x4_keeps_x_y_rows_and_the_translation(tmp_path):
    """Mitsuba applies to_uv as a 2-D affine map: x and y rows, the translation column; z is ignored."""
    m = np.eye(4)
    m[:2, :2] = [[2, 0.5], [0, 3]]
    m[:2, 3] = (0.25, -1)
    m[2, 3] = 7
    t = Texture("checkerboard", to_uv=m)
    assert t.to_uv == ((2, 0.5, 0.25), (0, 3, -1))


def test_srgb_decoding_of_8_bit_files_as_mitsuba(tmp_path):
    px, expect = MITSUBA_SRGB_PNG
    texgen.write_png(tmp_path / "t.png", np.array([px], dtype=np.uint8))
    data = load_bitmap(tmp_path / "t.png")
    assert np.allclose(data[0, 0], expect[0], atol=1e-5)
    assert np.allclose(srgb_to_linear(np.array([128 / 255]))[0], 0.21586, atol=1e-5)
    t = Texture("bitmap", data=data)
    assert np.allclose(t.eval([[0.5, 0.5]])[0], expect[1], atol=1e-5)  # filtered after decoding
    raw = load_bitmap(tmp_path / "t.png", raw=True)
    assert np.allclose(raw[0, 1], np.array(px[1]) / 255, atol=1e-6)


def test_memory_of_an_8k_texture():
    """3 reals a texel: 768 MiB for 8192 x 8192 in float builds (1.5 GiB in double)."""
    t = Texture("bitmap", data=np.zeros((8, 8, 3), np.float32))
    assert device_bytes([t]) == 8 * 8 * 12
    assert device_bytes([t]) * (8192 * 8192) // 64 == 768 * 2 ** 20


# --- the kernels' lookups, in renders with an exact answer ------------------------------------------------

RES = 16


def _head_on(tex: Texture):
    """The unit quad filling a RES x RES image head-on (a plane at right
    angles to the view: pixels map to equal squares of (u, v)), diffuse with
    the texture as its reflectance, inside a uniformly emitting sphere (Le =
    1). With BSDF sampling only, each sample is the texture's value where it
    lands (the cosine-weighted direction always finds Le = 1): a pixel's
    expectation is the texture's mean over its square."""
    d = 2.0
    cam = Camera(origin=(0.5, 0.5, d), target=(0.5, 0.5, 0), fov=math.degrees(2 * math.atan(0.5 / d)),
                 width=RES, height=RES)
    quad = Quad(corner=(0, 0, 0), edge_u=(1, 0, 0), edge_v=(0, 1, 0),
                material=Material(kd=tex.max(), textures=(("reflectance", tex),)))
    env = Sphere(center=(0.5, 0.5, 0), radius=10, material=Material(), emission=(1, 1, 1), two_sided=True)
    return Scene(camera=cam, shapes=[quad, env])


def _pixel_uv(offset=(0.5, 0.5)):
    """(u, v) of each pixel's point at offset within it (row 0 at the top, v = 1)."""
    j, i = np.mgrid[0:RES, 0:RES].astype(np.float64)
    return np.stack([(i + offset[0]) / RES, 1 - (j + offset[1]) / RES], axis=-1)


RNG_TEXELS = np.random.default_rng(7).uniform(0.05, 0.95, (4, 4, 3)).astype(np.float32)
SHIFT = ((2, 0, -0.5), (0, 2, -0.5))  # u, v in [-0.5, 1.5]: every wrap mode's outside
CASES = {
    "checkerboard": dict(kind="checkerboard", color0=(0.8, 0.2, 0.1), color1=(0.1, 0.3, 0.9),
                         to_uv=((2, 0, 0), (0, 2, 0))),
    "checkerboard_shifted": dict(kind="checkerboard", color0=(0.7, 0.7, 0.2), color1=(0.1, 0.6, 0.4),
                                 to_uv=((4, 0, 0.5), (0, 2, 0))),
    "nearest_repeat": dict(kind="bitmap", data=RNG_TEXELS, filter="nearest"),
    "bilinear_repeat": dict(kind="bitmap", data=RNG_TEXELS, to_uv=SHIFT),
    "nearest_mirror": dict(kind="bitmap", data=RNG_TEXELS, filter="nearest", wrap="mirror", to_uv=SHIFT),
    "bilinear_mirror": dict(kind="bitmap", data=RNG_TEXELS, wrap="mirror", to_uv=SHIFT),
    "nearest_clamp": dict(kind="bitmap", data=RNG_TEXELS, filter="nearest", wrap="clamp", to_uv=SHIFT),
    "bilinear_clamp": dict(kind="bitmap", data=RNG_TEXELS, wrap="clamp", to_uv=SHIFT),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_kernel_lookup_head_on(device_spec, case):
    """Each pixel is the texture's value at its centre: pixels lie inside one
    checkerboard cell or texel, or (bilinear) inside one square between
    texel centres, where the bilinear function's mean is its value at the
    centre. The checkerboards' cells therefore hold exactly color0 and
    color1. Tolerance: 5 sigma of the pixel mean, sigma bounded by the
    texture's largest difference from the centre within the pixel (and
    float rounding)."""
    kw = dict(CASES[case])
    tex = Texture(kw.pop("kind"), **kw)
    spp = 64
    res = clpt.Renderer(_head_on(tex), device=device_spec, nee=False, photons=False).render(
        spp=spp, seed=3, max_depth=1)
    img = res.image
    expect = tex.eval(_pixel_uv())
    spread = np.max([np.abs(tex.eval(_pixel_uv(o)) - expect) for o in ((0.01, 0.01), (0.99, 0.01), (0.01, 0.99),
                                                                      (0.99, 0.99))], axis=0)
    tol = 5 * spread / math.sqrt(spp) + 2e-5
    assert np.isfinite(img).all() and res.stats.nonfinite == 0
    worst = np.unravel_index(np.argmax(np.abs(img - expect) - tol), img.shape)
    assert (np.abs(img - expect) <= tol).all(), \
        f"pixel {worst[:2]}: {img[worst[:2]]} where the texture gives {expect[worst[:2]]}"
    if tex.kind == "checkerboard":
        for c in (tex.color0, tex.color1):
            assert (np.abs(img - np.array(c)).max(axis=2) < 2e-5).sum() >= RES * RES // 4


def test_scenes_without_textures_build_without_them():
    scene = clpt.load_scene("cornell_box")
    packed = pack_scene(scene)
    f = scene_features(packed)
    assert not f.textures and "-DCLPT_HAS_TEXTURES=0" in f.options()
    assert packed.textures == () and packed.texel_rows == 0 and packed.indexed_rows == len(packed.records)
    tex = Texture("checkerboard")
    p2 = pack_scene(_head_on(tex))
    assert scene_features(p2).textures and p2.textures == (tex,)


def test_one_texture_referenced_twice_is_stored_once(tmp_path):
    texgen.write_png(tmp_path / "t.png", texgen.pattern(8))
    s = _load(tmp_path, '''<texture type="bitmap" id="t"><string name="filename" value="t.png"/></texture>
        <shape type="rectangle"><bsdf type="diffuse"><ref name="reflectance" id="t"/></bsdf></shape>
        <shape type="sphere"><bsdf type="diffuse"><ref name="reflectance" id="t"/></bsdf></shape>''')
    p = pack_scene(s)
    assert len(p.textures) == 1 and p.texel_rows == 8 * 8 * 3 // 4


# --- the Mitsuba loader ------------------------------------------------------------------------------------

def _xml(body):
    return ('<?xml version="1.0"?>\n<scene version="3.0.0"><sensor type="perspective"><float name="fov" '
            'value="45"/><film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>'
            f'</film></sensor><shape type="sphere"><emitter type="area"><rgb name="radiance" value="1"/></emitter>'
            f'<float name="radius" value="0.1"/><point name="center" x="0" y="5" z="0"/></shape>{body}</scene>')


def _load(tmp_path, body):
    p = tmp_path / "s.xml"
    p.write_text(_xml(body))
    return load_mitsuba(p)


@pytest.mark.parametrize("prop, value, message", [
    ("filename", "missing.png", "file not found: 'missing.png'"),
    ("wrap_mode", "wrap", "unknown wrap_mode 'wrap'"),
    ("filter_type", "trilinear", "unknown filter_type 'trilinear'"),
])
def test_loader_errors_in_one_line(tmp_path, prop, value, message):
    texgen.write_png(tmp_path / "t.png", texgen.pattern(4))
    props = {"filename": "t.png", prop: value}
    body = "".join(f'<string name="{k}" value="{v}"/>' for k, v in props.items())
    with pytest.raises(SceneError) as e:
        _load(tmp_path, f'<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" '
                        f'name="reflectance">{body}</texture></bsdf></shape>')
    msg = str(e.value)
    assert message in msg and "\n" not in msg and "s.xml:" in msg


def test_loader_maps_textures_to_materials(tmp_path):
    clpt.save_image(tmp_path / "t.exr", np.array([[[0.2, 0.4, 0.6], [0.4, 0.6, 0.8]]], dtype=np.float32))
    s = _load(tmp_path, '''
        <shape type="rectangle" id="d"><bsdf type="diffuse"><texture type="bitmap" name="reflectance">
            <string name="filename" value="t.exr"/><string name="filter_type" value="nearest"/>
            <string name="wrap_mode" value="clamp"/></texture></bsdf></shape>
        <shape type="rectangle" id="p"><bsdf type="roughplastic"><texture type="checkerboard"
            name="diffuse_reflectance"><rgb name="color0" value="0.1"/><rgb name="color1" value="0.5"/>
            </texture></bsdf></shape>
        <shape type="rectangle" id="c"><bsdf type="roughconductor"><texture type="checkerboard"
            name="specular_reflectance"/></bsdf></shape>''')
    mats = {sh.name: s.surface(sh) for sh in s.shapes}
    t = mats["d"].texture("reflectance")
    assert t.filter == "nearest" and t.wrap == "clamp" and np.allclose(mats["d"].kd, (0.4, 0.6, 0.8))
    assert np.allclose(t.data[0, 1], (0.4, 0.6, 0.8))  # EXR: linear already
    assert mats["p"].plastic and np.allclose(mats["p"].kp, 0.5) and mats["p"].texture("reflectance").kind == \
        "checkerboard"
    assert np.allclose(mats["c"].km, 0.4) and mats["c"].texture("specular") is not None


def test_alpha_texture_of_a_rough_conductor(tmp_path):
    """Its luminance (Mitsuba's eval_1), clamped to ALPHA_RANGE as the kernels clamp it."""
    from clpt import program
    from clpt.scene import ALPHA_RANGE

    s = _load(tmp_path, '''<shape type="rectangle" id="c"><bsdf type="roughconductor"><texture type="checkerboard"
        name="alpha"><rgb name="color0" value="0.1, 0.2, 0.3"/><rgb name="color1" value="0.5"/></texture>
        </bsdf></shape>''')
    m = s.surface(s.shapes[-1])
    assert m.texture("alpha").kind == "checkerboard"
    assert m.alpha == pytest.approx(0.5 * (0.5 + np.dot((0.1, 0.2, 0.3), (0.2126, 0.7152, 0.0722))))
    src = program.stitch(["path.h", "trace.cl"])
    kernel_range = [float(re.search(rf"#define TEX_ALPHA_{k} (\S+)", src).group(1)) for k in ("MIN", "MAX")]
    assert kernel_range == list(ALPHA_RANGE)


def test_reflectance_texture_above_one_is_refused(tmp_path):
    clpt.save_image(tmp_path / "t.exr", np.full((1, 1, 3), 1.5, dtype=np.float32))
    with pytest.raises(SceneError, match="at most 1"):
        _load(tmp_path, '<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" '
                        'name="reflectance"><string name="filename" value="t.exr"/></texture></bsdf></shape>')


# --- texture coordinates from mesh files --------------------------------------------------------------------

def test_obj_texture_coordinates(tmp_path):
    """Per vertex (a vertex with two vt is split), u v [w]; Mitsuba flips v for OBJ files by default."""
    p = tmp_path / "m.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0.1 0.2\nvt 0.3 0.4 0\nvt 0.5\nvt 0.9 0.8\n"
                 "f 1/1 2/2 3/3\nf 2/4 4/2 3/3\n")
    v, t, n, uv = read_mesh_uv(p)
    assert n is None and len(v) == 5  # vertex 2 with vt 2 and with vt 4
    corner_uv = uv[t]
    assert np.allclose(corner_uv[0], [(0.1, 0.2), (0.3, 0.4), (0.5, 0.0)])
    assert np.allclose(corner_uv[1], [(0.9, 0.8), (0.3, 0.4), (0.5, 0.0)])
    s = _load(tmp_path, '<shape type="obj" id="m"><string name="filename" value="m.obj"/></shape>')
    mesh = next(x for x in s.shapes if x.name == "m")
    assert np.allclose(mesh.uvs[mesh.triangles][0], [(0.1, 0.8), (0.3, 0.6), (0.5, 1.0)])
    s = _load(tmp_path, '<shape type="obj" id="m"><string name="filename" value="m.obj"/>'
                        '<boolean name="flip_tex_coords" value="false"/></shape>')
    assert np.allclose(next(x for x in s.shapes if x.name == "m").uvs, uv)


@pytest.mark.parametrize("names", [("u", "v"), ("s", "t"), ("texture_u", "texture_v")])
@pytest.mark.parametrize("binary", [False, True])
def test_ply_texture_coordinates(tmp_path, names, binary):
    vs = np.array([[0, 0, 0, 0.1, 0.2], [1, 0, 0, 0.3, 0.4], [0, 1, 0, 0.5, 0.6]])
    head = (f"ply\nformat {'binary_little_endian' if binary else 'ascii'} 1.0\nelement vertex 3\n"
            "property float x\nproperty float y\nproperty float z\n"
            f"property float {names[0]}\nproperty float {names[1]}\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n").encode()
    if binary:
        body = vs.astype("<f4").tobytes() + bytes([3]) + np.array([0, 1, 2], "<i4").tobytes()
    else:
        body = ("\n".join(" ".join(f"{x:g}" for x in row) for row in vs) + "\n3 0 1 2\n").encode()
    (tmp_path / "m.ply").write_bytes(head + body)
    _, _, _, uv = read_mesh_uv(tmp_path / "m.ply")
    assert np.allclose(uv, vs[:, 3:], atol=1e-7)


def test_serialized_texture_coordinates(tmp_path):
    v, t = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]])
    uvs = np.array([[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]])
    meshgen.write_serialized(tmp_path / "m.serialized", [dict(vertices=v, triangles=t, uvs=uvs,
                                                              normals=np.tile([0, 0, 1.0], (3, 1)))])
    _, _, n, uv = read_mesh_uv(tmp_path / "m.serialized")
    assert n is not None and np.allclose(uv, uvs, atol=1e-7)
    meshgen.write_serialized(tmp_path / "n.serialized", [dict(vertices=v, triangles=t)])
    assert read_mesh_uv(tmp_path / "n.serialized")[3] is None


# --- a textured box against Mitsuba 3 -------------------------------------------------------------------------

REFERENCE = json.loads((DATA / "cbox_textured_mitsuba.json").read_text()) \
    if (DATA / "cbox_textured_mitsuba.json").is_file() else None


@pytest.mark.skipif(REFERENCE is None, reason="no stored Mitsuba reference (tests/mitsuba_measure.py --reference)")
def test_textured_box_renders_as_in_mitsuba(device_spec):
    """cbox_textured.xml (checkerboard floor and sphere, bitmap wall and cube
    through every parametrisation, a textured rough plastic OBJ) path traced:
    the image's mean colour within 0.5% of Mitsuba's, no 16x16-pixel block
    beyond 4 sigma of both renders' noise."""
    scene = clpt.load_scene(DATA / "cbox_textured.xml", params={"res": REFERENCE["width"]})
    res = clpt.Renderer(scene, device=device_spec, photons=False).render(spp=1024, seed=1)
    assert np.isfinite(res.image).all() and res.stats.nonfinite == 0
    stats.assert_matches_reference(res, REFERENCE)


def test_textures_are_weighed_against_memory():
    from clpt import preflight

    tex = Texture("bitmap", data=np.zeros((32, 16, 3), np.float32))
    scene = _head_on(tex)
    assert preflight.scene_resources(scene) == [("16x32 texture", 512 * preflight.TEXTURE_BYTES_PER_TEXEL)]
    room = preflight.HOST_BASE_BYTES + 512 * preflight.TEXTURE_BYTES_PER_TEXEL
    preflight.check_scene_memory(scene, available=room)
    with pytest.raises(SceneError, match=r"its textures need about .* \(1 texture, "
                                         r"the largest a 16x32 texture"):
        preflight.check_scene_memory(scene, available=room - 1)


def test_generic_lanes_and_double_builds_give_the_same_textured_image(device_spec):
    """The textured box in the generic build (textures on, counts at run time)
    is the specialized image to the bit; one lane and double precision agree
    within float rounding (the texture lookups are per lane in every build)."""
    scene = clpt.load_scene(DATA / "cbox_textured.xml", params={"res": 16})
    kw = dict(spp=2, seed=5, width=16, height=16)
    ref = clpt.Renderer(scene, device=device_spec, photons=False).render(**kw).image
    gen = clpt.Renderer(scene, device=device_spec, photons=False, kernel="generic")
    assert gen.features.textures and np.array_equal(gen.render(**kw).image, ref)
    for rkw in ({"lanes": 1}, {"precision": "double"}):
        img = clpt.Renderer(scene, device=device_spec, photons=False, **rkw).render(**kw).image
        assert np.isfinite(img).all()
        close = np.isclose(img, ref, rtol=1e-3, atol=1e-4).all(axis=2)
        assert close.mean() > 0.98, f"{rkw}: {1 - close.mean():.1%} of the pixels differ"


def _lobe(kind, colour, tex=None):
    """A material of one lobe whose colour (or texture) is in the slot a texture would fill."""
    names = {"roughconductor": ("specular",), "alpha": ("alpha",), "mirror": ("specular",),
             "glass": ("transmittance",), "roughglass": ("specular", "transmittance")}.get(kind, ("reflectance",))
    slot = tuple((name, tex) for name in names) if tex else ()
    c = tex.max() if tex else colour
    if kind == "alpha":  # a grey texture: its luminance is its value
        return Material.rough_conductor(alpha=c[0], distribution="ggx", specular_reflectance=(0.9, 0.8, 0.7),
                                        textures=slot)
    if kind == "diffuse":
        return Material(kd=c, textures=slot)
    if kind == "roughconductor":
        return Material.rough_conductor(alpha=0.3, distribution="ggx", specular_reflectance=c, textures=slot)
    if kind == "mirror":  # a smooth conductor
        return Material(kr=c, one_sided=True, textures=slot)
    if kind == "glass":
        return Material(kt=c, ior=1.5, textures=slot)
    if kind == "roughglass":
        return Material.rough_dielectric(alpha=0.3, distribution="ggx", specular_reflectance=c,
                                         specular_transmittance=c, textures=slot)
    return Material.rough_plastic(diffuse_reflectance=c, specular_reflectance=(0, 0, 0), alpha=0.2, textures=slot)


@pytest.mark.parametrize("kind", ["diffuse", "roughconductor", "plastic", "alpha", "mirror", "glass", "roughglass"])
def test_a_textured_lobe_is_the_untextured_lobe_of_its_colour(device_spec, kind):
    """Head-on (as above), one bounce, every random number the same: a
    checkerboard cell of the textured surface is, pixel for pixel, the
    untextured surface of that cell's colour (the BSDF never knows the colour
    was looked up; the rough conductor's specular and the plastic's diffuse
    base included, a rough conductor's alpha, a smooth conductor's
    reflectance, a dielectric's transmittance and a rough dielectric's
    reflectance and transmittance)."""
    colours = ((0.1, 0.1, 0.1), (0.6, 0.6, 0.6)) if kind == "alpha" else ((0.8, 0.3, 0.1), (0.2, 0.5, 0.9))
    tex = Texture("checkerboard", color0=colours[0], color1=colours[1], to_uv=((2, 0, 0), (0, 2, 0)))
    base = _head_on(tex)

    def render(mat):
        scene = Scene(camera=base.camera, shapes=[replace(base.shapes[0], material=mat), base.shapes[1]])
        return clpt.Renderer(scene, device=device_spec, photons=False).render(spp=8, seed=9, max_depth=1).image

    img = render(_lobe(kind, None, tex))
    cell0 = tex.eval(_pixel_uv())[..., 0] == tex.color0[0]
    for colour, where in ((tex.color0, cell0), (tex.color1, ~cell0)):
        plain = render(_lobe(kind, colour))
        assert plain[where].mean() > 0.01
        assert np.allclose(img[where], plain[where], rtol=1e-5, atol=1e-7), \
            f"{kind}: {np.abs(img[where] - plain[where]).max():.3g} off in the cells of {colour}"


def test_loader_maps_conductor_and_dielectric_textures(tmp_path):
    """A smooth conductor's specular_reflectance texture times the conductor's
    albedo (what its mirror colour is), a thin dielectric's reflectance and
    transmittance textures times its summed reflectance and the rest, a rough
    dielectric's into its own slots, a smooth dielectric's transmittance."""
    from clpt.mitsuba import conductor_albedo, conductor_ior

    checker = '<texture type="checkerboard" name="{}"><rgb name="color0" value="0.2, 0.4, 0.6"/></texture>'
    s = _load(tmp_path, f'''
        <shape type="rectangle" id="c"><bsdf type="conductor"><string name="material" value="Au"/>
            {checker.format("specular_reflectance")}</bsdf></shape>
        <shape type="rectangle" id="t"><bsdf type="thindielectric">{checker.format("specular_reflectance")}
            {checker.format("specular_transmittance")}</bsdf></shape>
        <shape type="rectangle" id="r"><bsdf type="roughdielectric">{checker.format("specular_reflectance")}
            {checker.format("specular_transmittance")}</bsdf></shape>
        <shape type="rectangle" id="d"><bsdf type="dielectric">{checker.format("specular_transmittance")}</bsdf>
        </shape>''')
    mats = {sh.name: s.surface(sh) for sh in s.shapes}
    albedo = np.array(conductor_albedo(*conductor_ior("Au")))
    c = mats["c"].texture("specular")
    assert np.allclose(c.color0, np.array([0.2, 0.4, 0.6]) * albedo) and np.allclose(mats["c"].kr, c.max())
    t = mats["t"]
    r = t.kr[0] / 0.2  # the checkerboard's largest value is color0 (color1 is 0.2 grey)
    assert np.allclose(t.texture("specular").color0, np.array([0.2, 0.4, 0.6]) * r)
    assert np.allclose(t.texture("transmittance").color0, np.array([0.2, 0.4, 0.6]) * (1 - r))
    rd = mats["r"]
    assert rd.texture("specular").color0 == (0.2, 0.4, 0.6) and rd.texture("transmittance").color0 == (0.2, 0.4, 0.6)
    assert mats["d"].texture("transmittance") is not None and np.allclose(mats["d"].kt, (0.2, 0.4, 0.6))


TOML_BOX = """
[camera]
origin = [0, 0, 3]
target = [0, 0, 0]
fov = 40
width = 16
height = 16

[materials.m]
{material}

[[shapes]]
type = "quad"
corner = [-1, -1, 0]
edge_u = [2, 0, 0]
edge_v = [0, 2, 0]
material = "m"

[[shapes]]
type = "sphere"
center = [0, 0, 5]
radius = 0.5
material = {{ kd = 0 }}
emission = [5, 5, 5]
"""


def test_toml_textures(tmp_path, device_spec):
    """A TOML material's colour or alpha may be a texture table with the XML
    loader's parameters: a bitmap (relative to the scene file, sRGB-decoded
    unless raw) and a checkerboard; the scene renders as the same Material
    built in Python does, to the bit."""
    texels = np.array([[[0.2, 0.4, 0.6], [0.9, 0.1, 0.3]], [[0.5, 0.5, 0.5], [0.05, 0.7, 0.2]]], dtype=np.float32)
    clpt.save_image(tmp_path / "t.exr", texels)
    (tmp_path / "s.toml").write_text(TOML_BOX.format(material='''
km = { texture = "bitmap", filename = "t.exr", filter_type = "nearest", wrap_mode = "mirror", to_uv = [[2, 0, 0], [0, 2, 0]] }
alpha = { texture = "checkerboard", color0 = 0.1, color1 = [0.3, 0.3, 0.3] }
distribution = "ggx"'''))
    s = clpt.load_scene(tmp_path / "s.toml")
    m = s.surface(s.shapes[0])
    km, alpha = m.texture("specular"), m.texture("alpha")
    assert km.kind == "bitmap" and km.filter == "nearest" and km.wrap == "mirror"
    assert np.array_equal(km.data, texels) and km.to_uv == ((2.0, 0.0, 0.0), (0.0, 2.0, 0.0))
    assert m.km == km.max() and alpha.color1 == (0.3, 0.3, 0.3) and m.alpha == pytest.approx(0.2)
    plain = Material(km=km.max(), alpha=0.2, distribution="ggx", textures=(("specular", km), ("alpha", alpha)))
    built = Scene(camera=s.camera, shapes=[replace(s.shapes[0], material=plain), s.shapes[1]])
    kw = dict(spp=4, seed=3)
    a = clpt.Renderer(s, device=device_spec, photons=False).render(**kw).image
    b = clpt.Renderer(built, device=device_spec, photons=False).render(**kw).image
    assert np.array_equal(a, b) and a.max() > 0


@pytest.mark.parametrize("material,message", [
    ('kd = { texture = "marble" }', "materials.m.kd.texture: unknown texture 'marble'"),
    ('kd = { texture = "bitmap" }', "materials.m.kd: missing required key 'filename'"),
    ('kd = { texture = "bitmap", filename = "none.png" }', "materials.m.kd.filename: cannot read"),
    ('kd = { texture = "bitmap", filename = "t.exr", color0 = 0.1 }', "materials.m.kd.color0: not a bitmap key"),
    ('kd = { texture = "checkerboard", wrap_mode = "clamp" }', "materials.m.kd.wrap_mode: not a checkerboard key"),
    ('kd = { texture = "bitmap", filename = "t.exr", wrap_mode = "wrap" }', "unknown wrap_mode 'wrap'"),
    ('kd = { texture = "checkerboard", color0 = 1.5 }', "must be at most 1"),
    ('kd = { texture = "checkerboard", to_uv = [[1, 0]] }', "materials.m.kd.to_uv: must be 2 or 3 rows"),
    ('kd = { texture = "checkerboard", colour0 = 0.5 }', "materials.m.kd.colour0: unknown key"),
    ('km = { texture = "checkerboard" }\nkr = { texture = "checkerboard" }', "a second texture for the specular slot"),
])
def test_toml_texture_errors_in_one_line(tmp_path, material, message):
    clpt.save_image(tmp_path / "t.exr", np.full((1, 1, 3), 0.5, dtype=np.float32))
    (tmp_path / "s.toml").write_text(TOML_BOX.format(material=material))
    with pytest.raises(clpt.SceneError) as e:
        clpt.load_scene(tmp_path / "s.toml")
    assert message in str(e.value) and "\n" not in str(e.value), str(e.value)


# Mitsuba 3.9.1's (u, v) and shading-frame tangent at points of a disk and a cylinder (scalar_rgb: a ray
# along -n onto sample_position's points of the shapes of DISK_CYLINDER): (point, uv, s).
DISK_CYLINDER = '''
    <shape type="disk" id="d"><transform name="to_world"><rotate x="1" angle="30"/><translate z="1"/></transform>
        </shape>
    <shape type="cylinder" id="c"><point name="p0" x="0.3" y="0.1" z="-0.5"/><point name="p1" x="-0.2" y="0.4"
        z="1.1"/><float name="radius" value="0.7"/></shape>'''
MITSUBA_DISK_CYLINDER = [
    ((0.018568, 0.78006, 1.450368), (0.900927, 0.24672), (0.02061, 0.865842, 0.499894)),
    ((-0.523499, 0.631127, 1.364381), (0.897299, 0.349142), (-0.583416, 0.703363, 0.406087)),
    ((-0.357229, -0.102531, 0.940803), (0.376337, 0.550934), (-0.949227, -0.272446, -0.157297)),
    ((0.639947, -0.122548, 0.929247), (0.655405, 0.965365), (0.976414, -0.186981, -0.107954)),
    ((0.687304, 0.401943, 0.560557), (0.027559, 0.549594), (-0.138368, 0.964689, -0.224119)),
    ((-0.730957, 0.144417, 0.53524), (0.538143, 0.753513), (0.200918, -0.949545, 0.240826)),
    ((0.27695, -0.465435, 0.196454), (0.788429, 0.329732), (0.93421, 0.261184, 0.242969)),
    ((-0.486759, 0.371485, -0.247225), (0.453498, 0.303195), (-0.300777, -0.949977, 0.084128)),
]


def test_disk_and_cylinder_uvs_as_mitsuba(tmp_path):
    """A disk's (u, v) = (r, phi / 2 pi) and a cylinder's (phi / 2 pi, z /
    length) in Mitsuba's frames: each fan triangle and prism quad carries them
    at its vertices (within the polygon's approximation of the circle; a fan
    triangle's centre takes its middle phi), and
    dp/du from them is Mitsuba's tangent within the segments' 1.9 degrees."""
    from clpt.pack import _planar_tangents

    s = _load(tmp_path, DISK_CYLINDER)
    shapes = {sh.name: sh for sh in s.shapes}
    for k, (p, uv, tangent) in enumerate(MITSUBA_DISK_CYLINDER):
        mesh = shapes["dc"[k // 4]]
        v, t = mesh.vertices, mesh.triangles
        a, e1, e2 = v[t[:, 0]], v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]
        # The triangle nearest the point, and the point's barycentrics in it.
        q = np.asarray(p) - a
        g = np.stack([e1, e2], axis=2)
        bc = np.array([np.linalg.lstsq(g[i], q[i], rcond=None)[0] for i in range(len(t))])
        dist = np.linalg.norm(np.einsum("tij,tj->ti", g, bc) - q, axis=1)
        inside = (bc >= -1e-3).all(axis=1) & (bc.sum(axis=1) <= 1 + 1e-3)
        i = int(np.argmin(np.where(inside, dist, np.inf)))
        u0, u1, u2 = mesh.uvs[t[i]]
        got = u0 + bc[i, 0] * (u1 - u0) + bc[i, 1] * (u2 - u0)
        # r within the polygon's 0.1%; phi / 2 pi within half a segment (1 / 192): a fan triangle's
        # centre has one phi.
        assert (np.abs(got - uv) <= (np.array([2e-3, 1 / 192]) if k < 4 else 2e-3)).all(), (k, got, uv)
        rec = _planar_tangents(e1[i:i + 1], e2[i:i + 1], np.stack([u0, u1 - u0, u2 - u0])[None])["dpdu"][0, :3]
        assert np.dot(rec / np.linalg.norm(rec), tangent) > np.cos(np.radians(1.9)), k
