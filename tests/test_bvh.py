"""The BVH: its builders, and its closest-hit and shadow queries on the
device against the plain loops (brute force) on random, surface-born and
grazing rays."""

import numpy as np
import pytest

import clpt
from clpt import bvh, layout
from clpt.pack import pack_scene
from meshgen import grid, uv_sphere


def _scene():
    """Meshes (a smooth tessellated sphere, a flat grid, a dense small
    sphere), analytic spheres, quads and a triangle, overlapping."""
    s = clpt.Scene(camera=clpt.Camera(origin=(0, 0, 5)))
    v, t, n = uv_sphere(center=(0.2, 0.1, 0.0), radius=0.8, n_theta=10, n_phi=20)
    s.shapes.append(clpt.Mesh(vertices=v, triangles=t, normals=n, material="white", name="ball"))
    v, t = grid(8, size=3.0, z=-0.5)
    s.shapes.append(clpt.Mesh(vertices=v, triangles=t, material="red", emission=(1, 1, 1), name="floor"))
    v, t, _ = uv_sphere(center=(-0.9, 0.6, 0.3), radius=0.15, n_theta=6, n_phi=12)
    s.shapes.append(clpt.Mesh(vertices=v, triangles=t, material="green"))
    s.shapes += [clpt.Sphere(center=(0.9, -0.6, 0.4), radius=0.3), clpt.Sphere(center=(0.2, 0.1, 0.0), radius=0.5),
                 clpt.Quad(corner=(-1.5, -1.5, -1.0), edge_u=(3, 0, 0), edge_v=(0, 3, 0), emission=(2, 2, 2)),
                 clpt.Box(center=(-0.5, -0.8, 0.5), size=(0.4, 0.3, 0.2), rotation=(10, 20, 30)),
                 clpt.Triangle(vertices=((0, 1.2, 0), (1, 1.2, 0.5), (0, 1.2, 1)))]
    return s


def _rays(packed_off, rng, n):
    """Random rays through the scene's bounds, rays born on triangles and
    spheres, and grazing rays along the floor grid's plane."""
    lo, hi = np.array([-1.6, -1.6, -1.1]), np.array([1.6, 1.6, 1.1])
    o1 = rng.uniform(lo, hi, (n, 3))
    d1 = rng.normal(size=(n, 3))
    # Born on a primitive: a point of a random triangle of the plain loop's records.
    tris = packed_off.section("triangles")
    pick = rng.integers(0, len(tris), n)
    a, b = rng.uniform(size=(2, n))
    flip = a + b > 1
    a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
    corner = tris["corner_mat"][pick, :3]
    nrm = tris["n_light"][pick, :3]
    # Recover the edges from the dual vectors: u, v solve [wu; wv; n] [u v n] = I.
    m = np.stack([tris["wu_prim"][pick, :3], tris["wv_kind"][pick, :3], nrm], axis=1)
    inv = np.linalg.inv(m)
    u, v = inv[:, :, 0], inv[:, :, 1]
    o2 = corner + a[:, None] * u + b[:, None] * v
    d2 = rng.normal(size=(n, 3))
    # Grazing: in the floor's plane z = -0.5 (exactly, and a hair off it).
    o3 = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), np.full(n, -0.5)])
    d3 = np.column_stack([rng.normal(size=(n, 2)), rng.choice([0.0, 1e-7, -1e-7, 1e-3], n)])
    o = np.concatenate([o1, o2, o3])
    d = np.concatenate([d1, d2, d3])
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def _query(probe, packed, o, d, tmax):
    args = probe.scene_args(packed)
    return probe.run("probe_hit", [o[:, 0], o[:, 1], o[:, 2], d[:, 0], d[:, 1], d[:, 2], tmax], 9, prefix=args)


@pytest.mark.parametrize("method,walk", [("sah", "hybrid"), ("lbvh", "hybrid"), ("sah", "lane")])
@pytest.mark.parametrize("lanes,double", [(1, False), (8, False), (8, True)])
def test_bvh_equals_brute_force(probes, method, walk, lanes, double):
    scene = _scene()
    off = pack_scene(scene, bvh="off")
    on = pack_scene(scene, bvh="on", bvh_method=method)
    assert on.count("nodes") > 1 and off.count("nodes") == 0
    rng = np.random.default_rng(7)
    o, d = _rays(off, rng, 3000)
    probe = probes(lanes=lanes, double=double, bvh_walk=walk)
    ref = _query(probe, off, o, d, np.full(len(o), np.inf))
    t_ref = ref[0]
    tmax = np.where(np.isfinite(t_ref), t_ref * rng.uniform(0.3, 1.7, len(o)), 10.0)
    ref = _query(probe, off, o, d, tmax)
    got = _query(probe, on, o, d, tmax)
    hit = np.isfinite(ref[0])
    assert hit.mean() > 0.3 and (~hit).sum() > 100
    # The same primitive tests on the same records: equal to the bit.
    np.testing.assert_array_equal(got[0], ref[0])
    same_prim = got[1] == ref[1]
    # Different primitives only where two are hit at the same t (a shared edge).
    assert (~same_prim).mean() < 2e-3
    for k in (2, 3, 4, 5, 6, 7):  # barycentrics, normal, light
        np.testing.assert_array_equal(got[k][same_prim], ref[k][same_prim])
    assert (ref[8] > 0).any() and (ref[8] == 0).any()
    np.testing.assert_array_equal(got[8], ref[8])


def test_hits_carry_primitive_and_barycentrics(probes):
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    t = np.array([[0, 1, 2], [1, 3, 2]])
    scene = clpt.Scene(shapes=[clpt.Sphere(center=(5, 5, 5), radius=0.1, emission=(1, 1, 1)),
                               clpt.Mesh(vertices=v, triangles=t)])
    packed = pack_scene(scene, bvh="on")
    o = np.array([[0.2, 0.3, 1.0], [0.8, 0.9, 1.0]])
    d = np.array([[0.0, 0, -1], [0, 0, -1]])
    t_, prim, bu, bv, *_ = _query(probes(lanes=1), packed, o, d, np.full(2, np.inf))
    np.testing.assert_allclose(t_, 1.0, rtol=1e-6)
    np.testing.assert_array_equal(prim, [1, 2])  # the sphere is primitive 0
    np.testing.assert_allclose([bu[0], bv[0]], [0.2, 0.3], atol=1e-6)
    # Second triangle (v1, v3, v2): p = v1 + a (v3 - v1) + b (v2 - v1).
    np.testing.assert_allclose([bu[1], bv[1]], [0.7, 0.2], atol=1e-6)


def test_shading_normals_interpolate(probes):
    v, t, n = uv_sphere(radius=1.0, n_theta=8, n_phi=16)
    scene = clpt.Scene(shapes=[clpt.Mesh(vertices=v, triangles=t, normals=n, emission=(1, 1, 1))])
    rng = np.random.default_rng(3)
    o = rng.normal(size=(500, 3))
    o = 3 * o / np.linalg.norm(o, axis=1, keepdims=True)
    d = -o / 3 + rng.normal(scale=0.1, size=o.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    packed = pack_scene(scene, bvh="on")
    probe = probes(lanes=8)
    args = probe.scene_args(packed)
    t_, prim, bu, bv, *_ = _query(probe, packed, o, d, np.full(len(o), np.inf))
    ns = np.stack(probe.run("probe_shading_normal", [o[:, 0], o[:, 1], o[:, 2], d[:, 0], d[:, 1], d[:, 2]], 3,
                            prefix=args), axis=1)
    hit = np.isfinite(t_)
    assert hit.mean() > 0.9
    tri = t[prim[hit].astype(int)]
    a, b = bu[hit][:, None], bv[hit][:, None]
    expect = (1 - a - b) * n[tri[:, 0]] + a * n[tri[:, 1]] + b * n[tri[:, 2]]
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(ns[hit], expect, atol=2e-5)
    # Not the flat normal: the interpolated one differs from the face's.
    x = o[hit] + t_[hit][:, None] * d[hit]
    assert np.abs(np.einsum("ij,ij->i", ns[hit], x / np.linalg.norm(x, axis=1, keepdims=True)) - 1).max() < 0.02


@pytest.mark.parametrize("method", bvh.METHODS)
def test_builders_cover_every_primitive(method):
    rng = np.random.default_rng(1)
    c = rng.uniform(-1, 1, (5000, 3))
    c[:200] = c[0]  # many identical boxes
    lo, hi = c - 0.01, c + 0.02
    tree = bvh.build(lo, hi, method=method)
    assert sorted(tree.order) == list(range(len(c)))
    leaf = tree.left < 0
    assert tree.count[leaf].sum() == len(c) and tree.count[leaf].max() <= bvh.MAX_LEAF
    # Every node's box holds its primitives; children tile their parent's range.
    for i in rng.choice(tree.n_nodes, 200):
        prims = tree.order[tree.start[i]:tree.start[i] + tree.count[i]]
        assert (lo[prims] >= tree.lo[i]).all() and (hi[prims] <= tree.hi[i]).all()
        if tree.left[i] >= 0:
            l, r = tree.left[i], tree.left[i] + 1
            assert tree.start[l] == tree.start[i] and tree.start[r] == tree.start[l] + tree.count[l]
            assert tree.count[l] + tree.count[r] == tree.count[i]
    assert tree.depth() < 64


def test_flatten_rounds_boxes_outwards():
    lo = np.array([[0.1, 0.2, 0.3]])
    hi = np.array([[0.7, 0.8, 0.9]])
    tree = bvh.build(lo, hi)
    wide = bvh.collapse(tree)
    recs, leaves = bvh.flatten(tree, wide, node_base=10, leaf_base=26, double=False)
    assert recs.shape == (16, 4)
    node = layout.BVH_NODE.view(recs)[0]  # one column a child
    assert all(node[f"lo_{a}"][0].astype(np.float32) <= lo[0, k] for k, a in enumerate("xyz"))
    assert all(node[f"hi_{a}"][0].astype(np.float32) >= hi[0, k] for k, a in enumerate("xyz"))
    assert node["ptr"][0] == 26 and node["count"][0] == 1 and (node["count"][1:] == -1).all()  # a leaf root, empty slots


@pytest.mark.parametrize("method", bvh.METHODS)
def test_collapse_keeps_every_leaf_once(method):
    """The wide tree's children are the binary tree's nodes: every binary
    leaf under exactly one wide node, every inner child a wide node of its
    own, no wide node over WIDTH children, and each box holding its
    children's boxes."""
    rng = np.random.default_rng(2)
    c = rng.uniform(-1, 1, (3000, 3))
    tree = bvh.build(c - 0.01, c + 0.01, method=method)
    wide = bvh.collapse(tree)
    ch = wide.children
    assert ch.shape[1] == bvh.WIDTH
    used = ch[ch >= 0]
    assert len(used) == len(set(used.tolist()))
    leaves = set(np.flatnonzero(tree.left < 0).tolist())
    assert leaves <= set(used.tolist())
    inner = [x for x in used.tolist() if tree.left[x] >= 0]
    assert len(inner) == wide.n_nodes - 1
    assert (np.sort(tree.count[list(leaves)]).sum()) == len(c)
    # Fewer, fuller nodes than the binary tree's.
    assert 2 * wide.n_nodes < (tree.left >= 0).sum() and (ch >= 0).sum(1).mean() > 3
    recs, order = bvh.flatten(tree, wide, node_base=0, leaf_base=16 * wide.n_nodes, double=False)
    assert sorted(order.tolist()) == sorted(leaves)
    rows = recs.reshape(-1, 8, 8)
    cnt = rows[:, 7]
    assert ((cnt > 0).sum()) == len(leaves) and ((cnt == 0).sum()) == wide.n_nodes - 1


def test_scene_sized_primitives_stay_in_the_plain_loops():
    """A room's walls (quads as big as the scene) are kept out of the BVH, in
    the plain loops, and the mesh goes in it; the hits are the brute force's
    (test_bvh_equals_brute_force covers a scene with such a quad)."""
    s = clpt.load_scene("cornell_box")
    v, t, n = uv_sphere(center=(0.0, -0.5, 0.0), radius=0.3, n_theta=10, n_phi=20)
    s.shapes.append(clpt.Mesh(vertices=v, triangles=t, normals=n, material="white", name="ball"))
    p = pack_scene(s, bvh="on")
    n_quads = sum(len(sh.primitives()) for sh in s.shapes if not isinstance(sh, clpt.Mesh))
    assert 0 < p.count("quads") < n_quads  # the walls, not the blocks' small faces or the light
    assert p.count("triangles") == 0 and p.count("nodes") > 0  # smooth triangles stay in the tree
    # Every primitive somewhere, once.
    from clpt.pack import _big_primitives
    lo = np.array([[0.0, 0, 0], [0, 0, 0], [0.4, 0.4, 0.4]])
    hi = np.array([[1.0, 1, 1], [1, 1, 1], [0.5, 0.5, 0.5]])
    assert _big_primitives(lo, hi, np.zeros(3, bool)).tolist() == [True, True, False]
    assert _big_primitives(lo[:2], hi[:2], np.zeros(2, bool)).sum() == 1  # one stays in the tree
    assert not _big_primitives(lo, hi, np.array([True, True, False])).any()
