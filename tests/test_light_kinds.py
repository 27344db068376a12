"""hide_emitters and the TOML format's lights without a surface.

- hide_emitters (Mitsuba 3's integrator option, RenderSettings): camera
  rays see no emission: the environment behind the scene and a lamp seen
  directly are black, every other pixel is the image without it, to the bit.
- TOML [[shapes]] of type point, spot, directional, envmap and constant
  give the Python API's lights (same parameters), render as those do, and
  refuse bad input in one line.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import clpt
from clpt.scene import (Camera, DirectionalLight, EnvironmentLight, Material, PointLight, Quad, RenderSettings,
                        Scene, SceneError, Sphere, SpotLight, parse_scene)

SIZE = 16


def _env_scene(hide):
    cam = Camera(origin=(0, 0, 4), target=(0, 0, 0), fov=40, width=SIZE, height=SIZE)
    ball = Sphere(center=(0, 0, 0), radius=0.6, material=Material(kd=(0.7, 0.5, 0.3)))
    lamp = Quad(corner=(0.8, 0.5, 0), edge_u=(0.3, 0, 0), edge_v=(0, 0.3, 0), material=Material(emission=(5, 5, 5)))
    return Scene(camera=cam, shapes=[ball, lamp, EnvironmentLight(radiance=(0.5, 0.7, 1.0))],
                 render=RenderSettings(hide_emitters=hide))


def test_hide_emitters_blacks_out_what_camera_rays_see_of_emitters(device_spec):
    shown = clpt.Renderer(_env_scene(False), device=device_spec, photons=False).render(16, seed=3, max_depth=4)
    hidden = clpt.Renderer(_env_scene(True), device=device_spec, photons=False).render(16, seed=3, max_depth=4)
    black = (hidden.image == 0).all(axis=2)
    # The sky (the corners) and the lamp (its pixels: radiance 5 shown) are black.
    assert black[0, 0] and black[-1, -1] and black[0, -1]
    assert (shown.image[black] > 0).all()
    lamp = (shown.image >= 4.99).all(axis=2)
    assert lamp.any() and black[lamp].all()
    # Pixels wholly on the ball (its centre) are the same to the bit; the ball's rim mixes in sky samples.
    c = slice(SIZE // 2 - 2, SIZE // 2 + 2)
    assert np.array_equal(hidden.image[c, c], shown.image[c, c]) and hidden.image[c, c].min() > 0
    assert (hidden.image <= shown.image).all()


def test_hide_emitters_from_mitsuba_xml(tmp_path):
    p = tmp_path / "s.xml"
    p.write_text('<scene version="3.0.0"><integrator type="path"><boolean name="hide_emitters" value="true"/>'
                 '</integrator><sensor type="perspective"><film type="hdrfilm"><integer name="width" value="8"/>'
                 '<integer name="height" value="8"/></film></sensor><shape type="sphere"/>'
                 '<emitter type="constant"/></scene>')
    assert clpt.load_scene(p).render.hide_emitters
    p.write_text(p.read_text().replace('value="true"', 'value="false"'))
    assert not clpt.load_scene(p).render.hide_emitters


# --- TOML ---------------------------------------------------------------------------------------------------

HEAD = """
[camera]
origin = [0, 2, 4]
target = [0, 0, 0]
fov = 40
width = 16
height = 16

[[shapes]]
type = "quad"
corner = [-2, 0, 2]
edge_u = [4, 0, 0]
edge_v = [0, 0, -4]
material = "white"
"""


def _toml(light, extra=""):
    return HEAD + extra + "\n[[shapes]]\n" + light


LIGHTS = {
    "point": ('type = "point"\nposition = [0, 1.5, 0]\nintensity = [4, 3, 2]',
              PointLight(position=(0, 1.5, 0), intensity=(4, 3, 2))),
    "spot": ('type = "spot"\nposition = [0, 1.5, 0]\ndirection = [0, -1, 0.2]\nintensity = 6\ncutoff_angle = 35\n'
             'beam_width = 20', SpotLight(position=(0, 1.5, 0), direction=(0, -1, 0.2), intensity=(6, 6, 6),
                                          cutoff_angle=35, beam_width=20)),
    "directional": ('type = "directional"\ndirection = [0.3, -1, 0]\nirradiance = [2, 2, 1]',
                    DirectionalLight(direction=(0.3, -1, 0), irradiance=(2, 2, 1))),
    "constant": ('type = "constant"\nradiance = [0.5, 0.6, 0.7]', EnvironmentLight(radiance=(0.5, 0.6, 0.7))),
}


@pytest.mark.parametrize("kind", sorted(LIGHTS))
def test_toml_lights_are_the_python_apis(device_spec, kind):
    text, light = LIGHTS[kind]
    scene = parse_scene(_toml(text))
    got = scene.shapes[-1]
    assert type(got) is type(light)
    for f in ("position", "intensity", "direction", "irradiance", "radiance", "cutoff_angle", "beam_width"):
        if hasattr(light, f):
            assert np.allclose(np.asarray(getattr(got, f), float), np.asarray(getattr(light, f), float)), f
    api = Scene(camera=scene.camera, shapes=list(scene.shapes[:-1]) + [light])
    a = clpt.Renderer(scene, device=device_spec, photons=False).render(4, seed=1, max_depth=2)
    b = clpt.Renderer(api, device=device_spec, photons=False).render(4, seed=1, max_depth=2)
    assert np.array_equal(a.image, b.image) and a.image.max() > 0


def test_toml_envmap_reads_its_file_scale_and_transform(tmp_path):
    from clpt.image import save_image

    img = np.random.default_rng(2).uniform(0.1, 2.0, (8, 16, 3)).astype(np.float32)
    save_image(tmp_path / "sky.exr", img)
    scene = parse_scene(_toml('type = "envmap"\nfile = "sky.exr"\nscale = 2.5\n[shapes.transform]\nrotate = [0, 90, 0]'),
                        base_dir=tmp_path)
    env = scene.shapes[-1]
    assert isinstance(env, EnvironmentLight) and env.scale == 2.5
    assert np.allclose(env.image, img, rtol=1e-3)
    assert np.allclose(env.rotation(), [[0, 0, 1], [0, 1, 0], [-1, 0, 0]], atol=1e-12)


def test_toml_hide_emitters():
    assert parse_scene(HEAD + "\n[render]\nhide_emitters = true\n" + "[[shapes]]\n" + LIGHTS["point"][0]
                       ).render.hide_emitters


@pytest.mark.parametrize("light, message", [
    ('type = "point"\nposition = [0, 1, 0]\nmaterial = "white"', r"shapes\[1\]\.material: unknown key"),
    ('type = "point"\nposition = [0, 1]', r"shapes\[1\]\.position: must be a list of 3 numbers"),
    ('type = "spot"\ncutoff_angle = 120', r"shapes\[1\]\.cutoff_angle: must be in \(0, 90\] degrees"),
    ('type = "spot"\ncutoff_angle = 20\nbeam_width = 30', r"shapes\[1\]\.beam_width: must be in \[0, cutoff_angle"),
    ('type = "envmap"', r"shapes\[1\]: missing required key 'file'"),
    ('type = "envmap"\nfile = "missing.exr"', r"shapes\[1\]\.file: .*missing\.exr"),
    ('type = "constant"\nradiance = "bright"', r"shapes\[1\]\.radiance: must be"),
    ('type = "directional"\ndirection = [0, 0, 0]', r"direction"),
    ('type = "pointlight"', r"unknown shape type 'pointlight' \(did you mean 'point'\?\)"),
])
def test_toml_light_errors_in_one_line(light, message):
    with pytest.raises(SceneError, match=message) as e:
        parse_scene(_toml(light))
    assert "\n" not in str(e.value)
