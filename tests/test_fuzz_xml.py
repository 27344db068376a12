"""Fuzzing of Mitsuba XML scenes (tests/fuzzing.py has the inputs and the
checks): mutations of the test scenes in tests/data and scenes generated from
a grammar of the supported elements load, or fail with one SceneError line
naming the file, the line and the reason; a sample of those that load render
a finite image. tests/fuzz_long.py runs the same for as long as one likes.
Below them, the defects the fuzzing found, each as a plain test."""

import os
import shutil

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given  # noqa: E402

import clpt  # noqa: E402
import fuzzing  # noqa: E402
from fuzzing import bounded  # noqa: E402


@pytest.fixture(scope="module")
def workspace():
    d = fuzzing.xml_workspace()
    yield d
    shutil.rmtree(d, ignore_errors=True)


def _write(workspace, data, name="fuzz.xml"):
    p = workspace / name
    p.write_bytes(data)
    return p


def test_the_seed_scenes_load(workspace):
    """The mutations start from scenes that load (all but the included BSDFs,
    which are no scene on their own), so what they refuse is the damage."""
    outcomes = [fuzzing.check_scene_file(_write(workspace, s), render=False, need_place=True)
                for s in fuzzing.xml_seeds()]
    assert outcomes == ["accepted", "accepted", "refused", "accepted", "accepted"]


@bounded(300)
@given(data=fuzzing.mutations_of(fuzzing.xml_seeds(), fuzzing.XML_MUTATIONS))
def test_mutated_xml_scenes_load_or_fail_in_one_line(workspace, data):
    """Changed attribute values and bytes, deleted and duplicated spans and
    lines, swapped tags, truncations of the test scenes."""
    fuzzing.check_scene_file(_write(workspace, data), render=False, need_place=True)


@bounded(150)
@given(data=fuzzing.xml_scenes())
def test_generated_xml_scenes_load_or_fail_in_one_line(workspace, data):
    fuzzing.check_scene_file(_write(workspace, data), render=False, need_place=True)


@bounded(15)
@given(data=fuzzing.xml_inputs())
def test_fuzzed_xml_scenes_render_finite(workspace, device_spec, data):
    """Those that load render (4x4, 1 spp) a finite, non-negative image."""
    fuzzing.check_scene_file(_write(workspace, data), render=True, device=device_spec, need_place=True)


# --- the defects found, one by one ----------------------------------------------------------

SCENE = """<scene version="3.0.0">
    <shape type="rectangle">
        <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter>
    </shape>
    {}
</scene>
"""


def _refused(workspace, text, match, name="s.xml"):
    p = _write(workspace, text.encode() if isinstance(text, str) else text, name)
    with pytest.raises(clpt.SceneError, match=match) as e:
        clpt.load_scene(p)
    assert "\n" not in str(e.value) and name in str(e.value)
    return str(e.value)


@pytest.mark.parametrize("element", ['<point name="center" x="0" y="6.5" z=""/>',
                                     '<point name="center" x="0" y="1, 2" z="0"/>'])
def test_an_empty_or_list_coordinate_is_refused_with_its_line(workspace, element):
    text = SCENE.format(f'<shape type="sphere">{element}</shape>')
    _refused(workspace, text, r"s.xml:5: <point name=\"center\">: z must be one number \(got 0\)"
             if 'z=""' in element else r"s.xml:5: .*y must be one number \(got 2\)")


def test_an_empty_rotation_angle_is_refused(workspace):
    text = SCENE.format('<shape type="sphere"><transform name="to_world"><rotate x="1" angle=""/></transform>'
                        '</shape>')
    _refused(workspace, text, r"s.xml:5: <rotate>: angle must be one number")


def test_an_unknown_encoding_is_refused(workspace):
    text = '<?xml version="1.0" encoding="utf1e309"?>\n' + SCENE.format("")
    _refused(workspace, text, r"s.xml:1: cannot decode the file: unknown encoding")


def test_a_singular_mesh_transform_is_refused_at_its_shape(workspace):
    text = SCENE.format('<shape type="obj"><string name="filename" value="cbox/light.obj"/>'
                        '<transform name="to_world"><scale value="0, 1, 1"/></transform></shape>')
    _refused(workspace, text, r"s.xml:5: <shape type=\"obj\">: to_world: a transform must be invertible")


def test_deep_nesting_and_entities_are_refused(workspace):
    deep = "<transform>" * 5000 + "</transform>" * 5000
    _refused(workspace, SCENE.format(deep), r"s.xml:5: <transform>: elements are nested more than 64 deep")
    laughs = ('<?xml version="1.0"?><!DOCTYPE scene [<!ENTITY a "aaaaaaaaaa">'
              + "".join(f'<!ENTITY {c} "{("&" + p + ";") * 10}">' for p, c in zip("abcdefgh", "bcdefghi"))
              + ']>\n<scene version="3.0.0"><string name="x" value="&i;"/></scene>')
    _refused(workspace, laughs, r"s.xml:1: entity declarations \(<!ENTITY a ...>\) are not supported")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_pipe_or_a_huge_file_is_refused_before_reading(workspace):
    fifo = workspace / "pipe.xml"
    os.mkfifo(fifo)
    with pytest.raises(clpt.SceneError, match="pipe.xml: not a regular file"):
        clpt.load_scene(fifo)  # would block for ever if opened for reading as a file
    big = workspace / "big.xml"
    with open(big, "wb") as f:
        f.truncate(clpt.scene.MAX_SCENE_BYTES + 1)
    with pytest.raises(clpt.SceneError, match=r"big.xml: \d+ bytes is too large for a scene file"):
        clpt.load_scene(big)


def test_an_integer_without_a_value_is_refused(workspace):
    """It raised KeyError: 'value' (the missing attribute's SceneError, a
    ValueError, was caught as a bad integer)."""
    _refused(workspace, SCENE.format('<integrator type="path"><integer name="max_depth"/></integrator>'),
             r"s.xml:5: <integer name=\"max_depth\">: missing attribute 'value'")


def test_a_file_included_twice_is_named_where_it_is_included(workspace):
    """The duplicate ids were reported inside the included file, at the
    same place twice, without naming the scene that includes it twice."""
    text = SCENE.format('<include filename="cbox/materials.xml"/>\n<include filename="cbox/materials.xml"/>')
    _refused(workspace, text, r"s.xml:6: <include>: .*cbox/materials.xml is included a second time \(first at "
                              r".*s.xml:5\), so its id 'white' is defined twice")
