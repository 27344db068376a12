"""Textured area lights: Mitsuba 3's `area` emitter whose radiance is a
bitmap or checkerboard texture, looked up at the emitting point's (u, v).

- Seen head-on by camera rays, each pixel is the texture's value there
  (the emission event of kernels/path.h), on a quad, a mesh with texture
  coordinates and a sphere.
- A plane lit by a checkerboard-textured quad light gives the image of two
  separate quads of the two colours, with next event estimation and
  multiple importance sampling (the light sample's radiance at the sampled
  point), with BSDF sampling only, and through a glass sphere's photons
  (photon emission: the radiance at the photon's starting point).
- The Mitsuba XML loader maps a textured `radiance` to the emission slot;
  scenes without textured emitters build without them.
- A textured light's pick power is its radiance's mean over its surface by
  area (a sphere map's rows weighted by sin(theta), a mesh's uneven (u, v)
  map), as brute-force sampling of the surface finds it.
- tests/data/cbox_textured_lights.xml against a stored Mitsuba 3 reference
  (tests/mitsuba_textured_lights.py made it).
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

import clpt
import stats
from clpt.features import scene_features
from clpt.pack import pack_scene
from clpt.photons import PhotonSettings
from clpt.scene import EMISSION_SLOT, Camera, Material, Mesh, Quad, Scene, SceneError, Sphere
from clpt.texture import Texture

DATA = Path(__file__).resolve().parent / "data"
RES = 16
TEXELS = np.random.default_rng(11).uniform(0.2, 3.0, (4, 4, 3)).astype(np.float32)
CHECKER = Texture("checkerboard", color0=(4.0, 1.0, 0.5), color1=(0.5, 2.0, 3.0))


def _lamp(tex: Texture, **kw) -> Material:
    return Material(emission=tex.max(), textures=((EMISSION_SLOT, tex),), **kw)


def _pixel_uv(offset=(0.5, 0.5)):
    j, i = np.mgrid[0:RES, 0:RES].astype(np.float64)
    return np.stack([(i + offset[0]) / RES, 1 - (j + offset[1]) / RES], axis=-1)


def _head_on_camera():
    d = 2.0
    return Camera(origin=(0.5, 0.5, d), target=(0.5, 0.5, 0), fov=math.degrees(2 * math.atan(0.5 / d)),
                  width=RES, height=RES)


def _render(scene, device_spec, spp, **kw):
    r = clpt.Renderer(scene, device=device_spec, **kw).render(spp=spp, seed=5, max_depth=kw.pop("max_depth", 8))
    assert np.isfinite(r.image).all()
    return r.image


@pytest.mark.parametrize("shape", ["quad", "mesh"])
@pytest.mark.parametrize("kind", ["nearest", "checker"])
def test_textured_emitter_seen_head_on(device_spec, shape, kind):
    """Every pixel lies inside one texel or checkerboard cell: its value exactly (float rounding)."""
    tex = Texture("bitmap", data=TEXELS, filter="nearest") if kind == "nearest" else \
        Texture("checkerboard", color0=(4.0, 1.0, 0.5), color1=(0.5, 2.0, 3.0), to_uv=((2, 0, 0), (0, 2, 0)))
    if shape == "quad":
        s = Quad(corner=(0, 0, 0), edge_u=(1, 0, 0), edge_v=(0, 1, 0), material=_lamp(tex))
    else:  # two triangles with texture coordinates (u, v) = (x, y)
        v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
        s = Mesh(vertices=v, triangles=np.array([[0, 1, 2], [0, 2, 3]]), uvs=v[:, :2].copy(), material=_lamp(tex))
    img = _render(Scene(camera=_head_on_camera(), shapes=[s]), device_spec, 16, photons=False)
    expect = tex.eval(_pixel_uv())
    assert np.abs(img - expect).max() <= 1e-5 * tex.max()[0] + 1e-5, np.abs(img - expect).max()


# --- a textured light lighting a plane: the same as separate lights of its colours ------------------------------

C0, C1 = (3.0, 1.0, 0.4), (0.5, 1.5, 2.5)
HALVES = Texture("checkerboard", color0=C0, color1=C1, to_uv=((1, 0, 0), (0, 0, 0.25)))  # u <= 1/2: C0


def _lit_floor(lamps, glass=False):
    """A diffuse floor (z = 0) seen from above, lit by lamps facing down at z = 1 over x, y in [-1/2, 1/2]
    (edge u along y: the split at y = 0), with a glass ball between them if glass."""
    cam = Camera(origin=(0, 0, 3), target=(0, 0, 0), up=(0, 1, 0), fov=60, width=RES, height=RES)
    floor = Quad(corner=(-2, -2, 0), edge_u=(4, 0, 0), edge_v=(0, 4, 0), material=Material(kd=(0.6, 0.6, 0.6)))
    shapes = [floor] + lamps
    if glass:
        shapes.append(Sphere(center=(0.3, 0.2, 0.45), radius=0.25, material=Material(kt=(1, 1, 1), ior=1.5)))
    return Scene(camera=cam, shapes=shapes)


def _textured_lamp():
    return [Quad(corner=(-0.5, -0.5, 1), edge_u=(0, 1, 0), edge_v=(1, 0, 0), material=_lamp(HALVES))]


def _two_lamps():
    return [Quad(corner=(-0.5, -0.5, 1), edge_u=(0, 0.5, 0), edge_v=(1, 0, 0), material=Material(emission=C0)),
            Quad(corner=(-0.5, 0, 1), edge_u=(0, 0.5, 0), edge_v=(1, 0, 0), material=Material(emission=C1))]


def _agree(a, b, what, k=5.0):
    """Two independent renders agree per 4x4 block of pixels within k sigma of both noises (Sidak over the
    blocks and channels is below k = 5 for 48 tests)."""
    def blocks(x):
        return x.reshape(RES // 4, 4, RES // 4, 4, -1).mean(axis=(1, 3))

    da = blocks(a.image) - blocks(b.image)
    var = sum(blocks((r.lum_var / r.sample_count)[..., None]) / 16 for r in (a, b))
    z = np.abs(da) @ np.array([0.2126, 0.7152, 0.0722]) / np.sqrt(var[..., 0])
    assert z.max() < k, f"{what}: a block is {z.max():.1f} sigma off"
    rel = abs(a.image.mean() / b.image.mean() - 1)
    assert rel < 0.02, f"{what}: image means differ by {rel:.2%}"


@pytest.mark.parametrize("nee", [True, False])
def test_textured_lamp_lights_like_two_lamps(device_spec, nee):
    """Next event estimation (the radiance at the sampled point, the light
    picked by its texture's mean power) with MIS, and BSDF sampling alone."""
    spp = 256 if nee else 1024
    a = clpt.Renderer(_lit_floor(_textured_lamp()), device=device_spec, nee=nee, photons=False).render(
        spp=spp, seed=1, max_depth=3)
    b = clpt.Renderer(_lit_floor(_two_lamps()), device=device_spec, nee=nee, photons=False).render(
        spp=spp, seed=2, max_depth=3)
    _agree(a, b, "nee" if nee else "bsdf")


def test_textured_lamp_photons_like_two_lamps(device_spec):
    """A glass ball's caustic from the photon map (offline: the caustic
    buffer alone), each photon carrying the radiance where it leaves the
    lamp (emitted by area, as untextured): the caustic's total energy per
    channel matches two lamps' within 10% (200k photons; the spread measured
    over seeds is 3.5%; the lamp's largest value in place of its texture
    gives 1.2x to 1.8x)."""
    kw = dict(device=device_spec, photons=PhotonSettings(count=200_000, pilot=False, mode="offline"))
    a = clpt.Renderer(_lit_floor(_textured_lamp(), glass=True), **kw).render(spp=64, seed=1, max_depth=4)
    b = clpt.Renderer(_lit_floor(_two_lamps(), glass=True), **kw).render(spp=64, seed=11, max_depth=4)
    ratio = a.caustic_image.reshape(-1, 3).sum(axis=0) / b.caustic_image.reshape(-1, 3).sum(axis=0)
    assert np.abs(ratio - 1).max() < 0.1, f"caustic energy ratio {ratio}"


# --- the loader and the build ---------------------------------------------------------------------------------


def _xml_scene(tmp_path, emitter_radiance, shape='type="rectangle"'):
    p = tmp_path / "s.xml"
    p.write_text('<?xml version="1.0"?>\n<scene version="3.0.0"><sensor type="perspective"><float name="fov" '
                 'value="45"/><film type="hdrfilm"><integer name="width" value="8"/><integer name="height" '
                 f'value="8"/></film></sensor><shape {shape}><emitter type="area">{emitter_radiance}</emitter>'
                 '</shape></scene>')
    return clpt.load_scene(p)


def test_loader_maps_a_textured_radiance_to_the_emission_slot(tmp_path):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no mean-colour fallback any more
        scene = _xml_scene(tmp_path, '<texture type="checkerboard" name="radiance"><rgb name="color0" '
                                     'value="0.9, 0.5, 0.1"/><rgb name="color1" value="0.1, 0.2, 0.3"/></texture>')
    m = scene.surface(scene.shapes[0])
    t = m.texture(EMISSION_SLOT)
    assert t is not None and t.kind == "checkerboard" and m.emission == (0.9, 0.5, 0.3)
    assert m.mean_emission == pytest.approx((0.5, 0.35, 0.2)) and m.bsdf_textures == ()
    packed = pack_scene(scene)
    assert packed.has_textured_emitters
    assert "-DCLPT_HAS_TEXTURED_EMITTERS=1" in scene_features(packed).options()


def test_scenes_without_textured_emitters_build_without_them():
    packed = pack_scene(clpt.load_scene("cornell_box"))
    assert not packed.has_textured_emitters
    assert "-DCLPT_HAS_TEXTURED_EMITTERS=0" in scene_features(packed).options()


def test_a_textured_emission_must_hold_the_texture_maximum():
    quad = Quad(corner=(0, 0, 0), edge_u=(1, 0, 0), edge_v=(0, 1, 0),
                material=Material(emission=(1, 1, 1), textures=((EMISSION_SLOT, CHECKER),)))
    with pytest.raises(SceneError, match=r"emission must be its texture's largest value per channel"):
        Scene(camera=_head_on_camera(), shapes=[quad]).check()


# --- against Mitsuba 3 ----------------------------------------------------------------------------------------

REFERENCE = json.loads((DATA / "cbox_textured_lights_mitsuba.json").read_text())


def test_textured_lights_box_renders_as_in_mitsuba(device_spec):
    """cbox_textured_lights.xml (a bitmap ceiling lamp, a checkerboard wall
    panel and a checkerboard sphere light, nothing else lit) path traced:
    the image's mean colour within 0.5% of Mitsuba's, no 16x16-pixel block
    beyond 4 sigma of both renders' noise."""
    scene = clpt.load_scene(DATA / "cbox_textured_lights.xml", params={"res": REFERENCE["width"]})
    res = clpt.Renderer(scene, device=device_spec, photons=False).render(spp=1024, seed=1)
    assert np.isfinite(res.image).all() and res.stats.nonfinite == 0
    stats.assert_matches_reference(res, REFERENCE)


# --- a textured light's pick power: its radiance's mean over its surface by area ---------------------------------

def _pole_texture():
    """A sphere map bright in two rows near the pole (v = theta / pi small) over a dim rest: those rows are
    1/16 of the texels but about 1% of the sphere's area."""
    img = np.full((32, 64, 3), 0.2, np.float32)
    img[1:3] = (40.0, 30.0, 20.0)
    return Texture("bitmap", data=img)


def _warped_mesh(n=6):
    """The unit square as an n x n grid of triangle pairs with (u, v) = (x^2, y^3): texels cover unequal areas."""
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    k = lambda i, j: i * (n + 1) + j  # noqa: E731
    tris = [t for i in range(n) for j in range(n)
            for t in ([k(i, j), k(i + 1, j), k(i + 1, j + 1)], [k(i, j), k(i + 1, j + 1), k(i, j + 1)])]
    return v, np.array(tris), np.stack([v[:, 0] ** 2, v[:, 1] ** 3], axis=1)


def _mc_mean(vals):
    """Mean and its standard error per channel of brute-force samples."""
    return vals.mean(axis=0), vals.std(axis=0) / math.sqrt(len(vals))


def _light_power(scene, k):
    """Light k's pick probability over the others' power: the power the packed scene gives it."""
    info = pack_scene(scene).section("lights")["info"]
    return info[k, 1]


def test_a_textured_spheres_power_is_its_radiance_averaged_by_area():
    """Brute force: 2^21 directions uniform on the sphere (fixed seed), the texture looked up at their
    (phi / 2 pi, theta / pi). The light's power (through its pick probability next to a plain quad
    light) is pi times its area times that mean within 5 standard errors, where the texel mean
    (each texel row alike) is hundreds of them off."""
    tex = _pole_texture()
    rng = np.random.default_rng(3)
    d = rng.normal(size=(1 << 21, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    phi = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi)
    mean, err = _mc_mean(tex.eval(np.stack([phi / (2 * np.pi), np.arccos(d[:, 2]) / np.pi], axis=1)))
    assert (np.abs(np.asarray(tex.mean()) - mean) > 200 * err).all()
    ball = Sphere(center=(0, 0, 0), radius=0.5, material=_lamp(tex))
    lamp = Quad(corner=(2, 0, 0), edge_u=(1, 0, 0), edge_v=(0, 1, 0), material=Material(emission=(1.0, 1.0, 1.0)))
    cam = Camera(origin=(0, 0, 5), target=(0, 0, 0), width=8, height=8)
    p = _light_power(Scene(camera=cam, shapes=[ball, lamp]), 0)
    expect_ball = math.pi * math.pi * float(mean.mean())  # pi * area (pi for r = 1/2) * mean radiance
    expect = expect_ball / (expect_ball + math.pi * 1.0)
    tol = 5 * float(err.mean()) * math.pi * math.pi * math.pi / (expect_ball + math.pi) ** 2  # d expect / d mean
    assert abs(p - expect) < tol, (p, expect, tol)


def test_a_textured_meshs_power_is_its_radiance_averaged_by_area():
    """As above on a mesh whose (u, v) = (x^2, y^3) crowds texels towards u, v = 0: brute force picks
    2^20 points uniform by area (a triangle by area, uniform barycentrics), their (u, v)
    interpolated; the packed power within 5 standard errors, the texel mean far off."""
    texels = np.random.default_rng(12).uniform(0.1, 1.0, (8, 8, 3)).astype(np.float32)
    texels[:2, :2] = 30.0  # bright where the map crowds texels into little area
    tex = Texture("bitmap", data=texels, wrap="clamp")
    v, t, uv = _warped_mesh()
    mesh = Mesh(vertices=v, triangles=t, uvs=uv, material=_lamp(tex))
    rng = np.random.default_rng(4)
    n = 1 << 20
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    areas = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    k = rng.choice(len(t), size=n, p=areas / areas.sum())
    s, r = np.sqrt(rng.random(n)), rng.random(n)
    b1, b2 = s * (1 - r), s * r
    u0 = uv[t[k, 0]]
    pts = u0 + b1[:, None] * (uv[t[k, 1]] - u0) + b2[:, None] * (uv[t[k, 2]] - u0)
    mean, err = _mc_mean(tex.eval(pts))
    assert (np.abs(np.asarray(tex.mean()) - mean) > 100 * err).all()
    lamp = Quad(corner=(2, 0, 0), edge_u=(1, 0, 0), edge_v=(0, 1, 0), material=Material(emission=(1.0, 1.0, 1.0)))
    cam = Camera(origin=(0, 0, 5), target=(0, 0, 0), width=8, height=8)
    p = _light_power(Scene(camera=cam, shapes=[mesh, lamp]), 0)
    expect_mesh = math.pi * float(mean.mean())  # area 1
    expect = expect_mesh / (expect_mesh + math.pi)
    tol = 5 * float(err.mean()) * math.pi * math.pi / (expect_mesh + math.pi) ** 2
    assert abs(p - expect) < tol, (p, expect, tol)
