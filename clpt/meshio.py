"""Triangle meshes from OBJ and PLY files, and their transforms.

The readers here are clpt's own, so that every damaged file is refused with
one line naming the file, the place and the reason (a line of an OBJ or ASCII
PLY file, a byte offset in a binary PLY file, a shape and byte of a Mitsuba
.serialized file, a vertex or face by number), and
so that sizes are checked before anything is allocated: the memory reading
needs against what the machine has, and the counts a PLY header declares
against the bytes that follow it (and a .serialized header's against what its
compressed bytes can hold). They read positions, polygons and per-vertex
normals, and nothing else (texture coordinates, colours, materials, groups and
other elements are skipped). Polygons are fanned into triangles from their
first vertex, in order. Nothing is reordered or repaired, so triangle i of the
file is triangle i here, less the degenerate ones, which are dropped with one
warning giving their count; an OBJ file's vertices are its distinct (position,
texture coordinate, normal) triples, as Mitsuba makes them. vertex_normals
computes smooth normals for a mesh without them, as Mitsuba does.

Every problem with a file is a ``MeshError`` (a SceneError, so a ValueError).
"""

from __future__ import annotations

import io
import math
import os
import re
import struct
import warnings
import zlib
from array import array
from pathlib import Path

import numpy as np

from . import hostio
from .errors import MeshError, SceneError
from .hostio import open_regular_file

FORMATS = ("obj", "ply", "serialized")

# What reading needs at its peak, in bytes per byte of the file (measured with
# tracemalloc on a 160,000-triangle sphere, normals and not): the file itself,
# the arrays built from it and check_mesh's copies. A binary PLY is the
# densest (9.5: float32 and int32 become float64 and int64); an OBJ read line
# by line 3.3, an ASCII PLY 3.9. OBJ's whole-file parse is faster but holds
# every token as a Python object (11 to 14): it is taken only where that fits.
READ_BYTES_PER_FILE_BYTE = {"obj": 4, "ply": 10, "serialized": 1}  # serialized: see SERIALIZED_READ_BYTES_PER_BYTE
OBJ_WHOLE_FILE_BYTES_PER_FILE_BYTE = 15
MAX_PLY_HEADER_BYTES = 1 << 16
MAX_INDEX = 2 ** 62  # larger indices and counts cannot be in range of any file that fits in memory


def fan_triangulate(faces):
    """(M, k) polygons, k >= 3, as (M (k - 2), 3) triangles fanned from each
    polygon's first vertex, in order: (f0, f1, f2), (f0, f2, f3), ..."""
    f = np.asarray(faces)
    return fan_polygons(f.reshape(-1), np.full(len(f), f.shape[1]))


def fan_polygons(corners, sizes):
    """Polygons given as their corners one after another (sizes[i] of them
    for polygon i, each >= 3) as triangles fanned from each polygon's first
    corner, in order."""
    corners = np.asarray(corners, dtype=np.int64)
    sizes = np.asarray(sizes, dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    per = sizes - 2
    first = np.repeat(start, per)
    # j = 1 .. k-2 within each polygon
    j = np.arange(int(per.sum()), dtype=np.int64) - np.repeat(np.cumsum(per) - per, per) + 1
    return np.stack([corners[first], corners[first + j], corners[first + j + 1]], axis=1)


def read_mesh(path, shape_index=0):
    """(vertices float64 (N,3), triangles int64 (M,3), normals float64 (N,3) or None).

    Normals are the file's per-vertex normals, normalized, or None when it
    has none (or only some of its faces have them, in an OBJ file).
    shape_index picks one of the meshes of a Mitsuba .serialized file."""
    return read_mesh_uv(path, shape_index)[:3]


def read_mesh_uv(path, shape_index=0):
    """read_mesh's arrays and the file's texture coordinates, float64 (N, 2)
    per vertex as the file gives them, or None when it has none: OBJ `vt`
    (a corner without one gets (0, 0) when others have one), PLY vertex
    properties u, v (or s, t, texture_u, texture_v, texture_s, texture_t),
    a serialized mesh's when its flags say so."""
    p = Path(path)
    fmt = p.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise MeshError(f"{path}: unsupported mesh format {p.suffix or '(no extension)'!r}; "
                        f"supported: {', '.join('.' + f for f in FORMATS)}")
    if shape_index != 0 and fmt != "serialized":
        raise MeshError(f"{path}: shape_index {shape_index}: only a .serialized file holds several meshes")
    data = _read_bytes(p, path, fmt)
    if fmt == "serialized":
        v, t, n, uv = _read_serialized(data, path, shape_index)
        return (*check_mesh(v, t, n, source=f"{path}: shape {shape_index}"), uv)
    v, t, n, uv = (_read_obj if fmt == "obj" else _read_ply)(data, path)
    return (*check_mesh(v, t, n, source=str(path)), uv)


def _read_bytes(p: Path, name, fmt) -> bytes:
    """The file's bytes: a regular file whose reading fits in memory (checked
    before reading)."""
    try:
        f = open_regular_file(p, name, "mesh file")
    except MeshError:
        raise
    except SceneError as e:
        raise MeshError(str(e)) from None
    with f:
        size = os.fstat(f.fileno()).st_size
        need = size * READ_BYTES_PER_FILE_BYTE[fmt]
        avail = hostio.available_host_bytes()
        if avail is not None and need > avail:
            raise MeshError(f"{name}: a {size / 2**30:.1f} GiB mesh file needs about {need / 2**30:.1f} GiB of "
                            f"memory to read and {avail / 2**30:.1f} GiB are available; too large")
        try:
            data = f.read()
        except OSError as e:
            raise MeshError(f"{name}: cannot read the mesh file: {e.strerror or e}") from None
    if not data:
        raise MeshError(f"{name}: the file is empty")
    return data


def _finite_number(tok: bytes, fail, what):
    try:
        x = float(tok)
    except ValueError:
        fail(f"bad number {tok.decode('latin-1')!r} in {what}")
    if not math.isfinite(x):
        fail(f"{what} is not finite ({tok.decode('latin-1')})")
    return x


# --- OBJ -----------------------------------------------------------------------------------


def _read_obj(data: bytes, path):
    """v (the first three numbers), vn and f statements; faces' corners as
    v, v/vt, v//vn or v/vt/vn, with 1-based or negative (relative) indices.
    Every other statement is skipped. A regular file is read at once
    (_obj_arrays); any other, and any damaged one, line by line (_obj_lines),
    which names the line of the first problem."""
    avail = hostio.available_host_bytes()
    whole = avail is None or len(data) * OBJ_WHOLE_FILE_BYTES_PER_FILE_BYTE <= avail
    v, vn, vt, c, ct, cn, sizes = (whole and _obj_arrays(data)) or _obj_lines(data, path)
    # Only the vertices faces use, each once per (position, texture coordinate,
    # normal) triple it is used with, as Mitsuba keys them: an OBJ corner pairs a
    # position with the others, clpt's vertices have one of each. Texture
    # coordinates are kept per vertex, and split vertices (at a UV seam), which
    # also matters to the normals computed for a mesh without them (vertex_normals).
    cols = [c] + [x + 1 for x in (ct, cn) if x is not None]  # -1 (none) -> 0
    keys = _row_keys(cols)
    uniq, inverse = np.unique(keys, return_inverse=True, axis=0 if keys.ndim == 2 else None)
    first = np.zeros(len(uniq), dtype=np.int64)
    first[inverse.reshape(-1)] = np.arange(len(c))  # a corner of each unique vertex
    tris = fan_polygons(inverse.reshape(-1), sizes)
    uv = None
    if ct is not None:
        k = ct[first]
        uv = np.where((k >= 0)[:, None], vt[np.maximum(k, 0)] if len(vt) else 0.0, 0.0)
    return v[c[first]], tris, (None if cn is None else vn[cn[first]]), uv


def _row_keys(cols):
    """One int64 per row of the index columns when their ranges' product fits
    (a fast np.unique), else the (rows, k) array itself."""
    if len(cols) == 1:
        return cols[0]
    spans = [int(x.max()) + 1 for x in cols[1:]]
    if (int(cols[0].max()) + 1) * math.prod(spans) < 2 ** 62:
        key = cols[0].copy()
        for x, span in zip(cols[1:], spans):
            key = key * span + x
        return key
    return np.stack(cols, axis=1)


def _obj_arrays(data: bytes):
    """(positions, normals, corners' vertex, texture coordinate and normal
    indices (None where no corner has one), polygon sizes)
    of a regular OBJ file, parsed a statement kind at a time by numpy: one
    space after each keyword, no line starting with white space, vertices of 3
    numbers, every corner of the same form, no relative indices. None for any
    other file, or a damaged one (which _obj_lines reads, and names the fault)."""
    if b"\t" in data:
        return None
    lines = data.split(b"\n")
    if any(ln[:1] == b" " for ln in lines):
        return None
    v = [ln for ln in lines if ln[:2] == b"v "]
    vn = [ln for ln in lines if ln[:3] == b"vn "]
    vt = [ln for ln in lines if ln[:3] == b"vt "]
    f = b" ".join(ln for ln in lines if ln[:2] == b"f ").split()
    if not v or not f:
        return None
    try:
        pos, nrm = _obj_numbers(v), _obj_numbers(vn)
        starts = [i for i, t in enumerate(f) if t == b"f"]
        sizes = np.diff(np.array(starts + [len(f)], dtype=np.int64)) - 1
        if sizes.min() < 3:
            return None
        corners = [t for t in f if t != b"f"]
        slashes, double = corners[0].count(b"/"), b"//" in corners[0]
        joined = b" ".join(corners)
        if joined.count(b"/") != slashes * len(corners) or joined.count(b"//") != double * len(corners) or \
                slashes > 2:
            return None
        width = {0: 1, 1: 2, 2: 2 if double else 3}[slashes]
        parts = joined.replace(b"/", b" ").split()
        if len(parts) != width * len(corners):
            return None
        idx = np.array(list(map(int, parts)), dtype=np.int64).reshape(-1, width) - 1
    except (ValueError, OverflowError):
        return None
    c = idx[:, 0]
    cn = idx[:, -1] if slashes == 2 else None
    ct = idx[:, 1] if slashes == 1 or (slashes == 2 and not double) else None
    n_vt = sum(1 for ln in lines if ln[:2] == b"vt" and ln[2:3] in b" \r")
    tex = _obj_uvs(vt)
    if tex is None or len(tex) != n_vt:
        return None
    if pos is None or (vn and nrm is None) or (c < 0).any() or (c >= len(pos)).any() or \
            (cn is not None and (nrm is None or (cn < 0).any() or (cn >= len(nrm)).any())) or \
            (ct is not None and ((ct < 0).any() or (ct >= n_vt).any())):
        return None
    return pos, np.zeros((0, 3)) if nrm is None else nrm, tex, c, ct, cn, sizes


def _obj_uvs(rows):
    """(N, 2) finite u, v of `vt` rows of 1 to 3 numbers (a missing v is 0), or None."""
    try:
        out = np.array([(lambda t: (float(t[1]), float(t[2]) if len(t) > 2 else 0.0))(ln.split())
                        for ln in rows if 2 <= len(ln.split()) <= 4], dtype=np.float64).reshape(-1, 2)
    except ValueError:
        return None
    return out if len(out) == len(rows) and np.isfinite(out).all() else None


def _obj_numbers(rows):
    """(N, 3) finite numbers of `v` or `vn` rows of exactly 3 numbers, or None
    (no rows, or any other)."""
    tok = b" ".join(rows).split()
    if not rows or len(tok) != 4 * len(rows):
        return None
    del tok[::4]  # the keywords
    out = np.array(list(map(float, tok)), dtype=np.float64).reshape(-1, 3)
    return out if np.isfinite(out).all() else None


def _obj_lines(data: bytes, path):
    """What _obj_arrays gives, for any OBJ file, line by line; a MeshError at
    the first line that is wrong. A corner without a texture coordinate has
    index -1 (when others have one)."""
    verts, norms, texs = array("d"), array("d"), array("d")
    corners, corner_normals, sizes, face_lines = array("q"), array("q"), array("q"), array("q")
    corner_uvs = array("q")
    all_normals, any_uv, n_vt = True, False, 0
    for lineno, line in enumerate(io.BytesIO(data), 1):
        tok = line.split()
        if not tok or tok[0][:1] == b"#":
            continue

        def fail(reason):
            raise MeshError(f"{path}:{lineno}: {reason}")

        kw = tok[0]
        if kw in (b"v", b"vn"):
            if len(tok) < 4:
                fail(f"'{kw.decode()}' needs 3 numbers (got {len(tok) - 1})")
            what = "a vertex" if kw == b"v" else "a normal"
            (verts if kw == b"v" else norms).extend(_finite_number(x, fail, what) for x in tok[1:4])
        elif kw == b"vt":
            if not 2 <= len(tok) <= 4:
                fail(f"'vt' needs 1 to 3 numbers (got {len(tok) - 1})")
            texs.extend(_finite_number(x, fail, "a texture coordinate") for x in (tok[1:3] + [b"0"])[:2])
            n_vt += 1
        elif kw == b"f":
            if len(tok) < 4:
                fail(f"a face needs at least 3 vertices (got {len(tok) - 1})")
            nv, nn = len(verts) // 3, len(norms) // 3
            for c in tok[1:]:
                parts = c.split(b"/")
                if len(parts) > 3:
                    fail(f"bad face corner {c.decode('latin-1')!r} (v, v/vt, v//vn or v/vt/vn)")
                corners.append(_obj_index(parts[0], nv, fail, "vertex", c))
                if len(parts) >= 2 and parts[1]:
                    any_uv = True
                    corner_uvs.append(_obj_index(parts[1], n_vt, fail, "texture coordinate", c))
                else:
                    corner_uvs.append(-1)
                if len(parts) == 3 and parts[2]:
                    corner_normals.append(_obj_index(parts[2], nn, fail, "normal", c))
                else:
                    all_normals = False
                    corner_normals.append(-1)
            sizes.append(len(tok) - 1)
            face_lines.append(lineno)
    if not sizes:
        raise MeshError(f"{path}: the file has no faces")
    c = np.frombuffer(corners, dtype=np.int64)
    cn = np.frombuffer(corner_normals, dtype=np.int64)
    ct = np.frombuffer(corner_uvs, dtype=np.int64)
    sizes = np.frombuffer(sizes, dtype=np.int64)
    nv, nn = len(verts) // 3, len(norms) // 3
    for arr, count, what, plural in ((c, nv, "vertex", "vertices"), (cn, nn, "normal", "normals"),
                                     (ct, n_vt, "texture coordinate", "texture coordinates")):
        bad = np.flatnonzero(arr >= count)
        if len(bad):
            face = int(np.searchsorted(np.cumsum(sizes), bad[0], side="right"))
            raise MeshError(f"{path}:{face_lines[face]}: {what} {arr[bad[0]] + 1} does not exist "
                            f"(the file has {count} {plural})")
    v = np.frombuffer(verts, dtype=np.float64).reshape(-1, 3)
    vn = np.frombuffer(norms, dtype=np.float64).reshape(-1, 3)
    vt = np.frombuffer(texs, dtype=np.float64).reshape(-1, 2)
    return v, vn, vt, c, (ct if any_uv else None), (cn if all_normals else None), sizes


def _obj_index(tok: bytes, count: int, fail, what, corner) -> int:
    """A 0-based index from an OBJ index (1-based, or negative: from the last
    defined so far); one past the end is checked once the whole file is read."""
    try:
        i = int(tok)
    except ValueError:
        fail(f"bad {what} index {tok.decode('latin-1')!r} in face corner {corner.decode('latin-1')!r}")
    if i == 0 or i < -count or i > MAX_INDEX:
        fail(f"{what} index {i} does not exist (indices start at 1; -1 is the last {what} so far, of {count})")
    return i - 1 if i > 0 else count + i


# --- PLY -----------------------------------------------------------------------------------

PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
             "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
             "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
FACE_LISTS = ("vertex_indices", "vertex_index")


class _Element:
    def __init__(self, name, count, line):
        self.name, self.count, self.line = name, count, line
        self.props: list[tuple] = []  # (name, type) or (name, count type, item type)

    @property
    def face_list(self):
        """The list property of vertex indices (of a face element), or None."""
        return next((p for p in self.props if len(p) == 3 and p[0] in FACE_LISTS), None)

    @property
    def has_lists(self):
        return any(len(p) == 3 for p in self.props)

    def dtype(self, order):
        return np.dtype([(n, order + PLY_TYPES[t]) for n, t in self.props])


def _ply_header(data: bytes, path):
    """(format, elements, offset of the body)."""
    end = re.search(rb"(^|\n)end_header[ \t]*\r?\n", data[:MAX_PLY_HEADER_BYTES])
    if not data.startswith(b"ply"):
        raise MeshError(f"{path}:1: cannot read the PLY file: it does not start with 'ply'")
    if end is None:
        raise MeshError(f"{path}: header: no 'end_header' line in the first {MAX_PLY_HEADER_BYTES} bytes")
    fmt, elements = None, []
    lines = data[:end.start()].decode("latin-1").split("\n")
    for lineno, line in enumerate(lines, 1):
        tok = line.split()

        def fail(reason):
            raise MeshError(f"{path}:{lineno}: header: {reason}")

        if lineno == 1:
            if tok != ["ply"]:
                fail("the first line must be 'ply'")
            continue
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format":
            if len(tok) != 3 or tok[1] not in PLY_FORMATS or tok[2] != "1.0":
                fail(f"bad format line {line.strip()!r} (format ascii|binary_little_endian|binary_big_endian 1.0)")
            fmt = tok[1]
        elif tok[0] == "element":
            if len(tok) != 3 or not tok[2].isdigit():
                fail(f"bad element line {line.strip()!r} (element NAME COUNT)")
            elements.append(_Element(tok[1], int(tok[2]), lineno))
        elif tok[0] == "property":
            if not elements:
                fail("a property before any element")
            if tok[-1] in [p[0] for p in elements[-1].props]:
                fail(f"property '{tok[-1]}' is given twice")
            if len(tok) == 3 and tok[1] in PLY_TYPES:
                elements[-1].props.append((tok[2], tok[1]))
            elif len(tok) == 5 and tok[1] == "list" and tok[2] in PLY_TYPES and tok[3] in PLY_TYPES:
                if PLY_TYPES[tok[2]][0] == "f":
                    fail(f"a list's count must be an integer type (got {tok[2]})")
                elements[-1].props.append((tok[4], tok[2], tok[3]))
            else:
                fail(f"bad property line {line.strip()!r} (property TYPE NAME or property list TYPE TYPE NAME)")
        else:
            fail(f"unknown header line {line.strip()!r}")
    if fmt is None:
        raise MeshError(f"{path}: header: no format line")
    return fmt, elements, end.end()


def _read_ply(data: bytes, path):
    fmt, elements, off = _ply_header(data, path)
    by_name = {e.name: e for e in elements}
    for name in ("vertex", "face"):
        if name not in by_name:
            raise MeshError(f"{path}: header: no '{name}' element")
    ve, fe = by_name["vertex"], by_name["face"]
    names = [p[0] for p in ve.props]
    for k in ("x", "y", "z"):
        if k not in names:
            raise MeshError(f"{path}:{ve.line}: header: the vertex element has no '{k}' property")
    if ve.has_lists:
        raise MeshError(f"{path}:{ve.line}: header: vertices with list properties are not supported")
    if fe.face_list is None:
        raise MeshError(f"{path}:{fe.line}: header: the face element has no 'vertex_indices' list")
    if PLY_TYPES[fe.face_list[2]][0] == "f":
        raise MeshError(f"{path}:{fe.line}: header: vertex indices must be integers (got {fe.face_list[2]})")
    if fe.count == 0:
        raise MeshError(f"{path}: the file has no faces")
    reader = _PlyText(data, off, path) if fmt == "ascii" else _PlyBinary(data, off, path, PLY_FORMATS[fmt])
    out = {}
    for e in elements:
        if len(out) == 2:
            break  # what follows is not read
        out_e = reader.element(e, wanted=e is ve or e is fe)
        if out_e is not None:
            out[e.name] = out_e
    pos = out["vertex"]
    has_n, uv_cols = _vertex_layout(ve)
    normals = pos[:, 3:6] if has_n else None
    uv = pos[:, 3 + 3 * has_n:] if uv_cols else None
    corners, sizes, where = out["face"]
    nv = len(pos)
    bad = np.flatnonzero((corners < 0) | (corners >= nv))
    if len(bad):
        face = int(np.searchsorted(np.cumsum(sizes), bad[0], side="right"))
        raise MeshError(f"{path}{where(face)}: face {face} has vertex index {corners[bad[0]]}, "
                        f"out of range (the file has {nv} vertices)")
    return pos[:, :3], fan_polygons(corners, sizes), normals, uv


# A PLY vertex's texture coordinates: the first of these pairs it has (Mitsuba's names).
PLY_UV_NAMES = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))


def _vertex_layout(e: _Element):
    """(whether the vertices have normals, the names of their texture coordinates or ())."""
    names = [p[0] for p in e.props]
    has_n = all(k in names for k in ("nx", "ny", "nz"))
    return has_n, next((pair for pair in PLY_UV_NAMES if all(k in names for k in pair)), ())


def _vertex_columns(e: _Element):
    """The vertex properties read, in order: x y z [nx ny nz] [u v]."""
    names = [p[0] for p in e.props]
    has_n, uv = _vertex_layout(e)
    cols = ["x", "y", "z"] + (["nx", "ny", "nz"] if has_n else []) + list(uv)
    return [names.index(c) for c in cols]


class _PlyText:
    """The body of an ASCII PLY file, one record per line (blank lines skipped)."""

    def __init__(self, data, off, path):
        self.lines = enumerate(io.BytesIO(data[off:]), data[:off].count(b"\n") + 1)
        self.path = path

    def _records(self, e):
        n, lineno = 0, 0
        if e.count == 0:
            return
        for lineno, line in self.lines:
            tok = line.split()
            if tok:
                yield lineno, tok
                n += 1
                if n == e.count:
                    return
        self._fail(lineno, f"the file ends after {n} of its {e.count} {e.name} records")

    def element(self, e: _Element, wanted: bool):
        if e.name == "vertex" and wanted:
            cols = _vertex_columns(e)
            vals = array("d")  # grows with the lines read: nothing is allocated on the header's word
            for lineno, tok in self._records(e):
                if len(tok) != len(e.props):
                    self._fail(lineno, f"a vertex has {len(tok)} values, the header says {len(e.props)}")
                vals.extend(_finite_number(tok[i], lambda r: self._fail(lineno, r), "a vertex") for i in cols)
            return np.frombuffer(vals, dtype=np.float64).reshape(-1, len(cols))
        corners, sizes, lines = array("q"), array("q"), array("q")
        face_list = e.face_list if wanted else None
        for lineno, tok in self._records(e):
            i = 0
            for prop in e.props:
                if i >= len(tok):
                    self._fail(lineno, f"a {e.name} record ends before its property '{prop[0]}'")
                if len(prop) == 2:
                    i += 1
                    continue
                k = self._int(tok[i], lineno, f"the count of '{prop[0]}'")
                if k < 0 or i + 1 + k > len(tok):
                    self._fail(lineno, f"'{prop[0]}' has {k} items but the line has {len(tok) - i - 1} more "
                                       "values")
                if prop is face_list:
                    if k < 3:
                        self._fail(lineno, f"a face has {k} vertices (a polygon needs at least 3)")
                    corners.extend(self._int(t, lineno, "a vertex index") for t in tok[i + 1:i + 1 + k])
                    sizes.append(k)
                    lines.append(lineno)
                i += 1 + k
            if i != len(tok):
                self._fail(lineno, f"a {e.name} record has {len(tok) - i} values more than its properties")
        if not wanted:
            return None
        return (np.frombuffer(corners, dtype=np.int64), np.frombuffer(sizes, dtype=np.int64),
                lambda f: f":{lines[f]}")

    def _int(self, tok, lineno, what):
        try:
            i = int(tok)
        except ValueError:
            self._fail(lineno, f"bad integer {tok.decode('latin-1')!r} for {what}")
        if abs(i) > MAX_INDEX:
            self._fail(lineno, f"{what} {i} is out of range")
        return i

    def _fail(self, lineno, reason):
        raise MeshError(f"{self.path}:{lineno}: {reason}")


class _PlyBinary:
    """The body of a binary PLY file. Every count is checked against the bytes
    left before anything is read or allocated."""

    def __init__(self, data, off, path, order):
        self.data, self.off, self.path, self.order = data, off, path, order

    def _fail(self, at, reason):
        raise MeshError(f"{self.path}: byte {at}: {reason}")

    def _take(self, e, size, what):
        """Offset of the next `size` bytes (then skipped), which must be there."""
        left = len(self.data) - self.off
        if size > left:
            self._fail(self.off, f"the file ends inside the {e.name} element ({what}: {size} bytes needed, "
                                 f"{left} left)")
        at = self.off
        self.off += size
        return at

    def element(self, e: _Element, wanted: bool):
        if not e.has_lists:
            dt = e.dtype(self.order)
            at = self._take(e, e.count * dt.itemsize, f"{e.count} records of {dt.itemsize} bytes")
            if not wanted:
                return None
            if e.name != "vertex":
                raise MeshError(f"{self.path}:{e.line}: header: the face element has no list of vertex indices")
            rec = np.frombuffer(self.data, dt, e.count, at)
            out = np.stack([rec[e.props[i][0]].astype(np.float64) for i in _vertex_columns(e)], axis=1)
            bad = np.flatnonzero(~np.isfinite(out).all(axis=1))
            if len(bad):
                self._fail(at + int(bad[0]) * dt.itemsize, f"vertex {bad[0]} is not finite "
                                                         f"({', '.join(f'{x:g}' for x in out[bad[0]])})")
            return out
        face_list = e.face_list if wanted else None
        out = self._fixed(e, face_list)
        if out is None:
            out = self._walk(e, face_list)
        return out if wanted else None

    def _counts_of_first(self, e):
        """The dtype of e's records if every list had the length it has in the first record."""
        fields, at = [], self.off
        for j, prop in enumerate(e.props):
            t = np.dtype(self.order + PLY_TYPES[prop[1]])
            if at + t.itemsize > len(self.data):
                return None
            if len(prop) == 2:
                fields.append((f"s{j}", t))
            else:
                k = int(np.frombuffer(self.data, t, 1, at)[0])
                item = np.dtype(self.order + PLY_TYPES[prop[2]])
                if k < 0 or k > len(self.data):
                    return None
                fields += [(f"n{j}", t), (f"l{j}", item, (k,))]
                at += k * item.itemsize
            at += t.itemsize
        return np.dtype(fields)

    def _fixed(self, e, face_list):
        """Records read at once when every list has the same length (a file of
        triangles, or of quads); None when not."""
        dt = self._counts_of_first(e)
        if dt is None or e.count * dt.itemsize > len(self.data) - self.off:
            return None
        rec = np.frombuffer(self.data, dt, e.count, self.off)
        for j, prop in enumerate(e.props):
            if len(prop) == 3 and not (rec[f"n{j}"] == dt[f"l{j}"].shape[0]).all():
                return None
        at = self._take(e, e.count * dt.itemsize, "")
        if face_list is None:
            return ()
        j = e.props.index(face_list)
        k = dt[f"l{j}"].shape[0]
        if k < 3:
            self._fail(at, f"face 0 has {k} vertices (a polygon needs at least 3)")
        corners = rec[f"l{j}"].astype(np.int64).reshape(-1)
        return corners, np.full(e.count, k, dtype=np.int64), lambda f: f": byte {at + f * dt.itemsize}"

    def _walk(self, e, face_list):
        """Records one by one (lists of different lengths)."""
        corners, sizes, offsets = array("q"), array("q"), array("q")
        for r in range(e.count):
            start = self.off
            for prop in e.props:
                t = np.dtype(self.order + PLY_TYPES[prop[1]])
                at = self._take(e, t.itemsize, f"{e.name} {r}, '{prop[0]}'")
                if len(prop) == 2:
                    continue
                k = int(np.frombuffer(self.data, t, 1, at)[0])
                item = np.dtype(self.order + PLY_TYPES[prop[2]])
                if k < 0:
                    self._fail(at, f"{e.name} {r}: '{prop[0]}' has {k} items")
                at = self._take(e, k * item.itemsize, f"{e.name} {r}, '{prop[0]}' of {k} items")
                if prop is face_list:
                    if k < 3:
                        self._fail(start, f"face {r} has {k} vertices (a polygon needs at least 3)")
                    corners.extend(np.frombuffer(self.data, item, k, at).astype(np.int64).tolist())
                    sizes.append(k)
                    offsets.append(start)
        if face_list is None:
            return ()
        return (np.frombuffer(corners, dtype=np.int64), np.frombuffer(sizes, dtype=np.int64),
                lambda f: f": byte {offsets[f]}")


# --- Mitsuba's serialized meshes ----------------------------------------------------------------
#
# The format (documented in Mitsuba 3's src/shapes/serialized.cpp), little-endian:
# per shape, an uncompressed uint16 0x041C and uint16 version (3 or 4), then a zlib
# stream of: uint32 flags, (version 4) a NUL-terminated UTF-8 name, uint64 vertex and
# triangle counts, the positions (x y z ...), the normals, texture coordinates (u v)
# and vertex colours (r g b) where the flags say so, all float32 or (flag 0x2000)
# float64, and the triangles as uint32 (uint64 past 2^32 vertices). After the last
# shape: each shape's file offset (uint64 in version 4, uint32 in version 3) and a
# uint32 count, read only to find a shape_index other than 0.

SERIALIZED_MAGIC = 0x041C
SERIALIZED_HAS_NORMALS, SERIALIZED_HAS_UVS, SERIALIZED_HAS_COLORS = 0x0001, 0x0002, 0x0008
SERIALIZED_DOUBLE = 0x2000
# zlib's DEFLATE expands at most 1032:1: a header claiming more than this many
# bytes per compressed byte that follows is damaged (or a decompression bomb), and
# is refused before anything is decompressed or allocated.
ZLIB_MAX_RATIO = 1032
MAX_SERIALIZED_NAME = 1 << 16
# Peak memory of reading, per byte of the decompressed stream: the stream, the
# float64 and int64 arrays made from it and check_mesh's copies (float32 positions
# and uint32 triangles become 8-byte values: 2x, held about twice over).
SERIALIZED_READ_BYTES_PER_BYTE = 5


def _read_serialized(data: bytes, path, shape_index: int):
    """(vertices, triangles, normals or None, texture coordinates or None) of one shape of a .serialized
    file. Every fault is a one-line MeshError naming the shape and the byte
    (of the file, or of the shape's decompressed stream)."""
    def fail(at, reason, inner=False):
        where = f"shape {shape_index}, {'uncompressed ' if inner else ''}byte {at}"
        raise MeshError(f"{path}: {where}: {reason}")

    if len(data) < 4:
        fail(0, f"the file has {len(data)} bytes, too few for the header")
    magic, version = struct.unpack_from("<HH", data, 0)
    if magic != SERIALIZED_MAGIC:
        fail(0, f"not a Mitsuba serialized mesh (it starts with 0x{magic:04x}, not 0x{SERIALIZED_MAGIC:04x})")
    if version not in (3, 4):
        fail(2, f"format version {version} is not supported (3 and 4 are)")
    if shape_index < 0:
        raise MeshError(f"{path}: shape_index must be >= 0 (got {shape_index})")
    start, end = 0, len(data)
    if shape_index > 0:
        start, end = _serialized_extent(data, path, version, shape_index)
        at_magic, at_version = struct.unpack_from("<HH", data, start)
        if (at_magic, at_version) != (magic, version):
            fail(start, f"the shape's header is 0x{at_magic:04x} {at_version}, not the file's "
                        f"0x{magic:04x} {version}")
    stream = memoryview(data)[start + 4:end]
    z = zlib.decompressobj()
    out = bytearray()
    fed = []

    def inflate(n):
        """Decompress up to n bytes in all (never more: a bomb stops here);
        whether there were that many."""
        try:
            while len(out) < n:
                chunk = z.decompress(z.unconsumed_tail if fed else stream, n - len(out))
                fed.append(True)
                if not chunk:
                    break
                out.extend(chunk)
        except zlib.error as e:
            fail(start + 4, f"the compressed data is damaged ({e})")
        return len(out) >= n

    head = 4 + (MAX_SERIALIZED_NAME if version == 4 else 0) + 16
    inflate(head)
    if len(out) < 4:
        fail(len(out), "the stream ends inside the header (flags)", inner=True)
    flags = struct.unpack_from("<I", out, 0)[0]
    at = 4
    if version == 4:
        nul = out.find(b"\0", 4)
        if nul < 0:
            fail(4, f"the shape's name has no end (NUL) in {len(out) - 4} bytes", inner=True)
        at = nul + 1
    if len(out) < at + 16:
        fail(len(out), "the stream ends inside the header (vertex and triangle counts)", inner=True)
    n_vert, n_tri = struct.unpack_from("<QQ", out, at)
    at += 16
    real = 8 if flags & SERIALIZED_DOUBLE else 4
    index = 8 if n_vert > 0xFFFFFFFF else 4
    per_vertex = 3 + 3 * bool(flags & SERIALIZED_HAS_NORMALS) + 2 * bool(flags & SERIALIZED_HAS_UVS) \
        + 3 * bool(flags & SERIALIZED_HAS_COLORS)
    need = at + n_vert * per_vertex * real + n_tri * 3 * index
    if need > ZLIB_MAX_RATIO * len(stream) + 64:
        fail(at - 16, f"the header declares {n_vert} vertices and {n_tri} triangles ({need} bytes), more than "
                      f"the {len(stream)} compressed bytes that follow can hold", inner=True)

    avail = hostio.available_host_bytes()
    if avail is not None and need * SERIALIZED_READ_BYTES_PER_BYTE > avail:
        raise MeshError(f"{path}: shape {shape_index}: {n_vert} vertices and {n_tri} triangles need about "
                        f"{need * SERIALIZED_READ_BYTES_PER_BYTE / 2**30:.1f} GiB of memory to read and "
                        f"{avail / 2**30:.1f} GiB are available; too large")
    if not inflate(need):
        fail(len(out), f"the stream ends after {len(out)} of its {need} bytes (the header declares {n_vert} "
                       f"vertices and {n_tri} triangles)", inner=True)
    ft = np.dtype("<f8" if real == 8 else "<f4")

    def take(count, dtype, what):
        """The next count rows of 3 (offset, float64 or int64 array), each
        row checked by what(rows) -> mask of bad rows, named by its offset."""
        nonlocal at
        a = np.frombuffer(out, dtype, count * 3, at).reshape(count, 3)
        first, at = at, at + count * 3 * dtype.itemsize
        a = a.astype(np.int64 if dtype.kind == "u" else np.float64)
        bad = np.flatnonzero(what[0](a))
        if len(bad):
            i = int(bad[0])
            fail(first + i * 3 * dtype.itemsize, f"{what[1]} {i} {what[2](a[i])}", inner=True)
        return a

    def listed(row):
        return ", ".join(f"{x:g}" for x in row)

    not_finite = lambda a: ~np.isfinite(a).all(axis=1)  # noqa: E731
    v = take(n_vert, ft, (not_finite, "vertex", lambda r: f"is not finite ({listed(r)})"))
    n = None
    if flags & SERIALIZED_HAS_NORMALS:
        n = take(n_vert, ft, (lambda a: not_finite(a) | ~(np.abs(a).max(axis=1, initial=0) > 0), "normal",
                              lambda r: f"is zero or not finite ({listed(r)})"))
    uv = None
    if flags & SERIALIZED_HAS_UVS:
        uv = np.frombuffer(out, ft, n_vert * 2, at).reshape(n_vert, 2).astype(np.float64)
        bad = np.flatnonzero(~np.isfinite(uv).all(axis=1))
        if len(bad):
            fail(at + int(bad[0]) * 2 * real, f"texture coordinate {int(bad[0])} is not finite "
                                              f"({listed(uv[bad[0]])})", inner=True)
        at += n_vert * 2 * real
    at += n_vert * real * 3 * bool(flags & SERIALIZED_HAS_COLORS)
    t = take(n_tri, np.dtype("<u8" if index == 8 else "<u4"),
             (lambda a: (a >= n_vert).any(axis=1), "triangle",
              lambda r: f"has vertex index {int(r.max())}, out of range (the shape has {n_vert} vertices)"))
    return v, t, n, uv


def _serialized_extent(data: bytes, path, version: int, shape_index: int):
    """(start, end) in the file of shape shape_index, from the dictionary of
    offsets at its end."""
    width = 8 if version == 4 else 4
    size = len(data)
    if size < 8:
        raise MeshError(f"{path}: byte {size}: the file ends before its dictionary of shapes")
    count = struct.unpack_from("<I", data, size - 4)[0]
    table = size - 4 - count * width
    if count == 0 or table < 4:
        raise MeshError(f"{path}: byte {size - 4}: the dictionary of shapes lists {count} shapes, "
                        f"which the {size}-byte file cannot hold")
    if shape_index >= count:
        raise MeshError(f"{path}: shape_index {shape_index} is out of range (the file holds {count} shapes, "
                        f"0 to {count - 1})")
    # Python ints: an offset of 2^63 or more must not wrap to a negative int64.
    offsets = [int(o) for o in np.frombuffer(data, "<u8" if width == 8 else "<u4", count, table)]
    start = offsets[shape_index]
    if start + 4 > table:
        raise MeshError(f"{path}: byte {table + shape_index * width}: shape {shape_index} starts at byte {start}, "
                        f"beyond the shapes' data (which ends at byte {table})")
    later = offsets[shape_index + 1:]
    end = later[0] if later and start < later[0] <= table else table
    return start, end


# --- vertex normals ------------------------------------------------------------------------------


def vertex_normals(vertices, triangles):
    """Smooth per-vertex normals of a mesh that has none, as Mitsuba 3
    computes them (Mesh::recompute_vertex_normals, after Thuermer and
    Wuethrich, "Computing vertex normals from polygonal facets", JGT 1998):
    the sum over a vertex's triangles of each one's unit normal weighted by its
    angle at that vertex, normalized. Angles, not areas, so that a vertex's
    normal does not depend on how the surface around it is cut into triangles.
    Triangles of zero area add nothing; a vertex with no other triangle gets
    Mitsuba's placeholder (1, 0, 0). Triangles face by their winding, so the
    normals lie on the side of the geometric normal (the right-hand rule).
    In float64, where Mitsuba works in float32."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    p = [v[t[:, k]] for k in range(3)]
    n = cross_rows(p[1] - p[0], p[2] - p[0])
    length = norm_rows(n)
    keep = length > 0
    t, p, n = t[keep], [x[keep] for x in p], n[keep] / length[keep, None]
    out = np.zeros_like(v)
    for k in range(3):
        a, b = p[(k + 1) % 3] - p[k], p[(k + 2) % 3] - p[k]
        angle = _unit_angle(a / norm_rows(a)[:, None], b / norm_rows(b)[:, None])
        for axis in range(3):
            out[:, axis] += np.bincount(t[:, k], n[:, axis] * angle, minlength=len(v))
    length = norm_rows(out)
    ok = length > 0
    out[ok] /= length[ok, None]
    out[~ok] = (1.0, 0.0, 0.0)
    return out


def _unit_angle(a, b):
    """The angle between rows of unit vectors, accurate near 0 and pi (where
    acos of the dot product is not): 2 asin(|a - b| / 2), or its supplement."""
    dot = np.einsum("ij,ij->i", a, b)
    near = 2 * np.arcsin(np.minimum(norm_rows(a - b) / 2, 1.0))
    far = np.pi - 2 * np.arcsin(np.minimum(norm_rows(a + b) / 2, 1.0))
    return np.where(dot < 0, far, near)


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
