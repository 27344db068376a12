"""Scene-specialized kernels: the feature description, the build cache, and
that specialization changes nothing in the image."""

import re
from dataclasses import replace

import numpy as np
import pytest

import clpt
from clpt.features import Features, scene_features
from clpt.pack import pack_scene
from clpt.resources import kernel_dir, shipped_scenes


def test_features_follow_the_scene():
    f = scene_features(pack_scene(clpt.load_scene("cornell_box")))
    assert (f.quads, f.spheres, f.triangles, f.planes) == (True, False, False, False)
    assert (f.phong, f.mirror, f.glass, f.sphere_lights, f.triangle_lights) == (False,) * 5
    assert f.counts == (4, 0, 18, 0, 0, 1, 0, 0) and not f.photons and not f.bvh and not f.mesh_lights
    g = scene_features(pack_scene(clpt.load_scene("cornell_box_caustics")))
    assert g.spheres and g.mirror and g.glass and not g.phong and g.photons
    assert hash(f) != hash(g) and f.options() != g.options()
    assert f.options() == sorted(f.options())  # the options string doubles as a cache key
    assert "CLPT_NUM_QUADS=18" in " ".join(f.options())
    assert "specialized" in f.describe() and "quads" in f.describe()
    generic = scene_features(pack_scene(clpt.load_scene("cornell_box")), mode="generic")
    assert generic == Features(mode="generic", photons=False, textures=False, anisotropy=False,
                               textured_emitters=False, textured_spots=False)
    assert "CLPT_NUM_QUADS" not in " ".join(generic.options())


def test_a_material_change_rebuilds_and_a_repeat_hits_the_cache(device_spec, tmp_path, monkeypatch):
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path))
    scene = clpt.load_scene("cornell_box")
    first = clpt.Renderer(scene, device=device_spec)
    again = clpt.Renderer(scene, device=device_spec)
    assert not first.states[0].build.cache_hit and again.states[0].build.cache_hit
    assert again.states[0].build.seconds < 0.5
    # The tall box turns from white to glass: a new feature (refraction), a new build.
    glassy = clpt.load_scene("cornell_box")
    glassy.shapes = [replace(s, material="glass") if s.name.startswith("large-box") else s for s in glassy.shapes]
    g = clpt.Renderer(glassy, device=device_spec)
    assert g.features.glass and not first.features.glass
    assert not g.states[0].build.cache_hit
    # The glass box is a caustic caster: its photon kernels are a program of their own.
    assert len(list((tmp_path / "kernels").glob("*.bin"))) == 3
    assert clpt.clear_cache() == 3 and not list(tmp_path.glob("kernels/*.bin"))


@pytest.mark.parametrize("name", shipped_scenes())
def test_specialized_and_generic_images_are_identical(device_spec, name):
    """Same code, same IEEE operations in the same order, whether counts are
    constants or read at run time: the same bits."""
    imgs = [clpt.render(name, spp=2, width=16, height=16, device=device_spec, kernel=k)
            for k in ("specialized", "generic")]
    assert np.array_equal(imgs[0], imgs[1])


VEC3 = re.compile(r"\b(?:real|float|double|half|u?char|u?short|u?int|u?long)3\b")
FUNCTION = re.compile(r"^(?!#|typedef\b)(?P<head>[A-Za-z_][\w ]*?)\b(?P<name>\w+)\((?P<params>[^)]*)\)\s*[{;]", re.M)


def test_functions_with_three_component_vectors_are_always_inlined():
    """Intel's CPU runtime hands a 3-component vector (parameter, result or
    pointer) to a function it leaves out of line with the wrong stride across
    a group's work-items: the generic build of mesh_glass_knot walked its BVH
    with shuffled rays (kernels/simd.h INLINE_VEC3). Whether a plain `inline`
    function stays out of line is the compiler's choice, so every such
    function is declared INLINE_VEC3."""
    found = {}
    for path in sorted(kernel_dir().iterdir()):
        for m in FUNCTION.finditer(path.read_text()):
            if "__kernel" in m["head"] or not VEC3.search(m["head"] + " " + m["params"]):
                continue
            found[m["name"]] = m["head"].split()[0]
    assert {"bvh_walk1", "bvh_leaf1", "photon_gather_one", "grid_lower_corner"} <= set(found)
    assert {name for name, how in found.items() if how != "INLINE_VEC3"} == set()


def test_feature_buffers_only_with_the_filter(device_spec):
    """No feature buffers or filter kernel unless asked for; with them, the
    image itself does not change."""
    plain = clpt.Renderer("cornell_box", device=device_spec)
    res = plain.render(2, width=8, height=8)
    assert not plain.features.aux and plain.states[0].aux is None and plain.states[0].filter is None
    assert res.aux is None and res.filtered is None
    # A filter asked for at render time renders on a twin with the feature buffers.
    filtered = plain.render(2, width=8, height=8, filter=clpt.FilterSettings())
    assert filtered.filtered is not None and filtered.aux is not None and not plain.features.aux
    assert np.array_equal(filtered.image, res.image)
    aux = clpt.Renderer("cornell_box", device=device_spec, aux=True)
    res2 = aux.render(2, width=8, height=8)
    assert aux.features.aux and "-DCLPT_AUX=1" in aux.features.options()
    assert np.array_equal(res.image, res2.image)
    assert set(res2.aux) == {"normal", "albedo", "depth", "emission", "emitter", "caustic", "caustic_var",
                             "caustic_sq"}


def _function_lengths():
    """(lines, file, name) of every function defined in kernels/."""
    out = []
    for path in sorted(kernel_dir().iterdir()):
        lines = path.read_text().split("\n")
        i = 0
        while i < len(lines):
            m = re.match(r"^(?!#|typedef\b|//|\s)[\w ]+?\b(\w+)\(", lines[i])
            if not m or lines[i].rstrip().endswith(";"):
                i += 1
                continue
            j, depth, opened = i, 0, False
            while j < len(lines):
                depth += lines[j].count("{") - lines[j].count("}")
                opened = opened or "{" in lines[j]
                if opened and depth == 0:
                    break
                j += 1
            out.append((j - i + 1, path.name, m[1]))
            i = j + 1
    return out


def test_kernel_functions_stay_readable():
    """trace_paths is the loop over the path events (kernels/path.h), at most
    150 lines; every other kernel function at most 100."""
    lengths = {name: n for n, _, name in _function_lengths()}
    assert {"trace_paths", "path_emission", "bsdf_sample", "light_sample", "scene_walk"} <= set(lengths)
    assert lengths["trace_paths"] <= 150
    assert {name: n for name, n in lengths.items() if n > 100 and name != "trace_paths"} == {}
