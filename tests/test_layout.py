"""The layout is defined once (clpt/layout.py): the launch structs the kernels
read agree with the numpy dtypes the host fills, on the device; the kernels
read the scene's records only through the generated field constants; and a
record's fields can be reordered there without changing an image."""

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

import clpt
from clpt import layout, program
from clpt.layout import Record, Rows
from clpt.resources import kernel_dir


@pytest.mark.parametrize("double", [False, True])
def test_launch_records_match_the_device(probes, double):
    probe = probes(lanes=1, double=double)
    records = layout.launch_records()
    n = sum(1 + len(r.fields) for r in records)
    out = np.zeros(n + 1, dtype=np.uint32)
    ctx, q = probe.dctx.context, probe.dctx.queue
    buf = cl.Buffer(ctx, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=out)
    cl.Kernel(probe.program, "probe_record_layout")(q, (1,), None, buf)
    cl.enqueue_copy(q, out, buf)
    q.finish()
    assert out[n] == 0  # exactly n values written
    expect = []
    for r in records:
        dt = r.dtype(double)
        expect.append(dt.itemsize)
        expect += [dt.fields[f][1] for f, _ in r.fields]
    np.testing.assert_array_equal(out[:n], expect)


def test_dtype_follows_opencl_alignment():
    r = Record("Mixed", (("a", "uint"), ("b", "float4"), ("c", "real"), ("d", "real3"), ("e", "int")))
    dt = r.dtype(double=True)
    assert r.offsets(double=True) == {"a": 0, "b": 16, "c": 32, "d": 64, "e": 96}
    assert dt.itemsize == 128  # aligned to its widest member (double3: 32 bytes)
    assert r.offsets(double=False) == {"a": 0, "b": 16, "c": 32, "d": 48, "e": 64}
    assert r.size(double=False) == 80
    outer = Record("Outer", (("x", "uint"), ("m", r), ("y", "uint")))
    assert outer.offsets(double=False) == {"x": 0, "m": 16, "y": 96}  # a struct aligns to its widest member
    with pytest.raises(ValueError, match="unsupported field type"):
        Record("Bad", (("x", "real5"),)).dtype()


def test_rows_are_filled_and_read_by_name():
    r = Rows("thing", "THING", (("a", "real4"), ("b", "real8"), ("c", "real4")))
    assert r.stride == 4 and r.row("b") == 1 and r.row("c") == 3
    recs = r.zeros(2)
    recs["b"][1] = np.arange(8)
    recs["c"][0] = (1, 2, 3, 4)
    rows = Rows.rows(recs)
    assert rows.shape == (8, 4) and rows[5].tolist() == [0, 1, 2, 3] and rows[3].tolist() == [1, 2, 3, 4]
    assert r.view(rows)["b"][1].tolist() == list(range(8))
    assert "#define THING_STRIDE 4" in r.c_source() and "#define THING_C 3" in r.c_source()


def test_generated_c_is_in_every_build():
    src = program.stitch(["path.h", "trace.cl"])
    assert "#define PLANAR_STRIDE 4" in src and "#define BVH_COUNT 14" in src
    assert "} TraceLaunch;" in src and "    SceneInfo scene;" in src
    assert src.index("<clpt/layout.py>") < src.index('"kernels/scene.h"')
    assert layout.PLANAR.stride == 4 and layout.BVH_NODE.stride == 16 and layout.BVH_LEAF.stride == 16
    assert f"#define BVHL_WIDTH {layout.BVH_LEAF_WIDTH}" in src


# The functions through which kernels read scene rows: (name, index of the offset argument).
ACCESSORS = {"scene_rec": 1, "bvh_row": 2, "bvh_lrow": 2}


def _calls(text, name):
    """The argument lists of every call of name in text."""
    for m in re.finditer(rf"\b{name}\(", text):
        depth, i, args, start = 1, m.end(), [], m.end()
        while depth:
            c = text[i]
            if c in "([":
                depth += 1
            elif c in ")]":
                depth -= 1
            elif c == "," and depth == 1:
                args.append(text[start:i])
                start = i + 1
            i += 1
        args.append(text[start:i - 1])
        yield m.start(), [a.strip() for a in args]


def test_no_record_is_read_at_a_literal_offset():
    """A field is read at its generated constant (r + LIGHT_INFO), never at a
    number (r + 4): reordering a record in clpt/layout.py would silently
    read the wrong row."""
    bad = []
    files = sorted(kernel_dir().glob("*.[ch]*")) + sorted((Path(__file__).parent / "kernels").glob("*.cl"))
    assert len(files) > 10
    for path in files:
        text = path.read_text()
        for name, k in ACCESSORS.items():
            for pos, args in _calls(text, name):
                if len(args) > k and re.search(r"(?<![\w.])\d+u?\b", args[k]):
                    bad.append(f"{path.name}:{text.count(chr(10), 0, pos) + 1}: {name}({', '.join(args)})")
    assert bad == []


def test_the_literal_offset_check_catches_one():
    text = "real4 info = scene_rec(sc, r + 4); breal8 c = bvh_row(sc, node, 7); x = scene_rec(sc, r + LIGHT_N);"
    found = [(n, a[k]) for n, k in ACCESSORS.items() for _, a in _calls(text, n)
             if re.search(r"(?<![\w.])\d+u?\b", a[k])]
    assert found == [("scene_rec", "r + 4"), ("bvh_row", "7")]


def _reversed(r):
    fields = tuple((f, _reversed(t) if isinstance(t, Record) else t) for f, t in reversed(r.fields))
    return replace(r, fields=fields)


@pytest.mark.parametrize("scene", ["cornell_box_caustics", "mesh_lights", "fig07_caustics_from_three_lights",
                                   str(Path(__file__).parent / "data" / "plates.xml"),
                                   str(Path(__file__).parent / "data" / "plastic_spheres.xml"),
                                   str(Path(__file__).parent / "data" / "rough_glass.xml"),
                                   str(Path(__file__).parent / "data" / "cbox_textured.xml"),
                                   str(Path(__file__).parent / "data" / "cbox_textured_lights.xml"),
                                   str(Path(__file__).parent / "data" / "env_spheres.xml"),
                                   str(Path(__file__).parent / "data" / "brushed.xml")])
def test_reordered_fields_render_the_same_image(device_spec, monkeypatch, scene):
    """Every record with its fields in reverse order, scene rows and launch
    structs alike: the host fills by name and the kernels read by name, so
    the image is the same to the bit (the BVH, mesh lights, sphere,
    triangle and quad lights, photon mapping, rough conductors, plastics,
    rough dielectrics, textures, textured lights, an environment map and
    anisotropic lobes' tangents included)."""
    ref = clpt.Renderer(scene, device=device_spec, aux=True).render(2, width=16, height=16)
    for name in ("MATERIAL", "SPHERE", "PLANAR", "PLANE", "LIGHT", "CAUSTIC", "BVH_NODE", "BVH_LEAF", "NORMALS",
                 "LIGHT_TRI", "TEXTURE_SLOTS", "TEXTURE", "UV", "TANGENT", "ENV_TEXEL", "ENV_ALIAS", "SCENE_INFO", "CAMERA",
                 "PHOTON_LOOKUP", "TRACE_LAUNCH", "PHOTON_LAUNCH"):
        monkeypatch.setattr(layout, name, _reversed(getattr(layout, name)))
    assert "#define MAT_ANISO 0" in layout.c_source()  # the last field first
    r = clpt.Renderer(scene, device=device_spec, aux=True)
    assert r.packed.count("nodes") > 0 or scene != "mesh_lights"
    got = r.render(2, width=16, height=16)
    assert np.array_equal(got.image, ref.image) and np.array_equal(got.lum_var, ref.lum_var)
    for k in ref.aux:
        assert np.array_equal(got.aux[k], ref.aux[k]), k
