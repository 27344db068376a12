"""The scene format and its checks: every user mistake is one clear message
naming the file, the key path and the reason; shipped scenes load and match
their reference data."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

import clpt
from clpt.pack import pack_scene
from clpt.resources import scene_path, shipped_scenes

DATA = Path(__file__).parent / "data"

GOOD = """
[camera]
origin = [0, 0, 3]
target = [0, 0, 0]
fov = 40

[materials]
lamp = { kd = 0.5, emission = [4, 4, 4] }

[[shapes]]
type = "quad"
name = "light"
material = "lamp"
corner = [-0.5, 1, -0.5]
edge_u = [1, 0, 0]
edge_v = [0, 0, 1]

[[shapes]]
type = "sphere"
material = "white"
center = [0, 0, 0]
radius = 0.5
"""


def parse(text):
    return clpt.parse_scene(text, source="test.toml")


def error_of(text):
    with pytest.raises(clpt.SceneError) as e:
        parse(text)
    msg = str(e.value)
    assert msg.startswith("test.toml: ") and "\n" not in msg
    return msg


def test_good_scene_parses():
    sc = parse(GOOD)
    assert len(sc.shapes) == 2 and sc.camera.fov == 40
    assert sc.surface(sc.shapes[0]).emission == (4.0, 4.0, 4.0)
    assert sc.materials["lamp"].kd == (0.5, 0.5, 0.5)  # a number is a grey


@pytest.mark.parametrize("edit,expect", [
    (lambda t: t.replace("fov = 40", "fov = 40\nfovy = 3"), ["camera.fovy", "unknown key", "fov"]),
    (lambda t: t.replace("fov = 40", ""), ["camera", "missing required key 'fov'"]),
    (lambda t: t.replace("fov = 40", 'fov = "wide"'), ["camera.fov", "must be a number"]),
    (lambda t: t.replace("radius = 0.5", "radius = nan"), ["shapes[1].radius", "finite"]),
    (lambda t: t.replace("radius = 0.5", "radius = inf"), ["shapes[1].radius", "finite"]),
    (lambda t: t.replace("radius = 0.5", "radius = -0.5"), ["shapes[1].radius", "> 0"]),
    (lambda t: t.replace("edge_v = [0, 0, 1]", "edge_v = [2, 0, 0]"), ["shapes[0] 'light'", "degenerate quad"]),
    (lambda t: t.replace('material = "white"', 'material = "whte"'),
     ["shapes[1].material", "unknown material 'whte'", "did you mean 'white'"]),
    (lambda t: t.replace("emission = [4, 4, 4]", "emission = [0, 0, 0]"), ["shapes", "no light"]),
    (lambda t: t.replace("kd = 0.5,", "kd = 0.5, kr = 0.6,"), ["materials.lamp", "energy conserving"]),
    (lambda t: t.replace("kd = 0.5,", "kd = -0.1,"), ["materials.lamp.kd", "negative"]),
    (lambda t: t.replace('type = "sphere"', 'type = "cube"'), ["shapes[1].type", "unknown shape type"]),
    (lambda t: t.replace("center = [0, 0, 0]", "center = [0, 0]"), ["shapes[1].center", "3 numbers"]),
    (lambda t: t.replace("target = [0, 0, 0]", "target = [0, 0, 0]\nup = [0, 0, 1]"),
     ["camera.up", "parallel to the view direction"]),
    (lambda t: t.replace("fov = 40", "fov = 40\nwidth = 0"), ["camera.width", ">= 1"]),
    (lambda t: t + '\n[[shapes]]\ntype = "plane"\nmaterial = "white"\npoint = [0,0,0]\nnormal = [0,1,0]\n'
                   'emission = [1,1,1]\n', ["shapes[2].emission", "infinite plane cannot be a light"]),
    (lambda t: t + '\n[[shapes]]\ntype = "triangle"\nmaterial = "white"\nvertices = [[0,0,0],[1,1,1],[2,2,2]]\n',
     ["shapes[2]", "degenerate triangle"]),
    (lambda t: t + '\n[[shapes]]\ntype = "quad"\nmaterial = "white"\n'
                   'vertices = [[0,0,0],[1,0,0],[1,1,0],[0,2,0]]\n', ["shapes[2].vertices", "parallelogram"]),
    (lambda t: t.replace("[camera]", "[camera\n"), ["TOML syntax error", "line"]),
    (lambda t: t + "\n[extra]\n", ["extra", "unknown key"]),
    (lambda t: t.replace('type = "sphere"', 'type = "sphere"\nshininess = 3'), ["shapes[1].shininess", "unknown key"]),
    (lambda t: t.replace("lamp = {", 'lamp = { preset = "glas",'), ["materials.lamp.preset", "did you mean 'glass'"]),
])
def test_mistakes_are_named(edit, expect):
    msg = error_of(edit(GOOD))
    for part in expect:
        assert part in msg, f"{part!r} not in {msg!r}"


def test_api_scenes_are_checked_too():
    cam = clpt.Camera(origin=(0, 0, 3), target=(0, 0, 0))
    with pytest.raises(clpt.SceneError, match=r"shapes\[0\] 'ball'.radius: must be > 0"):
        clpt.Scene(camera=cam, shapes=[clpt.Sphere(radius=-1, name="ball", emission=(1, 1, 1))]).check()
    with pytest.raises(clpt.SceneError, match="no light"):
        clpt.Scene(camera=cam, shapes=[clpt.Sphere()]).check()
    with pytest.raises(clpt.SceneError, match="energy conserving"):
        clpt.Scene(camera=cam, shapes=[clpt.Sphere(material=clpt.Material(kd=(0.8,) * 3, kt=(0.5,) * 3),
                                                   emission=(1, 1, 1))]).check()
    with pytest.raises(clpt.SceneError, match="unknown material preset"):
        clpt.Material.preset("chrome")


def test_box_faces_point_out_or_in():
    q = clpt.Box(center=(1, 2, 3), size=(2, 4, 6), rotation=(0, 35, 0)).quads()
    c = np.array([1, 2, 3])
    for inward, sign in ((False, 1), (True, -1)):
        for f in clpt.Box(center=(1, 2, 3), size=(2, 4, 6), rotation=(0, 35, 0), inward=inward).quads():
            mid = np.array(f.corner) + 0.5 * (np.array(f.edge_u) + np.array(f.edge_v))
            n = np.cross(f.edge_u, f.edge_v)
            assert sign * n @ (mid - c) > 0
    assert sum(np.linalg.norm(np.cross(f.edge_u, f.edge_v)) for f in q) == pytest.approx(2 * (8 + 24 + 12))


@pytest.mark.parametrize("name", ["cornell_box", "cornell_box_caustics"])
def test_cornell_boxes_match_reference(name):
    """Geometry, materials, light and camera exactly as Mitsuba 3's cornell_box()."""
    ref = json.loads((DATA / f"{name}.json").read_text())
    sc = clpt.load_scene(name)
    cam = ref["camera"]
    assert sc.camera.origin == tuple(cam["origin"]) and sc.camera.target == tuple(cam["target"])
    assert sc.camera.up == tuple(cam["up"]) and sc.camera.fov == cam["fov_deg"]
    assert sc.camera.fov_axis == cam["fov_axis"]
    ours = iter(sc.shapes)
    for shape in ref["shapes"]:
        mref = ref["materials"][shape["material"]]
        items = shape["quads"] if shape["kind"] == "quads" else [None]
        for q in items:
            s = next(ours)
            m = sc.surface(s)
            if q is not None:
                assert isinstance(s, clpt.Quad)
                assert np.allclose(s.vertices(), q, atol=1e-12)
            else:
                assert isinstance(s, clpt.Sphere)
                assert s.center == tuple(shape["center"]) and s.radius == shape["radius"]
            if mref["type"] == "diffuse":
                assert m.kd == tuple(mref["reflectance_rgb"]) and max(m.ks + m.kr + m.kt) == 0
            elif mref["type"] == "mirror":
                assert m.kr == tuple(mref["reflectance_rgb"]) and max(m.kd + m.kt) == 0
            else:
                assert m.kt == (1.0, 1.0, 1.0) and m.ior == mref["int_ior"] and mref["ext_ior"] == 1.0
            assert m.emission == tuple(shape.get("emission_rgb", (0.0, 0.0, 0.0)))
            assert m.two_sided == (not shape.get("one_sided_emitter", True))
    assert next(ours, None) is None


@pytest.mark.parametrize("name", shipped_scenes())
def test_shipped_scenes_load_and_pack(name):
    sc = clpt.load_scene(scene_path(name))
    packed = pack_scene(sc)
    assert packed.count("lights") >= 1 and np.isfinite(packed.records).all()
    assert sc.source.endswith(f"{name}.toml")


def test_light_table_is_a_distribution():
    sc = parse(GOOD.replace('type = "sphere"\nmaterial = "white"',
                            'type = "sphere"\nmaterial = "white"\nemission = [1, 2, 3]'))
    p = pack_scene(sc)
    lights = p.section("lights")["info"]  # area, pick probability, alias probability, material
    assert lights[:, 1].sum() == pytest.approx(1.0) and lights[-1, 2] == 1.0
    # power = pi * area * mean(Le) per emitting side: quad 1 x 4, sphere 4 pi 0.25 x 2
    pq, ps = math.pi * 1 * 4, math.pi * 4 * math.pi * 0.25 * 2
    assert lights[:, 1] == pytest.approx([pq / (pq + ps), ps / (pq + ps)])


def test_format_documentation_example_renders(device_spec):
    """The example in scenes/README.md parses, and its light faces the room."""
    from clpt.resources import scene_dir
    text = (scene_dir() / "README.md").read_text()
    example = text.split("## Example", 1)[1].split("```toml", 1)[1].split("```", 1)[0]
    sc = clpt.parse_scene(example, source="scenes/README.md")
    light = sc.shapes[0]
    assert np.cross(light.edge_u, light.edge_v)[1] < 0
    img = clpt.render(sc, spp=4, width=16, height=16, device=device_spec)
    assert img.mean() > 0.05
