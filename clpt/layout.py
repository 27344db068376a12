"""The device layout of every record the host hands to the kernels, defined once.

Each record is a struct; here it is a list of (field, type) pairs, from which
come both a numpy dtype (for packing on the host, in float64 or float32) and
the C typedef and constants the kernels see (``c_source``, stitched in
before kernels/scene.h by clpt/program.py). Offsets follow OpenCL C's rules
(a vector of n elements aligned to n times the element size, n = 3 as 4), so
the two sides agree by construction; tests/test_layout.py checks sizeof and
offsetof against the device itself through a probe kernel.

The scene buffer is an array of ``real4`` (float4, or double4 when
CLPT_DOUBLE), so its records are made of real4 fields only, and each
record's stride in real4 units is ``<PREFIX>_STRIDE`` in C; field k of a
record at real4 index r is at r + ``<PREFIX>_<FIELD>``. Integers (material
ids, primitive ids, record indices, counts) are stored as reals: exact below
2^24 in float builds, which bounds a float scene at 2^24 real4 records.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# OpenCL C scalar types: (numpy type for float builds, for double builds, size).
_SCALARS = {"real": (np.float32, np.float64), "float": (np.float32, np.float32),
            "uint": (np.uint32, np.uint32), "int": (np.int32, np.int32)}
_VECTOR_SIZES = (2, 3, 4, 8, 16)


def _parse(ctype: str):
    """('real', 4) from 'real4'; ('uint', 1) from 'uint'."""
    for base in sorted(_SCALARS, key=len, reverse=True):
        if ctype.startswith(base):
            rest = ctype[len(base):]
            n = int(rest) if rest else 1
            if n != 1 and n not in _VECTOR_SIZES:
                break
            return base, n
    raise ValueError(f"unsupported field type {ctype!r}")


@dataclass(frozen=True)
class Record:
    """A struct crossing to the kernels: C name, macro prefix, fields."""

    name: str
    prefix: str
    fields: tuple  # ((field name, OpenCL C type), ...)
    doc: str = ""

    def _offsets(self, double: bool):
        off, align, out = 0, 1, []
        for fname, ctype in self.fields:
            base, n = _parse(ctype)
            np_t = np.dtype(_SCALARS[base][1 if double else 0])
            slots = 4 if n == 3 else n
            size = np_t.itemsize * slots
            a = size  # OpenCL vectors align to their size, scalars to theirs
            off = -(-off // a) * a
            out.append((fname, np_t, n, slots, off))
            off += size
            align = max(align, a)
        return out, -(-off // align) * align

    def dtype(self, double: bool = False) -> np.dtype:
        fields, size = self._offsets(double)
        return np.dtype({"names": [f for f, *_ in fields],
                         "formats": [(t, (s,)) if s > 1 else t for _, t, _, s, _ in fields],
                         "offsets": [o for *_, o in fields], "itemsize": size})

    def size(self, double: bool = False) -> int:
        return self._offsets(double)[1]

    def offsets(self, double: bool = False) -> dict:
        return {f: o for f, *_, o in self._offsets(double)[0]}

    @property
    def stride(self) -> int:
        """Size in real4 units (records of real4 fields only)."""
        if any(t != "real4" for _, t in self.fields):
            raise ValueError(f"{self.name} is not made of real4 fields")
        return len(self.fields)

    def c_source(self) -> str:
        lines = [f"// {self.doc}"] if self.doc else []
        lines.append("typedef struct {")
        lines += [f"    {t} {f};" for f, t in self.fields]
        lines.append(f"}} {self.name};")
        if all(t == "real4" for _, t in self.fields):
            lines.append(f"#define {self.prefix}_STRIDE {self.stride}")
            lines += [f"#define {self.prefix}_{f.upper()} {k}" for k, (f, _) in enumerate(self.fields)]
        return "\n".join(lines)


def _r4(*names):
    return tuple((n, "real4") for n in names)


MATERIAL = Record("MaterialRec", "MAT", _r4("kd_pd", "ks_ps", "kr_pr", "kt_pt", "le_sides", "params"),
                  "material: kd.rgb, p_diffuse | ks.rgb, p_phong | kr.rgb, p_mirror | kt.rgb, p_refract | "
                  "Le.rgb, two_sided | shininess, ior, nondelta, one_sided")
SPHERE = Record("SphereRec", "SPHERE", _r4("center_radius", "mat"),
                "sphere: center.xyz, radius | material, light + 1 (0: not a light), prim id, 0")
PLANAR = Record("PlanarRec", "PLANAR", _r4("corner_mat", "n_light", "wu_prim", "wv_kind"),
                "quad or triangle: corner.xyz, material | n.xyz, light + 1 (0: not a light) | wu.xyz, prim id | "
                "wv.xyz, kind (>= 0: a smooth triangle, the record index of its vertex normals; KIND_*). "
                "As a BVH item, a sphere: center.xyz, material | radius, 0, 0, light + 1 | 0, 0, 0, prim id | "
                "0, 0, 0, KIND_SPHERE")
PLANE = Record("PlaneRec", "PLANE", _r4("point_mat", "n"), "plane: point.xyz, material | n.xyz, prim id")
LIGHT = Record("LightRec", "LIGHT", _r4("p_kind", "u", "v", "n", "info"),
               "light: p.xyz, kind | u.xyz, 0 | v.xyz, 0 | n.xyz, alias | area, pick probability, alias "
               "probability, material; a mesh light: 0, 0, 0, kind | first triangle record, triangles, 0, 0 | ... | "
               "0, 0, 0, alias | info. Slot j of the lights' alias table (by power) keeps light j with its alias "
               "probability, else gives light alias")
CAUSTIC = Record("CausticRec", "CAUSTIC", _r4("sphere"), "caustic caster: bounding sphere center.xyz, radius")
# Wide BVH nodes (clpt/bvh.py WIDTH = 8 children): rows of 8 reals, each two
# real4 records, read as one real8; SoA leaf blocks of up to 4 items: rows
# of 4 reals, one real4 each.
_ROWS8 = lambda *rows: _r4(*[f"{r}_{h}" for r in rows for h in ("a", "b")])
BVH_NODE = Record("BvhNode", "BVH", _ROWS8("lo_x", "hi_x", "lo_y", "hi_y", "lo_z", "hi_z", "ptr", "count"),
                  "wide BVH node: 8 children's boxes as rows of 8 reals lo.x | hi.x | lo.y | hi.y | lo.z | hi.z, "
                  "then their pointers | counts (count > 0: a leaf block of count items at record pointer; "
                  "0: a node at record pointer; -1: an empty slot)")
BVH_LEAF_WIDTH = 4   # items a leaf block holds (clpt/bvh.py LEAF_WIDTH): one real4 a row
BVH_LEAF = Record("BvhLeaf", "BVHL", _r4("px", "py", "pz", "nx", "ny", "nz", "ux", "uy", "uz", "vx", "vy", "vz",
                                         "kind", "mat", "light", "prim"),
                  "BVH leaf block: up to BVHL_WIDTH (4) items as rows of 4 reals, their PlanarRec fields: corner "
                  "p.xyz | normal n.xyz | dual wu.xyz | dual wv.xyz (a sphere: centre in p, radius in n.x) | kind "
                  "(PlanarRec wv.w; ITEM_EMPTY for an empty slot) | material | light + 1 | primitive id")
NORMALS = Record("NormalsRec", "NORMALS", _r4("n0", "n1", "n2"), "vertex normals of a smooth triangle")
LIGHT_TRI = Record("LightTriRec", "LTRI", _r4("p_alias", "u_prob", "v"),
                   "triangle of a mesh light: v0.xyz, alias | v1 - v0, alias probability | v2 - v0, 0")

SCENE_RECORDS = (MATERIAL, SPHERE, PLANAR, PLANE, LIGHT, CAUSTIC, BVH_NODE, BVH_LEAF, NORMALS, LIGHT_TRI)

# Light kinds in LIGHT.p_kind.
KIND_QUAD, KIND_TRIANGLE, KIND_SPHERE, KIND_MESH = 0, 1, 2, 3
# Primitive kinds in PLANAR.wv_kind.w (a smooth triangle has its normals' record index there instead).
ITEM_FLAT_TRIANGLE, ITEM_QUAD, ITEM_SPHERE = -1, -2, -3
ITEM_EMPTY = -4  # an empty slot of a BVH leaf block


def c_source() -> str:
    """The C side of the layout: typedefs and constants for every record."""
    parts = ["// Generated by clpt/layout.py: the records the host packs (do not edit)."]
    parts += [r.c_source() for r in SCENE_RECORDS]
    parts += [f"#define KIND_QUAD {KIND_QUAD}", f"#define KIND_TRIANGLE {KIND_TRIANGLE}",
              f"#define KIND_SPHERE {KIND_SPHERE}", f"#define KIND_MESH {KIND_MESH}",
              f"#define ITEM_FLAT_TRIANGLE {ITEM_FLAT_TRIANGLE}", f"#define ITEM_QUAD {ITEM_QUAD}",
              f"#define ITEM_SPHERE {ITEM_SPHERE}", f"#define ITEM_EMPTY {ITEM_EMPTY}",
              f"#define BVHL_WIDTH {BVH_LEAF_WIDTH}"]
    return "\n".join(parts) + "\n"
