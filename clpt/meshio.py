"""Triangle meshes from OBJ and PLY files, and their transforms.

Files are parsed by trimesh's format readers (trimesh.exchange.obj and
trimesh.exchange.ply), which return plain arrays: positions, faces and,
where the file has them, per-vertex normals. Polygons are fanned into
triangles from their first vertex (the readers do so for files of mixed
polygon sizes, fan_triangulate for files of quads or other k-gons only). Nothing is merged, reordered or repaired on the way
(trimesh's ``process`` step is not run), so triangle i of the file is
triangle i here, less the degenerate ones, which are dropped with one
warning giving their count.

Every problem with a file is a ``MeshError`` (a ValueError) whose one-line
message names the file.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

FORMATS = ("obj", "ply")


from .scene import SceneError


class MeshError(SceneError):
    """A mesh file or array is missing, unreadable or malformed; the one-line
    message names it. A SceneError (and so a ValueError)."""


def _loader(fmt):
    if fmt == "obj":
        from trimesh.exchange.obj import load_obj
        return load_obj
    from trimesh.exchange.ply import load_ply
    return load_ply


def _parts(kw):
    """The (vertices, faces, normals-or-None) geometries in a reader's result."""
    if "geometry" in kw:  # OBJ: one entry per object or material group
        return [p for g in kw["geometry"].values() for p in _parts(g)]
    if kw.get("vertices") is None or kw.get("faces") is None:
        return []
    return [(kw["vertices"], kw["faces"], kw.get("vertex_normals"))]


def fan_triangulate(faces):
    """(M, k) polygons, k >= 3, as (M (k - 2), 3) triangles fanned from each
    polygon's first vertex, in order: (f0, f1, f2), (f0, f2, f3), ... (the
    readers fan mixed polygon sizes themselves, as here, but hand back
    files of quads or other k-gons only as (M, k))."""
    f = np.asarray(faces)
    k = f.shape[1]
    if k == 3:
        return f
    tri = np.empty((len(f), k - 2, 3), dtype=f.dtype)
    tri[:, :, 0] = f[:, :1]
    tri[:, :, 1] = f[:, 1:-1]
    tri[:, :, 2] = f[:, 2:]
    return tri.reshape(-1, 3)


def read_mesh(path):
    """(vertices float64 (N,3), triangles int64 (M,3), normals float64 (N,3) or None).

    Normals are the file's per-vertex normals, normalized, or None when it
    has none (or only some of its parts have them)."""
    p = Path(path)
    fmt = p.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise MeshError(f"{path}: unsupported mesh format {p.suffix or '(no extension)'!r}; "
                        f"supported: {', '.join('.' + f for f in FORMATS)}")
    if not p.is_file():
        raise MeshError(f"{path}: no such mesh file")
    try:
        with open(p, "rb") as f:
            kw = _loader(fmt)(f, file_type=fmt)
    except MeshError:
        raise
    except Exception as e:  # the readers raise many kinds; all mean a bad file
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise MeshError(f"{path}: cannot read the {fmt.upper()} file: {msg}") from None
    parts = _parts(kw)
    if not parts:
        raise MeshError(f"{path}: the file has no triangles")
    vs, fs, ns = [], [], []
    base = 0
    for v, f, n in parts:
        v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(f)
        if f.ndim != 2 or f.shape[1] < 3:
            raise MeshError(f"{path}: faces must be triangles or polygons (got shape {f.shape})")
        f = fan_triangulate(f)
        vs.append(v)
        fs.append(f.astype(np.int64) + base)
        ns.append(None if n is None else np.asarray(n, dtype=np.float64).reshape(-1, 3))
        base += len(v)
    vertices = np.concatenate(vs)
    triangles = np.concatenate(fs)
    normals = None if any(n is None for n in ns) else np.concatenate(ns)
    return check_mesh(vertices, triangles, normals, source=str(path))


def check_mesh(vertices, triangles, normals=None, source="<mesh>"):
    """Validate and clean mesh arrays: finite positions, indices in range,
    normals (normalized, one per vertex); degenerate triangles (zero area,
    or a repeated index) dropped with one warning giving their count."""
    if vertices is None or triangles is None:
        raise MeshError(f"{source}: needs vertices and triangles")
    v = np.array(vertices, dtype=np.float64)
    t = np.array(triangles)
    if t.size == 0:
        raise MeshError(f"{source}: the mesh has no triangles")
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"{source}: vertices must be an (N, 3) array (got shape {v.shape})")
    if t.ndim != 2 or t.shape[1] != 3:
        raise MeshError(f"{source}: triangles must be an (M, 3) array (got shape {t.shape})")
    if not np.issubdtype(t.dtype, np.integer):
        if t.dtype.kind not in "fb" or not np.array_equal(t, np.round(t)):
            raise MeshError(f"{source}: triangle indices must be integers")
    t = t.astype(np.int64)
    if not np.isfinite(v).all():
        bad = int(np.flatnonzero(~np.isfinite(v).all(axis=1))[0])
        raise MeshError(f"{source}: vertex {bad} is not finite ({v[bad].tolist()})")
    if (t.min() < 0 or t.max() >= len(v)):
        bad = int(np.flatnonzero(((t < 0) | (t >= len(v))).any(axis=1))[0])
        raise MeshError(f"{source}: triangle {bad} has vertex index out of range "
                        f"({t[bad].tolist()}, {len(v)} vertices)")
    n = None
    if normals is not None:
        n = np.asarray(normals, dtype=np.float64)
        if n.shape != v.shape:
            raise MeshError(f"{source}: normals must be one per vertex, shape {v.shape} (got {n.shape})")
        length = norm_rows(n)
        if not (np.isfinite(length).all() and (length > 0).all()):
            bad = int(np.flatnonzero(~(np.isfinite(length) & (length > 0)))[0])
            raise MeshError(f"{source}: normal {bad} is zero or not finite ({n[bad].tolist()})")
        n = n / length[:, None]
    keep = ~degenerate(v, t)
    dropped = int((~keep).sum())
    if dropped:
        warnings.warn(f"{source}: dropped {dropped} degenerate triangle{'s' if dropped > 1 else ''} "
                      f"(zero area or repeated vertex) of {len(t)}", stacklevel=2)
        t = t[keep]
    if len(t) == 0:
        raise MeshError(f"{source}: the mesh has no non-degenerate triangles")
    return v, t, n


def cross_rows(a, b):
    """Row-wise a x b of (M, 3) arrays (np.cross is several times slower)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def norm_rows(a):
    """Row-wise Euclidean length of an (M, 3) array."""
    return np.sqrt(a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1] + a[:, 2] * a[:, 2])


def degenerate(vertices, triangles):
    """Mask of triangles with a repeated index or (relative to their edge
    lengths) zero area."""
    a = vertices[triangles[:, 0]]
    e1, e2 = vertices[triangles[:, 1]] - a, vertices[triangles[:, 2]] - a
    area2 = norm_rows(cross_rows(e1, e2))
    scale = norm_rows(e1) * norm_rows(e2)
    repeated = ((triangles[:, 0] == triangles[:, 1]) | (triangles[:, 1] == triangles[:, 2])
                | (triangles[:, 0] == triangles[:, 2]))
    return repeated | ~(area2 > 1e-12 * scale) | (scale == 0)


def transform_mesh(vertices, normals, matrix):
    """Apply a 4x4 affine matrix (column vectors: p' = M @ [p, 1]) to vertices;
    normals by the inverse transpose, renormalized. Returns (vertices, normals)."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise ValueError(f"a transform must be a 4x4 matrix (got shape {m.shape})")
    if not np.isfinite(m).all():
        raise ValueError("a transform must be finite")
    if not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0)):
        raise ValueError(f"a transform's last row must be 0 0 0 1 (got {m[3].tolist()}): "
                         "projective transforms are not supported")
    a = m[:3, :3]
    if abs(np.linalg.det(a)) < 1e-300 or np.linalg.cond(a) > 1e12:
        raise ValueError("a transform must be invertible (its 3x3 part is singular)")
    v = np.asarray(vertices, dtype=np.float64) @ a.T + m[:3, 3]
    if normals is None:
        return v, None
    n = np.asarray(normals, dtype=np.float64) @ np.linalg.inv(a)  # (A^-T n) as rows
    return v, n / norm_rows(n)[:, None]


def _axis_rotation(axis, degrees):
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    x, y, z = axis
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def compose(translate=(0.0, 0.0, 0.0), rotate=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)):
    """4x4 matrix that scales, then rotates (degrees about x, then y, then z,
    as Box does), then translates."""
    m = np.eye(4)
    rx, ry, rz = rotate
    r = (_axis_rotation((0, 0, 1), rz) @ _axis_rotation((0, 1, 0), ry) @ _axis_rotation((1, 0, 0), rx))
    m[:3, :3] = r @ np.diag(np.broadcast_to(np.asarray(scale, dtype=np.float64), 3))
    m[:3, 3] = translate
    return m
