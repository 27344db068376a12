"""Triangle meshes from OBJ and PLY files, and their transforms.

The readers here are clpt's own, so that every damaged file is refused with
one line naming the file, the place and the reason (a line of an OBJ or ASCII
PLY file, a byte offset in a binary PLY file, a vertex or face by number), and
so that sizes are checked before anything is allocated: the memory reading
needs against what the machine has, and the counts a PLY header declares
against the bytes that follow it. They read positions, polygons and per-vertex
normals, and nothing else (texture coordinates, colours, materials, groups and
other elements are skipped). Polygons are fanned into triangles from their
first vertex, in order. Nothing is merged, reordered or repaired, so triangle
i of the file is triangle i here, less the degenerate ones, which are dropped
with one warning giving their count.

Every problem with a file is a ``MeshError`` (a SceneError, so a ValueError).
"""

from __future__ import annotations

import io
import math
import os
import re
import warnings
from array import array
from pathlib import Path

import numpy as np

from .scene import SceneError, open_regular_file

FORMATS = ("obj", "ply")

# What reading needs at its peak, in bytes per byte of the file (measured with
# tracemalloc on a 160,000-triangle sphere, normals and not): the file itself,
# the arrays built from it and check_mesh's copies. A binary PLY is the
# densest (9.5: float32 and int32 become float64 and int64); an OBJ read line
# by line 3.3, an ASCII PLY 3.9. OBJ's whole-file parse is faster but holds
# every token as a Python object (11 to 14): it is taken only where that fits.
READ_BYTES_PER_FILE_BYTE = {"obj": 4, "ply": 10}
OBJ_WHOLE_FILE_BYTES_PER_FILE_BYTE = 15
MAX_PLY_HEADER_BYTES = 1 << 16
MAX_INDEX = 2 ** 62  # larger indices and counts cannot be in range of any file that fits in memory


class MeshError(SceneError):
    """A mesh file or array is missing, unreadable or malformed; the one-line
    message names it. A SceneError (and so a ValueError)."""


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


def read_mesh(path):
    """(vertices float64 (N,3), triangles int64 (M,3), normals float64 (N,3) or None).

    Normals are the file's per-vertex normals, normalized, or None when it
    has none (or only some of its faces have them, in an OBJ file)."""
    p = Path(path)
    fmt = p.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise MeshError(f"{path}: unsupported mesh format {p.suffix or '(no extension)'!r}; "
                        f"supported: {', '.join('.' + f for f in FORMATS)}")
    data = _read_bytes(p, path, fmt)
    v, t, n = (_read_obj if fmt == "obj" else _read_ply)(data, path)
    return check_mesh(v, t, n, source=str(path))


def _read_bytes(p: Path, name, fmt) -> bytes:
    """The file's bytes: a regular file whose reading fits in memory (checked
    before reading)."""
    from .preflight import available_host_bytes

    try:
        f = open_regular_file(p, name, "mesh file")
    except MeshError:
        raise
    except SceneError as e:
        raise MeshError(str(e)) from None
    with f:
        size = os.fstat(f.fileno()).st_size
        need = size * READ_BYTES_PER_FILE_BYTE[fmt]
        avail = available_host_bytes()
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
    from .preflight import available_host_bytes

    avail = available_host_bytes()
    whole = avail is None or len(data) * OBJ_WHOLE_FILE_BYTES_PER_FILE_BYTE <= avail
    v, vn, c, cn, sizes = (whole and _obj_arrays(data)) or _obj_lines(data, path)
    # Only the vertices faces use, each once per normal it is used with (an OBJ
    # corner pairs a position with a normal; clpt's vertices have one of each).
    key = c if cn is None else c * (len(vn) + 1) + cn  # one integer per (vertex, normal) pair
    uniq, inverse = np.unique(key, return_inverse=True)
    if cn is None:
        return v[uniq], fan_polygons(inverse.reshape(-1), sizes), None
    return v[uniq // (len(vn) + 1)], fan_polygons(inverse.reshape(-1), sizes), vn[uniq % (len(vn) + 1)]


def _obj_arrays(data: bytes):
    """(positions, normals, corners' vertex and normal indices, polygon sizes)
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
    if pos is None or (vn and nrm is None) or (c < 0).any() or (c >= len(pos)).any() or \
            (cn is not None and (nrm is None or (cn < 0).any() or (cn >= len(nrm)).any())):
        return None
    return pos, np.zeros((0, 3)) if nrm is None else nrm, c, cn, sizes


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
    the first line that is wrong."""
    verts, norms = array("d"), array("d")
    corners, corner_normals, sizes, face_lines = array("q"), array("q"), array("q"), array("q")
    all_normals = True
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
        elif kw == b"f":
            if len(tok) < 4:
                fail(f"a face needs at least 3 vertices (got {len(tok) - 1})")
            nv, nn = len(verts) // 3, len(norms) // 3
            for c in tok[1:]:
                parts = c.split(b"/")
                if len(parts) > 3:
                    fail(f"bad face corner {c.decode('latin-1')!r} (v, v/vt, v//vn or v/vt/vn)")
                corners.append(_obj_index(parts[0], nv, fail, "vertex", c))
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
    sizes = np.frombuffer(sizes, dtype=np.int64)
    nv, nn = len(verts) // 3, len(norms) // 3
    for arr, count, what in ((c, nv, "vertex"), (cn, nn, "normal")):
        bad = np.flatnonzero(arr >= count)
        if len(bad):
            face = int(np.searchsorted(np.cumsum(sizes), bad[0], side="right"))
            raise MeshError(f"{path}:{face_lines[face]}: {what} {arr[bad[0]] + 1} does not exist "
                            f"(the file has {count} {'vertices' if what == 'vertex' else 'normals'})")
    v = np.frombuffer(verts, dtype=np.float64).reshape(-1, 3)
    vn = np.frombuffer(norms, dtype=np.float64).reshape(-1, 3)
    return v, vn, c, (cn if all_normals else None), sizes


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
    normals = pos[:, 3:6] if pos.shape[1] == 6 else None
    corners, sizes, where = out["face"]
    nv = len(pos)
    bad = np.flatnonzero((corners < 0) | (corners >= nv))
    if len(bad):
        face = int(np.searchsorted(np.cumsum(sizes), bad[0], side="right"))
        raise MeshError(f"{path}{where(face)}: face {face} has vertex index {corners[bad[0]]}, "
                        f"out of range (the file has {nv} vertices)")
    return pos[:, :3], fan_polygons(corners, sizes), normals


def _vertex_columns(e: _Element):
    names = [p[0] for p in e.props]
    cols = ["x", "y", "z"] + (["nx", "ny", "nz"] if all(k in names for k in ("nx", "ny", "nz")) else [])
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
