"""Test meshes generated in code: tessellated spheres and grids, and writers
for the OBJ and PLY files the loader reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def uv_sphere(center=(0.0, 0.0, 0.0), radius=1.0, n_theta=16, n_phi=32):
    """(vertices, triangles, normals) of a latitude-longitude sphere with
    outward-facing triangles and exact per-vertex normals."""
    th = np.linspace(0.0, np.pi, n_theta + 1)
    ph = np.linspace(0.0, 2 * np.pi, n_phi + 1)[:-1]
    t, p = np.meshgrid(th[1:-1], ph, indexing="ij")
    dirs = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3)
    dirs = np.concatenate([[(0.0, 1.0, 0.0)], dirs, [(0.0, -1.0, 0.0)]])
    tris = []
    ring = lambda i, j: 1 + i * n_phi + (j % n_phi)  # noqa: E731
    south = len(dirs) - 1
    for j in range(n_phi):
        tris.append((0, ring(0, j + 1), ring(0, j)))
        tris.append((south, ring(n_theta - 2, j), ring(n_theta - 2, j + 1)))
        for i in range(n_theta - 2):
            a, b, c, d = ring(i, j), ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)
            tris += [(a, b, c), (a, c, d)]
    v = np.asarray(center, dtype=np.float64) + radius * dirs
    return v, np.array(tris, dtype=np.int64), dirs.copy()


def grid(n=4, size=1.0, z=0.0):
    """(vertices, triangles) of an n x n grid of squares in the plane z,
    centred on the origin, facing +z."""
    x = np.linspace(-size / 2, size / 2, n + 1)
    gx, gy = np.meshgrid(x, x, indexing="ij")
    v = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], axis=1)
    idx = lambda i, j: i * (n + 1) + j  # noqa: E731
    tris = []
    for i in range(n):
        for j in range(n):
            tris += [(idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)), (idx(i, j), idx(i + 1, j + 1), idx(i, j + 1))]
    return v, np.array(tris, dtype=np.int64)


def write_obj(path, vertices, triangles, normals=None):
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in vertices]
    if normals is not None:
        lines += [f"vn {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in normals]
        lines += [f"f {a + 1}//{a + 1} {b + 1}//{b + 1} {c + 1}//{c + 1}" for a, b, c in triangles]
    else:
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in triangles]
    path.write_text("\n".join(lines) + "\n")


def write_ply(path, vertices, triangles, normals=None, binary=True):
    props = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
            f"element vertex {len(vertices)}", *[f"property float {p}" for p in props],
            f"element face {len(triangles)}", "property list uchar int vertex_indices", "end_header"]
    data = np.asarray(vertices, dtype=np.float32)
    if normals is not None:
        data = np.concatenate([data, np.asarray(normals, dtype=np.float32)], axis=1)
    if not binary:
        body = [" ".join(repr(float(c)) for c in row) for row in data]
        body += [f"3 {a} {b} {c}" for a, b, c in triangles]
        path.write_text("\n".join(head + body) + "\n")
        return
    faces = np.zeros(len(triangles), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"] = 3
    faces["i"] = triangles
    path.write_bytes(("\n".join(head) + "\n").encode() + data.astype("<f4").tobytes() + faces.tobytes())


def shared_mesh(name):
    """Path of a test mesh in ../shared/meshes next to the repository (or a
    folder above it), or None when absent."""
    root = Path(__file__).resolve().parents[1]
    for d in [root, *root.parents]:
        p = d.parent / "shared" / "meshes" / name if d == root else d / "shared" / "meshes" / name
        if p.is_file():
            return p
    return None
