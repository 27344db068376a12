"""Walls no shadow ray can cross (clpt/pack.py _mark_shadowless): which
plain-loop primitives are marked, and that shadow rays between points a path
can reach are blocked exactly as before when the marked ones are skipped."""

import numpy as np
import pytest

import clpt
from clpt import layout
from clpt.pack import pack_scene


def _kinds(packed):
    """wv_kind.w of the plain loops' quads and triangles, in section order."""
    r = packed.records
    off = layout.MATERIAL.stride * packed.count("materials") + layout.SPHERE.stride * packed.count("spheres")
    n = packed.count("quads") + packed.count("triangles")
    return r[off + layout.PLANAR.row("wv_kind"): off + layout.PLANAR.stride * n: layout.PLANAR.stride, 3]


def test_a_boxs_walls_are_marked_and_what_stands_inside_is_not():
    k = _kinds(pack_scene(clpt.load_scene("cornell_box")))
    # floor, ceiling, back, left and right walls; the lamp (the ceiling above it) and the blocks' faces are not
    assert (k == layout.ITEM_QUAD_NO_SHADOW).sum() == 5
    assert (k == layout.ITEM_QUAD).sum() == 13


def _room(**extra):
    s = clpt.Scene(camera=clpt.Camera(origin=(0, 0, 0.5), target=(0, 0, -1)))
    s.shapes += [clpt.Quad(corner=(-1, -1, -1), edge_u=(2, 0, 0), edge_v=(0, 2, 0), name="back"),
                 clpt.Quad(corner=(-0.2, 0.9, -0.5), edge_u=(0.4, 0, 0), edge_v=(0, 0, 0.4), emission=(5, 5, 5),
                           name="lamp"),
                 clpt.Sphere(center=(0.3, -0.5, -0.6), radius=0.3)]
    for k, v in extra.items():
        setattr(s, k, v) if k == "camera" else s.shapes.append(v)
    return s


def test_marking_needs_every_point_on_one_side():
    assert (_kinds(pack_scene(_room())) == layout.ITEM_QUAD_NO_SHADOW).sum() == 1  # the back wall only
    # A sphere reaching behind the wall: its box's corners cross the plane.
    behind = _room(ball=clpt.Sphere(center=(0, 0, -1.05), radius=0.1))
    assert (_kinds(pack_scene(behind)) == layout.ITEM_QUAD_NO_SHADOW).sum() == 0
    # The camera behind the wall: paths reach its back face.
    cam = _room(camera=clpt.Camera(origin=(0, 0, -3), target=(0, 0, 0)))
    assert (_kinds(pack_scene(cam)) == layout.ITEM_QUAD_NO_SHADOW).sum() == 0
    # A point light behind it.
    pt = _room(light=clpt.PointLight(position=(0, 0, -2), intensity=(1, 1, 1)))
    assert (_kinds(pack_scene(pt)) == layout.ITEM_QUAD_NO_SHADOW).sum() == 0
    # A sphere of radius 1e6 in front of the wall, all of it on the wall's front side: the points on it
    # get ray offsets of several units (kernels/scene.h offset_distance follows the sphere's
    # magnitude), more than the lamp's and the small sphere's distances from the wall's plane.
    big = _room(big=clpt.Sphere(center=(0, 0, 1e6), radius=1e6 - 0.5))
    assert (_kinds(pack_scene(big)) == layout.ITEM_QUAD_NO_SHADOW).sum() == 0
    # Lights at infinity: nothing is marked.
    env = _room(sky=clpt.EnvironmentLight(radiance=(1, 1, 1)))
    assert (_kinds(pack_scene(env)) == layout.ITEM_QUAD_NO_SHADOW).sum() == 0


@pytest.mark.parametrize("lanes", [1, 8])
def test_shadow_rays_inside_the_hull_are_blocked_as_before(probes, lanes):
    """Segments between random points of the box's surfaces and of its lamp:
    the same blocked lanes with the marked walls skipped as with every wall
    tested, and some of them blocked by what stands inside."""
    scene = clpt.load_scene("cornell_box")
    marked = pack_scene(scene)
    plain = pack_scene(scene, shadowless=False)
    assert (_kinds(plain) == layout.ITEM_QUAD_NO_SHADOW).sum() == 0
    rng = np.random.default_rng(11)
    quads = []
    for s in scene.shapes:
        for p in s.primitives():
            if isinstance(p, clpt.Quad):
                quads.append(p)
    n = 4000
    pick = rng.integers(0, len(quads), n)
    a, b = rng.uniform(0.01, 0.99, (2, n))
    c = np.array([quads[i].corner for i in pick], dtype=float)
    u = np.array([quads[i].edge_u for i in pick], dtype=float)
    v = np.array([quads[i].edge_v for i in pick], dtype=float)
    x = c + a[:, None] * u + b[:, None] * v
    lamp = max(quads, key=lambda q: max(q.emission or (0, 0, 0)))
    la, lb = rng.uniform(0, 1, (2, n))
    y = (np.array(lamp.corner) + la[:, None] * np.array(lamp.edge_u) + lb[:, None] * np.array(lamp.edge_v))
    # Origins nudged off their surface towards the lamp, as shadow rays leave theirs.
    d = y - x
    dist = np.linalg.norm(d, axis=1)
    d /= dist[:, None]
    x = x + 1e-4 * d
    tmax = (dist - 1e-4) * 0.9999
    probe = probes(lanes=lanes)
    got = probe.run("probe_hit", [*x.T, *d.T, tmax], 9, prefix=probe.scene_args(marked))[8]
    ref = probe.run("probe_hit", [*x.T, *d.T, tmax], 9, prefix=probe.scene_args(plain))[8]
    np.testing.assert_array_equal(got, ref)
    assert 0.05 < ref.mean() < 0.9
