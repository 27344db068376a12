"""Fuzzing of the OBJ, PLY and Mitsuba serialized readers (tests/fuzzing.py
has the inputs and the checks): mutations of real files (the test scenes' OBJ
files, a shipped PLY, and small files of every kind the readers take: ASCII,
little- and big-endian binary PLY, OBJ with normals, texture coordinates,
quads and negative indices; serialized files of versions 3 and 4 with every
flag, damaged as bytes or inside their zlib streams) load with finite data,
or fail with one line naming the file, the place (line, byte offset, shape,
vertex or face) and the reason. A sample of those that load render a finite
image. Below them, the defects the fuzzing (and the issue) found, each as a
plain test."""

import os

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given  # noqa: E402

import clpt  # noqa: E402
import fuzzing  # noqa: E402
from clpt.meshio import MeshError, read_mesh  # noqa: E402
from fuzzing import bounded  # noqa: E402


@pytest.mark.parametrize("fmt", ["obj", "ply"])
def test_the_seed_meshes_load(tmp_path, fmt):
    """The mutations start from files that load, so what they refuse is the
    damage. (The ASCII PLY with an empty extra element was refused: the
    reader took the next line as a record of it.)"""
    for data in fuzzing.mesh_seeds()[fmt]:
        (tmp_path / f"seed.{fmt}").write_bytes(data)
        assert fuzzing.check_mesh_file(tmp_path / f"seed.{fmt}", render=False) == "accepted"


@pytest.mark.parametrize("fmt", ["obj", "ply", "serialized"])
def test_fuzzed_meshes_load_or_fail_in_one_line(tmp_path_factory, fmt):
    reader, d = fuzzing.READERS[fmt], tmp_path_factory.mktemp("mesh")

    @bounded(300)
    @given(data=reader.inputs())
    def run(data):
        p = d / reader.filename
        p.write_bytes(data)
        reader.check(p, render=False)

    run()


@bounded(300)
@given(data=fuzzing.mesh_inputs("obj"))
def test_a_regular_obj_file_reads_the_same_at_once_as_line_by_line(data):
    """The whole-file parse (taken for regular files only) agrees array for
    array with the line-by-line one, which is the reference (and names the
    line of any fault)."""
    from clpt.meshio import _obj_arrays, _obj_lines

    fast = _obj_arrays(data)
    if fast is not None:
        slow = _obj_lines(data, "fuzz.obj")
        for a, b in zip(fast, slow):
            assert (a is None and b is None) or np.array_equal(a, b)


@pytest.mark.parametrize("fmt", ["obj", "ply", "serialized"])
def test_fuzzed_meshes_render_finite(tmp_path_factory, device_spec, fmt):
    """Serialized inputs edited inside their streams: byte damage rarely gets past zlib."""
    reader, d = fuzzing.READERS[fmt], tmp_path_factory.mktemp("mesh")

    @bounded(8 if fmt == "serialized" else 6)
    @given(data=fuzzing.serialized_edits() if fmt == "serialized" else reader.inputs())
    def run(data):
        p = d / reader.filename
        p.write_bytes(data)
        reader.check(p, render=True, device=device_spec)

    run()


def test_the_serialized_seeds_load(tmp_path):
    """Every shape of every seed loads (so what the mutations refuse is the
    damage), and a shape_index past the last is refused in one line."""
    for shapes, version in fuzzing.serialized_shapes():
        p = tmp_path / "seed.serialized"
        p.write_bytes(fuzzing.assemble_serialized(list(shapes), version))
        for k in range(len(shapes)):
            assert fuzzing.check_mesh_file(p, render=False, shape_index=k) == "accepted"
        assert fuzzing.check_mesh_file(p, render=False, shape_index=len(shapes)) == "refused"


# --- the defects found, one by one ----------------------------------------------------------

TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
PLY_HEAD = ("ply\nformat {} 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n"
            "element face {}\nproperty list uchar int vertex_indices\nend_header\n")


def _refused(path, data, match):
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    with pytest.raises(MeshError, match=match) as e:
        read_mesh(path)
    assert "\n" not in str(e.value) and str(path) in str(e.value)


def test_an_obj_file_that_is_not_utf8_is_read_without_guessing_its_encoding(tmp_path):
    """trimesh guessed the encoding with a package that was not installed
    ("No module named 'charset_normalizer'"); OBJ syntax is ASCII."""
    p = tmp_path / "m.obj"
    p.write_bytes(b"# caf\xe9 \xff\xfe\n" + TRIANGLE.encode() + b"usemtl \xe9t\xe9\nf 1 2 3\n")
    v, t, _ = read_mesh(p)
    assert len(t) == 1 and v.shape == (3, 3)
    _refused(p, TRIANGLE + "f 1 2 3\nf 1 2 x\n", r"m.obj:5: bad vertex index 'x' in face corner 'x'")
    _refused(p, TRIANGLE + "f 1 2 4\n", r"m.obj:4: vertex 4 does not exist \(the file has 3 vertices\)")
    _refused(p, TRIANGLE + "f 1 2 99999999999999999999999\n", r"m.obj:4: vertex index 99999999999999999999999 "
             "does not exist")
    _refused(p, "v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"m.obj:1: a vertex is not finite \(nan\)")
    _refused(p, TRIANGLE + "f -4 1 2\n", r"m.obj:4: vertex index -4 does not exist")
    _refused(p, TRIANGLE + "f 1 2 3\nf ", r"m.obj:5: a face needs at least 3 vertices \(got 0\)")  # was IndexError


def test_a_damaged_ply_in_a_toml_scene_is_reported_as_the_file_not_the_transform(tmp_path):
    """A ragged array from a damaged PLY was reported as the mesh's transform
    ("shapes[1].transform: setting an array element with a sequence.")."""
    (tmp_path / "m.ply").write_text(PLY_HEAD.format("ascii", 3, 1) + "0 0 0\n1 0 0\n0 1\n3 0 1 2\n")
    (tmp_path / "s.toml").write_text('[camera]\norigin = [0, 0, 3]\ntarget = [0, 0, 0]\nfov = 40\n'
                                     '[[shapes]]\ntype = "mesh"\nfile = "m.ply"\nmaterial = "white"\nemission = 1\n'
                                     'transform = { scale = 2 }\n')
    with pytest.raises(clpt.SceneError, match=r"shapes\[0\]\.file: .*m.ply:12: a vertex has 2 values, the header "
                                              r"says 3") as e:
        clpt.load_scene(tmp_path / "s.toml")
    assert "transform" not in str(e.value)


@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii"])
def test_counts_beyond_the_file_are_refused_before_allocating(tmp_path, fmt):
    """A header that claims 10^12 vertices is refused at the byte (or line)
    where the file ends, without allocating for them."""
    body = np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes() if fmt != "ascii" else b"0 0 0\n1 0 0\n0 1 0\n"
    match = (rf"m.ply: byte {len(PLY_HEAD.format(fmt, 10 ** 12, 1))}: the file ends inside the vertex element "
             r"\(1000000000000 records of 12 bytes"
             if fmt != "ascii" else r"m.ply:12: the file ends after 3 of its 1000000000000 vertex records")
    _refused(tmp_path / "m.ply", PLY_HEAD.format(fmt, 10 ** 12, 1).encode() + body, match)


def test_ply_faces_are_checked_where_they_are(tmp_path):
    p = tmp_path / "m.ply"
    verts = np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes()
    face = np.zeros(2, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, [[0, 1, 2], [0, 1, 7]]
    start = len(PLY_HEAD.format("binary_little_endian", 3, 2)) + len(verts)
    _refused(p, PLY_HEAD.format("binary_little_endian", 3, 2).encode() + verts + face.tobytes(),
             rf"m.ply: byte {start + 13}: face 1 has vertex index 7, out of range \(the file has 3 vertices\)")
    face["n"][1] = 2
    _refused(p, PLY_HEAD.format("binary_little_endian", 3, 2).encode() + verts + face.tobytes()[:13 + 9],
             rf"m.ply: byte {start + 13}: face 1 has 2 vertices \(a polygon needs at least 3\)")
    _refused(p, PLY_HEAD.format("ascii", 3, 1).replace("property float z\n", "property float z\nproperty float z\n")
             + "0 0 0 0\n", r"m.ply:7: header: property 'z' is given twice")


def test_a_pipe_or_a_mesh_too_large_for_memory_is_refused_before_reading(tmp_path, monkeypatch):
    if hasattr(os, "mkfifo"):
        os.mkfifo(tmp_path / "pipe.obj")
        with pytest.raises(MeshError, match="pipe.obj: not a regular file"):
            read_mesh(tmp_path / "pipe.obj")
    p = tmp_path / "m.obj"
    p.write_text(TRIANGLE + "f 1 2 3\n")
    monkeypatch.setattr("clpt.hostio.available_host_bytes", lambda: 50)
    _refused(p, TRIANGLE + "f 1 2 3\n", r"m.obj: a 0.0 GiB mesh file needs about 0.0 GiB of memory to read and "
             r"0.0 GiB are available; too large")


def test_a_big_endian_ply_reads_as_its_little_endian_twin(tmp_path):
    """The seed written big-endian from a shipped PLY gives its arrays exactly."""
    *_, big, little = fuzzing.mesh_seeds()["ply"]
    (tmp_path / "b.ply").write_bytes(big)
    (tmp_path / "l.ply").write_bytes(little)
    for a, b in zip(read_mesh(tmp_path / "b.ply"), read_mesh(tmp_path / "l.ply")):
        assert np.array_equal(a, b)


def test_a_serialized_offset_past_2_63_is_refused_not_wrapped(tmp_path):
    """Found by tests/fuzz_long.py: offsets of 2^63 and more were read as
    negative int64s and passed the range check (struct.error, ValueError)."""
    shapes, version = fuzzing.serialized_shapes()[0]
    p = tmp_path / "m.serialized"
    for offset in (2 ** 63, 2 ** 64 - 1):
        p.write_bytes(fuzzing.assemble_serialized(list(shapes), version, offsets=[0, offset, 0]))
        with pytest.raises(MeshError, match=rf"m.serialized: byte \d+: shape 1 starts at byte {offset}, beyond the "
                                            r"shapes' data"):
            read_mesh(p, shape_index=1)
