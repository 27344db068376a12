"""Test meshes generated in code: tessellated spheres and grids, and writers
for the OBJ, PLY and Mitsuba serialized files the loader reads."""

from __future__ import annotations

import zlib
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


def blob(n_theta=6, n_phi=10):
    """OBJ text of a coarse, lumpy sphere (radius about 1) without normals:
    quads between rings, triangle fans at the poles, and texture coordinates
    with a seam (u = 0 and u = 1 at phi = 0) and a coordinate per pole
    triangle, as modelling tools write them. Mitsuba splits a vertex for each
    (position, texture coordinate) pair, so the seam and the poles get normals
    of their own side only: the test mesh for computed vertex normals."""
    th = np.pi * np.arange(1, n_theta) / n_theta
    ph = 2 * np.pi * np.arange(n_phi) / n_phi
    t, p = np.meshgrid(th, ph, indexing="ij")
    r = 1 + 0.15 * np.cos(3 * p) * np.sin(t) ** 2 + 0.1 * np.cos(2 * t)
    ring = np.stack([r * np.sin(t) * np.cos(p), r * np.cos(t), r * np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3)
    pos = np.concatenate([[(0.0, 1.1, 0.0)], ring, [(0.0, -1.1, 0.0)]])
    lines = ["# A coarse lumpy sphere without normals (tests/meshgen.py blob())"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in pos]
    uv = [(j / n_phi, 1 - i / n_theta) for i in range(1, n_theta) for j in range(n_phi + 1)]
    uv += [((j + 0.5) / n_phi, 1.0) for j in range(n_phi)] + [((j + 0.5) / n_phi, 0.0) for j in range(n_phi)]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
    v_at = lambda i, j: 2 + (i - 1) * n_phi + j % n_phi  # noqa: E731  (1-based; ring i = 1 .. n_theta - 1)
    t_at = lambda i, j: 1 + (i - 1) * (n_phi + 1) + j  # noqa: E731
    north, south = 1, len(pos)
    pole_t = (n_theta - 1) * (n_phi + 1) + 1
    for j in range(n_phi):
        lines.append(f"f {north}/{pole_t + j} {v_at(1, j + 1)}/{t_at(1, j + 1)} {v_at(1, j)}/{t_at(1, j)}")
        for i in range(1, n_theta - 1):
            c = [(i, j), (i, j + 1), (i + 1, j + 1), (i + 1, j)]
            lines.append("f " + " ".join(f"{v_at(a, b)}/{t_at(a, b)}" for a, b in c))
        k = n_theta - 1
        lines.append(f"f {south}/{pole_t + n_phi + j} {v_at(k, j)}/{t_at(k, j)} {v_at(k, j + 1)}/{t_at(k, j + 1)}")
    return "\n".join(lines) + "\n"


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


# Mitsuba's serialized mesh format (Mitsuba 3's src/shapes/serialized.cpp documents it):
# per shape, an uncompressed header (uint16 0x041C, uint16 version) and a zlib stream
# of flags, (version 4) a NUL-terminated name, uint64 vertex and triangle counts, the
# arrays, uint32 triangles; after the last shape, the shapes' file offsets (uint64 in
# version 4, uint32 in version 3) and a uint32 count. Little-endian throughout.
SERIALIZED_FLAGS = {"normals": 0x0001, "uvs": 0x0002, "colors": 0x0008, "face_normals": 0x0010,
                    "single": 0x1000, "double": 0x2000}


def serialized_shape(vertices, triangles, normals=None, uvs=None, colors=None, double=False, name="",
                     version=4, extra_flags=0, level=6):
    """One shape of a .serialized file: its header and its compressed stream."""
    ft = "<f8" if double else "<f4"
    flags = SERIALIZED_FLAGS["double" if double else "single"] | extra_flags
    arrays = [np.asarray(vertices, dtype=ft)]
    for key, a in (("normals", normals), ("uvs", uvs), ("colors", colors)):
        if a is not None:
            flags |= SERIALIZED_FLAGS[key]
            arrays.append(np.asarray(a, dtype=ft))
    body = np.array([flags], "<u4").tobytes()
    if version == 4:
        body += name.encode() + b"\0"
    body += np.array([len(vertices), len(triangles)], "<u8").tobytes()
    body += b"".join(a.tobytes() for a in arrays) + np.asarray(triangles, dtype="<u4").tobytes()
    return np.array([0x041C, version], "<u2").tobytes() + zlib.compress(body, level)


def write_serialized(path, shapes, version=4):
    """A .serialized file of shapes (each a dict of serialized_shape's keywords)."""
    parts, offsets, at = [], [], 0
    for shape in shapes:
        offsets.append(at)
        parts.append(serialized_shape(version=version, **shape))
        at += len(parts[-1])
    table = np.array(offsets, "<u8" if version == 4 else "<u4").tobytes() + np.array([len(shapes)], "<u4").tobytes()
    Path(path).write_bytes(b"".join(parts) + table)


def shared_mesh(name):
    """Path of a test mesh in ../shared/meshes next to the repository (or a
    folder above it), or None when absent."""
    root = Path(__file__).resolve().parents[1]
    for d in [root, *root.parents]:
        p = d.parent / "shared" / "meshes" / name if d == root else d / "shared" / "meshes" / name
        if p.is_file():
            return p
    return None


SERIALIZED_SEEDS = "tests/data/serialized"


def serialized_seeds():
    """The seed .serialized files (name -> (shapes, version)): every flag the
    reader takes (normals, texture coordinates, colours, float64) in version 4
    files of several shapes, and a version 3 file."""
    v, t, n = uv_sphere(n_theta=3, n_phi=4)
    gv, gt = grid(n=2)
    box = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    box_t = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return {
        "shapes_v4.serialized": ([dict(vertices=v, triangles=t, normals=n, uvs=v[:, :2] * 0.5 + 0.5, name="ball"),
                                  dict(vertices=box * 0.5, triangles=box_t, double=True, colors=box, name="box"),
                                  dict(vertices=gv, triangles=gt, uvs=gv[:, :2], name="grid")], 4),
        "shapes_v3.serialized": ([dict(vertices=box, triangles=box_t),
                                  dict(vertices=v + 2.0, triangles=t, normals=n)], 3),
    }


if __name__ == "__main__":
    # python tests/meshgen.py: (re)writes the generated test meshes in tests/data.
    root = Path(__file__).resolve().parents[1]
    (root / "tests/data/cbox/blob.obj").write_text(blob())
    (root / SERIALIZED_SEEDS).mkdir(exist_ok=True)
    for name, (shapes, version) in serialized_seeds().items():
        write_serialized(root / SERIALIZED_SEEDS / name, shapes, version=version)
