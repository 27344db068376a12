"""Mesh loading (OBJ, PLY), transforms, degenerate triangles, TOML meshes."""

import warnings

import numpy as np
import pytest

import clpt
from clpt.meshio import MeshError, compose, read_mesh, transform_mesh
from meshgen import grid, shared_mesh, uv_sphere, write_obj, write_ply

BUNNY = shared_mesh("bunny.ply")


@pytest.mark.parametrize("fmt", ["obj", "ply", "ply-ascii"])
@pytest.mark.parametrize("with_normals", [True, False])
def test_read_roundtrip(tmp_path, fmt, with_normals):
    v, t, n = uv_sphere(radius=0.5, n_theta=6, n_phi=8)
    path = tmp_path / f"s.{fmt.split('-')[0]}"
    if fmt == "obj":
        write_obj(path, v, t, n if with_normals else None)
    else:
        write_ply(path, v, t, n if with_normals else None, binary=fmt == "ply")
    v2, t2, n2 = read_mesh(path)
    assert v2.dtype == np.float64 and t2.dtype == np.int64
    # Same triangles, vertex for vertex (OBJ readers may renumber vertices).
    tol = 1e-12 if fmt == "obj" else 1e-6
    np.testing.assert_allclose(v2[t2], v[t], atol=tol)
    if with_normals:
        assert n2 is not None
        np.testing.assert_allclose(n2[t2], n[t], atol=1e-6)
        np.testing.assert_allclose(np.linalg.norm(n2, axis=1), 1.0, atol=1e-12)
    else:
        assert n2 is None


def test_degenerate_dropped_with_one_warning(tmp_path):
    v, t = grid(2)
    bad = np.array([[0, 0, 1], [0, 1, 2]])  # repeated index; collinear (0, 1, 2 lie on one grid line)
    path = tmp_path / "g.obj"
    write_obj(path, v, np.concatenate([t, bad]))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        v2, t2, _ = read_mesh(path)
    msgs = [str(x.message) for x in w]
    assert len(msgs) == 1 and "dropped 2 degenerate triangles" in msgs[0] and "g.obj" in msgs[0]
    assert len(t2) == len(t)


def test_transform_normals_inverse_transpose():
    v, t, n = uv_sphere(n_theta=8, n_phi=16)
    m = compose(translate=(1, 2, 3), rotate=(10, 20, 30), scale=(2.0, 0.5, 1.0))
    v2, n2 = transform_mesh(v, n, m)
    np.testing.assert_allclose(v2, v @ m[:3, :3].T + m[:3, 3])
    # A normal stays perpendicular to every edge of the transformed surface.
    e = v2[t[:, 1]] - v2[t[:, 0]]
    fn = np.cross(v2[t[:, 1]] - v2[t[:, 0]], v2[t[:, 2]] - v2[t[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    assert np.abs(np.einsum("ij,ij->i", fn, e)).max() < 1e-9
    # For the sphere, the exact normal of the ellipsoid at each vertex.
    exact = (v2 - m[:3, 3]) @ np.linalg.inv(m[:3, :3] @ m[:3, :3].T).T
    exact /= np.linalg.norm(exact, axis=1, keepdims=True)
    np.testing.assert_allclose(n2, exact, atol=1e-12)
    with pytest.raises(ValueError, match="invertible"):
        transform_mesh(v, n, np.diag([1.0, 0.0, 1.0, 1.0]))


@pytest.mark.parametrize("content,expect", [
    (None, "no such mesh file"),
    ("this is not a ply file", "cannot read the PLY file"),
])
def test_bad_files(tmp_path, content, expect):
    path = tmp_path / "m.ply"
    if content is not None:
        path.write_text(content)
    with pytest.raises(MeshError, match=expect) as e:
        read_mesh(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)


def test_bad_obj_and_format(tmp_path):
    p = tmp_path / "m.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    with pytest.raises(MeshError, match="m.obj"):
        read_mesh(p)
    with pytest.raises(MeshError, match="unsupported mesh format"):
        read_mesh(tmp_path / "m.stl")


def test_mesh_shape_checks():
    v, t, n = uv_sphere(n_theta=4, n_phi=6)
    m = clpt.Mesh(vertices=v, triangles=t, normals=n)
    assert m.vertices.shape == v.shape and not m.vertices.flags.writeable
    heron = sum(0.5 * np.linalg.norm(np.cross(v[b] - v[a], v[c] - v[a])) for a, b, c in t)
    assert m.area() == pytest.approx(heron, rel=1e-12) and m.area() < 4 * np.pi
    lo, hi = m.points().min(0), m.points().max(0)
    np.testing.assert_array_equal(lo, v.min(0))
    np.testing.assert_array_equal(hi, v.max(0))
    with pytest.raises(clpt.SceneError, match="out of range"):
        clpt.Mesh(vertices=v, triangles=t + len(v))
    with pytest.raises(clpt.SceneError, match="normals must be one per vertex"):
        clpt.Mesh(vertices=v, triangles=t, normals=n[:3])


def test_toml_mesh_relative_path_and_transform(tmp_path):
    v, t, n = uv_sphere(radius=1.0, n_theta=6, n_phi=8)
    (tmp_path / "meshes").mkdir()
    write_obj(tmp_path / "meshes" / "ball.obj", v, t, n)
    toml = """
[camera]
origin = [0, 0, 5]
target = [0, 0, 0]
fov = 40
[[shapes]]
type = "mesh"
file = "meshes/ball.obj"
material = "white"
emission = 1
transform = { translate = [1, 0, 0], scale = 0.5 }
"""
    (tmp_path / "s.toml").write_text(toml)
    s = clpt.load_scene(tmp_path / "s.toml")
    mesh = s.shapes[0]
    assert isinstance(mesh, clpt.Mesh)
    np.testing.assert_allclose(mesh.vertices[mesh.triangles], 0.5 * v[t] + [1, 0, 0], atol=1e-12)
    (tmp_path / "bad.toml").write_text(toml.replace("meshes/ball.obj", "meshes/nope.obj"))
    with pytest.raises(clpt.SceneError, match=r"bad.toml: shapes\[0\].file: .*nope.obj: no such mesh file"):
        clpt.load_scene(tmp_path / "bad.toml")
    (tmp_path / "bad2.toml").write_text(toml.replace("scale = 0.5", "scale = 0.5, matrix = []"))
    with pytest.raises(clpt.SceneError, match="either matrix or translate"):
        clpt.load_scene(tmp_path / "bad2.toml")
    m = [[2, 0, 0, 1], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]]
    (tmp_path / "m.toml").write_text(toml.replace("{ translate = [1, 0, 0], scale = 0.5 }", f"{{ matrix = {m} }}"))
    mesh = clpt.load_scene(tmp_path / "m.toml").shapes[0]
    np.testing.assert_allclose(mesh.vertices[mesh.triangles], 2 * v[t] + [1, 0, 0], atol=1e-12)


@pytest.mark.skipif(BUNNY is None, reason="../shared/meshes/bunny.ply is absent (test data outside the repo)")
def test_bunny_loads():
    v, t, n = read_mesh(BUNNY)
    assert len(t) == 69451 and len(v) == 35947 and n is None


# --- mesh lights ------------------------------------------------------------------

def _bumpy_light(n=5, seed=2):
    """A height-field mesh above y = 1 facing down (-y), with triangles of
    uneven sizes (jittered grid)."""
    rng = np.random.default_rng(seed)
    v, t = grid(n, size=1.2)
    v[:, :2] += rng.uniform(-0.08, 0.08, (len(v), 2)) * (np.abs(v[:, :2]) < 0.59)
    # grid() lies in z = 0 facing +z: map (x, y, z) -> (x, 1 + 0.1 z-bump, y), facing -y.
    bump = 0.05 * np.sin(3 * v[:, 0]) * np.cos(2 * v[:, 1])
    verts = np.column_stack([v[:, 0], 1.0 + bump, v[:, 1]])
    return verts, t


def test_alias_table_is_exact():
    from clpt.pack import alias_table
    w = np.random.default_rng(0).uniform(0.01, 5, 37)
    prob, alias = alias_table(w)
    implied = prob / len(w)
    np.add.at(implied, alias, (1 - prob) / len(w))
    np.testing.assert_allclose(implied, w / w.sum(), rtol=1e-12)


@pytest.mark.parametrize("x", [(0.0, 0.0, 0.0), (0.9, -0.2, 0.4)])
def test_mesh_light_irradiance(probes, x):
    from test_shapes import estimate_irradiance, lambert_irradiance
    verts, tris = _bumpy_light()
    n = np.array([0.0, 1.0, 0.0])
    x = np.array(x)
    ref = sum(lambert_irradiance(x, n, verts[t]) for t in tris)
    cam = clpt.Camera(origin=(0, -2, 3))
    mesh = clpt.Scene(camera=cam, shapes=[clpt.Mesh(vertices=verts, triangles=tris, material="black",
                                                    emission=(1, 1, 1))])
    by_hand = clpt.Scene(camera=cam, shapes=[clpt.Triangle(vertices=tuple(map(tuple, verts[t])), material="black",
                                                           emission=(1, 1, 1)) for t in tris])
    for scene in (mesh, by_hand):
        e, sigma, _, _ = estimate_irradiance(probes(8), scene, x, n)
        assert abs(e - ref) < 5 * sigma + 1e-6, f"E = {e:.5f} +- {sigma:.5f}, analytic {ref:.5f}"


def test_mesh_light_renders_like_hand_built_triangles(device_spec):
    verts, tris = _bumpy_light(4)
    floor = clpt.Quad(corner=(-2, 0, -2), edge_u=(0, 0, 4), edge_v=(4, 0, 0), material=clpt.Material(kd=(0.7,) * 3))
    cam = clpt.Camera(origin=(0.0, 0.6, 2.2), target=(0.0, 0.3, 0.0), fov=60, width=24, height=24)
    lamp = dict(material=clpt.Material(kd=(0.3,) * 3), emission=(4, 4, 4))
    mesh = clpt.Scene(camera=cam, shapes=[floor, clpt.Mesh(vertices=verts, triangles=tris, **lamp)])
    by_hand = clpt.Scene(camera=cam, shapes=[floor] + [clpt.Triangle(vertices=tuple(map(tuple, verts[t])), **lamp)
                                                       for t in tris])
    a = clpt.Renderer(mesh, device=device_spec).render(128, max_depth=3, seed=1)
    b = clpt.Renderer(by_hand, device=device_spec).render(128, max_depth=3, seed=2)
    assert a.features.mesh_lights and not b.features.mesh_lights
    va, vb = a.lum_var / a.sample_count, b.lum_var / b.sample_count
    la = a.image @ np.array([0.2126, 0.7152, 0.0722])
    lb = b.image @ np.array([0.2126, 0.7152, 0.0722])
    z = (la - lb) / np.sqrt(va + vb + 1e-12)
    assert np.abs(z).max() < 6
    # The images' means agree within their noise.
    sigma = np.sqrt((va + vb).sum()) / la.size
    assert abs(la.mean() - lb.mean()) < 5 * sigma
    assert la.mean() > 0.1


@pytest.mark.parametrize("fmt", ["obj", "ply"])
@pytest.mark.parametrize("faces", ["quads", "pentagons", "mixed"])
def test_polygons_are_fan_triangulated(tmp_path, fmt, faces):
    """Quads and other k-gons (a file of them only, or mixed with triangles)
    become k - 2 triangles with the polygon's winding that cover its area:
    fanned from its first vertex, in order, for a file of k-gons only."""
    # A convex pentagon and a unit square in the plane z = 0, counter-clockwise.
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [3, 0, 0], [3.3, 0.8, 0],
                  [2.5, 1.4, 0], [1.8, 0.8, 0]], dtype=float)
    polys = {"quads": [[0, 1, 2, 3]], "pentagons": [[4, 5, 6, 7, 8]],
             "mixed": [[0, 1, 2], [4, 5, 6, 7, 8], [0, 2, 3]]}[faces]
    p = tmp_path / f"m.{fmt}"
    if fmt == "obj":
        p.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in v)
                     + "".join("f " + " ".join(str(i + 1) for i in f) + "\n" for f in polys))
    else:
        p.write_text("ply\nformat ascii 1.0\n" f"element vertex {len(v)}\n"
                     "property float x\nproperty float y\nproperty float z\n"
                     f"element face {len(polys)}\nproperty list uchar int vertex_indices\nend_header\n"
                     + "".join(f"{x} {y} {z}\n" for x, y, z in v)
                     + "".join(f"{len(f)} " + " ".join(map(str, f)) + "\n" for f in polys))
    vr, t, _ = read_mesh(p)
    expect = [[f[0], f[i], f[i + 1]] for f in polys for i in range(1, len(f) - 1)]
    if faces != "mixed":  # ours: in order, from the first vertex
        # The OBJ reader keeps only the vertices faces use: compare positions.
        np.testing.assert_allclose(vr[t], v[np.array(expect)], rtol=1e-6)  # PLY: float32
    else:  # a mix of sizes: compared as sets of triangles (whatever their order and rotation)
        def canon(tris):
            tris = np.round(np.asarray(tris, dtype=float), 5)
            out = []
            for tr in tris:
                k = min(range(3), key=lambda i: tuple(tr[i]))
                out.append(tuple(map(tuple, np.roll(tr, -k, axis=0))))
            return sorted(out)
        assert canon(vr[t]) == canon(v[np.array(expect)])
    e1, e2 = vr[t[:, 1]] - vr[t[:, 0]], vr[t[:, 2]] - vr[t[:, 0]]
    cz = np.cross(e1, e2)[:, 2]
    assert (cz > 0).all()  # the polygons' winding (+z) is kept
    shoelace = sum(0.5 * abs(sum(v[f[i], 0] * v[f[(i + 1) % len(f)], 1] - v[f[(i + 1) % len(f)], 0] * v[f[i], 1]
                                 for i in range(len(f)))) for f in polys)
    assert np.isclose(0.5 * cz.sum(), shoelace)


def test_flat_vertex_normals_pack_as_flat_triangles():
    """Triangles whose vertex normals are their face normal are packed flat
    (and a big one leaves the BVH); curved ones keep their normals."""
    from clpt.pack import pack_scene

    cam = clpt.Camera(origin=(0.0, 0.5, 3.0), target=(0.0, 0.0, 0.0), fov=60, width=8, height=8)
    gv, gt = grid(2, size=4.0)
    sv, st, sn = uv_sphere((0.0, 0.3, 0.0), 0.3, n_theta=8, n_phi=16)
    floor = clpt.Mesh(vertices=gv, triangles=gt, normals=np.tile((0.0, 0.0, 1.0), (len(gv), 1)), material="white")
    ball = clpt.Mesh(vertices=sv, triangles=st, normals=sn, material="white")
    lamp = clpt.Quad(corner=(-0.2, 2, -0.2), edge_u=(0.4, 0, 0), edge_v=(0, 0, 0.4), material="white",
                     emission=(5, 5, 5))
    p = pack_scene(clpt.Scene(camera=cam, shapes=[floor, ball, lamp]))
    assert p.smooth and p.count("triangles") == len(gt)  # the floor in the plain loops, flat
    assert len(p.section("triangles")) and p.bvh is not None and p.bvh.count[0] == len(st) + 1
    p = pack_scene(clpt.Scene(camera=cam, shapes=[floor, lamp]))
    assert not p.smooth
