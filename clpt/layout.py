"""The device layout of everything the host hands to the kernels, defined once.

Two kinds of record, each a list of named fields from which come both the
numpy side (the host packs and fills by field name) and the C side (stitched
in before kernels/scene.h by clpt/program.py, ``c_source``):

- ``Rows``: the scene's records, in the one array of ``real4`` (float4, or
  double4 when CLPT_DOUBLE) the kernels read. A record is a run of rows,
  each field one real4 row (or a real8, two rows: a BVH node's 8 children).
  The C side gets ``<PREFIX>_STRIDE`` (rows per record) and one constant per
  field, ``<PREFIX>_<FIELD>``, its row within the record: kernels read field
  f of the record at row r as ``scene_rec(sc, r + <PREFIX>_<F>)``, never at a
  number (tests/test_layout.py fails on a literal offset and renders with the
  fields reordered). Integers (material ids, primitive ids, record indices,
  counts) are stored as reals: exact below 2^24 in float builds, which bounds
  a float scene at 2^24 real4 records. What the four components of a row
  hold is each record's doc.
- ``Record``: a C struct the kernels take by value through a ``__constant``
  pointer: the launch records (``TraceLaunch``, ``PhotonLaunch``) and the
  records nested in them (scene counts, camera, photon map). Offsets follow
  OpenCL C's rules (a vector of n elements aligned to n times the element
  size, n = 3 as 4; a struct to its widest member), so the numpy dtype and
  the C typedef agree by construction; tests/test_layout.py checks sizeof
  and offsetof against the device. A field added here is a named member on
  both sides, with no other change.

Code that packs records refers to them as ``layout.NAME`` (not a copy bound
at import), so a test can reorder a record's fields and see the image stay.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

# OpenCL C scalar types: (numpy type for float builds, for double builds).
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


# --- structs: the launch records ----------------------------------------------------------
@dataclass(frozen=True)
class Record:
    """A C struct crossing to the kernels: name, fields ((name, OpenCL C type
    or a nested Record), ...)."""

    name: str
    fields: tuple
    doc: str = ""

    def _layout(self, double: bool):
        """[(field, numpy dtype, offset)], size, alignment."""
        return _record_layout(self, double)

    def dtype(self, double: bool = False) -> np.dtype:
        return _record_dtype(self, double)

    def size(self, double: bool = False) -> int:
        return self._layout(double)[1]

    def alignment(self, double: bool = False) -> int:
        return self._layout(double)[2]

    def offsets(self, double: bool = False) -> dict:
        return {f: o for f, _, o in self._layout(double)[0]}

    def zeros(self, double: bool = False) -> np.ndarray:
        """One record, zero-filled, to fill by field name."""
        return np.zeros((), dtype=self.dtype(double))

    def c_source(self) -> str:
        lines = [f"// {self.doc}"] if self.doc else []
        lines.append("typedef struct {")
        lines += [f"    {t.name if isinstance(t, Record) else t} {f};" for f, t in self.fields]
        lines.append(f"}} {self.name};")
        return "\n".join(lines)


# A record's layout and dtype are made once (every launch record is a fresh
# zeros() of one: the nested TraceLaunch took 0.25 ms to lay out, a fifth of
# the host's time between two launches).
@functools.lru_cache(maxsize=None)
def _record_layout(rec: Record, double: bool):
    off, align, out = 0, 1, []
    for fname, ftype in rec.fields:
        if isinstance(ftype, Record):
            dt, a = ftype.dtype(double), ftype.alignment(double)
        else:
            base, n = _parse(ftype)
            np_t = np.dtype(_SCALARS[base][1 if double else 0])
            slots = 4 if n == 3 else n
            dt = np.dtype((np_t, (slots,))) if slots > 1 else np_t
            a = np_t.itemsize * slots  # OpenCL vectors align to their size, scalars to theirs
        off = -(-off // a) * a
        out.append((fname, dt, off))
        off += dt.itemsize
        align = max(align, a)
    return out, -(-off // align) * align, align


@functools.lru_cache(maxsize=None)
def _record_dtype(rec: Record, double: bool) -> np.dtype:
    fields, size, _ = rec._layout(double)
    return np.dtype({"names": [f for f, _, _ in fields], "formats": [t for _, t, _ in fields],
                     "offsets": [o for _, _, o in fields], "itemsize": size})


# --- rows: the scene's records ------------------------------------------------------------
_ROW_TYPES = {"real4": 1, "real8": 2}  # field type -> real4 rows


@dataclass(frozen=True)
class Rows:
    """A scene record: a run of real4 rows. name (for messages), the C
    constants' prefix, fields ((name, "real4" or "real8"), ...), doc."""

    name: str
    prefix: str
    fields: tuple
    doc: str = ""

    @property
    def stride(self) -> int:
        """Rows (real4s) per record."""
        return sum(_ROW_TYPES[t] for _, t in self.fields)

    def row(self, field: str) -> int:
        """The field's first row within the record."""
        k = 0
        for f, t in self.fields:
            if f == field:
                return k
            k += _ROW_TYPES[t]
        raise KeyError(f"{self.name} has no field {field!r}")

    def host_dtype(self) -> np.dtype:
        """One record as the host packs it: each field float64[4 * rows] at its row."""
        return np.dtype({"names": [f for f, _ in self.fields],
                         "formats": [(np.float64, (4 * _ROW_TYPES[t],)) for _, t in self.fields],
                         "offsets": [32 * self.row(f) for f, _ in self.fields], "itemsize": 32 * self.stride})

    def zeros(self, n: int) -> np.ndarray:
        """n records, zero-filled, to fill by field name (rec["info"][:, 1] = ...)."""
        return np.zeros(n, dtype=self.host_dtype())

    def view(self, rows: np.ndarray) -> np.ndarray:
        """Records by field name over float64 rows (..., 4) or (n, stride, 4), C-contiguous: a view."""
        rows = np.asarray(rows)
        if rows.dtype != np.float64 or not rows.flags.c_contiguous:
            raise ValueError(f"{self.name}: records are C-contiguous float64 rows")
        return rows.reshape(-1).view(self.host_dtype())

    @staticmethod
    def rows(records: np.ndarray) -> np.ndarray:
        """Structured records (zeros, view) as float64 rows (n * stride, 4)."""
        return np.ascontiguousarray(records).view(np.float64).reshape(-1, 4)

    def c_source(self) -> str:
        lines = [f"// {self.doc}"] if self.doc else []
        lines.append(f"#define {self.prefix}_STRIDE {self.stride}")
        lines += [f"#define {self.prefix}_{f.upper()} {self.row(f)}" for f, _ in self.fields]
        return "\n".join(lines)


def _r4(*names):
    return tuple((n, "real4") for n in names)


MATERIAL = Rows("material", "MAT", _r4("kd_pd", "ks_ps", "kr_pr", "kt_pt", "le_sides", "params", "km_pm",
                                      "eta_alpha", "k_dist", "kp_pp", "kps_w", "coat", "coat_tab", "gr_pg",
                                      "gt", "glass_rough", "aniso"),
                "material: kd.rgb, p_diffuse | ks.rgb, p_phong | kr.rgb, p_mirror | kt.rgb, p_refract | "
                "Le.rgb, two_sided | shininess, ior, nondelta, one_sided | km.rgb, p_microfacet | "
                "eta.rgb, alpha | k.rgb, distribution (0 GGX, 1 Beckmann) | plastic (a coated diffuse base): "
                "diffuse_reflectance.rgb, p_plastic | specular_reflectance.rgb, specular sampling weight | "
                "eta, internal reflectance, alpha (0: smooth), distribution | record index of its "
                "transmittance table (COAT_TABLE_ROWS rows after the triangles' records), nonlinear, record "
                "index of its TEXTURE_SLOTS (0: no textures), 0 | "
                "rough dielectric: specular_reflectance.rgb, p_rough_dielectric | specular_transmittance.rgb, 0 | "
                "eta (inside over outside), alpha, distribution, sample_visible | "
                "anisotropy (scenes with an anisotropic material): alpha_v of the rough conductor or rough "
                "dielectric (alpha above is alpha_u), record index of the TANGENT section (0: isotropic), 0, 0")
SPHERE = Rows("sphere", "SPHERE", _r4("center_radius", "mat"),
              "sphere: center.xyz, radius | material, light + 1 (0: not a light), prim id, 0")
PLANAR = Rows("planar", "PLANAR", _r4("corner_mat", "n_light", "wu_prim", "wv_kind"),
              "quad or triangle: corner.xyz, material | n.xyz, light + 1 (0: not a light) | wu.xyz, prim id | "
              "wv.xyz, kind (>= 0: a smooth triangle, the record index of its vertex normals; ITEM_*). "
              "As a BVH item, a sphere: center.xyz, material | radius, 0, 0, light + 1 | 0, 0, 0, prim id | "
              "0, 0, 0, ITEM_SPHERE")
PLANE = Rows("plane", "PLANE", _r4("point_mat", "n"), "plane: point.xyz, material | n.xyz, prim id")
LIGHT = Rows("light", "LIGHT", _r4("p_kind", "u", "v", "n", "info", "tex"),
             "light: p.xyz, kind | u.xyz, 0 | v.xyz, 0 | n.xyz, alias | area, pick probability, alias "
             "probability, material; a mesh light: 0, 0, 0, kind | first triangle record, triangles, 0, 0 | ... | "
             "0, 0, 0, alias | info; a point or spot light: p.xyz, kind | axis.xyz, cos cutoff | cutoff, "
             "1 / (cutoff - beam width), cos beam width, 0 | 0, 0, 0, alias | 1, ... (Le: the intensity). Slot j of the lights' alias table (by power) keeps light j with its alias "
             "probability, else gives light alias. Last row (area lights): the record index of the TEXTURE of "
             "its radiance (0: none), its primitive's id (a mesh light's first triangle's), 0, 0")
CAUSTIC = Rows("caustic caster", "CAUSTIC", _r4("sphere"), "caustic caster: bounding sphere center.xyz, radius")
# Wide BVH nodes (clpt/bvh.py WIDTH = 8 children): rows of 8 reals, read as
# one real8 each; SoA leaf blocks of up to 4 items: rows of 4 reals.
BVH_NODE = Rows("BVH node", "BVH", tuple((r, "real8") for r in ("lo_x", "hi_x", "lo_y", "hi_y", "lo_z", "hi_z",
                                                                    "ptr", "count")),
                "wide BVH node: 8 children's boxes as rows of 8 reals lo.x | hi.x | lo.y | hi.y | lo.z | hi.z, "
                "then their pointers | counts (count > 0: a leaf block of count items at record pointer; "
                "0: a node at record pointer; -1: an empty slot)")
BVH_LEAF_WIDTH = 4   # items a leaf block holds (clpt/bvh.py LEAF_WIDTH): one real4 a row
BVH_LEAF = Rows("BVH leaf block", "BVHL", _r4("px", "py", "pz", "nx", "ny", "nz", "ux", "uy", "uz", "vx", "vy", "vz",
                                              "kind", "mat", "light", "prim"),
                "BVH leaf block: up to BVHL_WIDTH (4) items as rows of 4 reals, their PlanarRec fields: corner "
                "p.xyz | normal n.xyz | dual wu.xyz | dual wv.xyz (a sphere: centre in p, radius in n.x) | kind "
                "(PlanarRec wv.w; ITEM_EMPTY for an empty slot) | material | light + 1 | primitive id")
NORMALS = Rows("vertex normals", "NORMALS", _r4("n0", "n1", "n2"), "vertex normals of a smooth triangle")
TEXTURE = Rows("texture", "TEX", _r4("kind_size", "data", "uv_u", "uv_v", "color0", "color1"),
               "texture (clpt/texture.py): kind (TEX_BITMAP, TEX_CHECKERBOARD), width, height, wrap (TEX_REPEAT, "
               "TEX_MIRROR, TEX_CLAMP) | the record of its first texel as hi, lo (hi * TEX_ROW_SPLIT + lo; "
               "3 reals a texel, row by row, from there), filter (TEX_BILINEAR, TEX_NEAREST), record index of the UV section | to_uv: a, b, c, 0 (u' = a u + b v + c) | d, e, f, 0 (v') | color0.rgb, 0 | "
               "color1.rgb, 0")
TEXTURE_SLOTS = Rows("material textures", "TEXS", _r4("slots", "more"),
                     "a textured material's textures (the record index of each TEXTURE, 0: none): reflectance "
                     "(kd, or kp of a plastic), specular reflectance (km, gr of a rough dielectric, or kr), a "
                     "rough conductor's alpha (the texture's luminance), record index of the UV section | "
                     "transmittance (gt of a rough dielectric, or kt), 0, 0, 0")
UV = Rows("surface coordinates", "UV", _r4("a", "b"),
          "a primitive's (u, v), one record per primitive id (scenes with textures): a quad or triangle: "
          "u, v at its corner, their change along edge u | their change along edge v, 0, UV_PLANAR; a sphere: "
          "the x row of its frame (world to its own), the frame's determinant | the y row, UV_SPHERE")
TANGENT = Rows("surface tangent", "TAN", _r4("dpdu"),
               "a primitive's dp/du, one record per primitive id (scenes with an anisotropic material): a quad "
               "or triangle: dp/du.xyz (0: none, the shading frame's own tangent), TAN_PLANAR; a sphere: its "
               "frame's z axis.xyz (dp/du is z x n), TAN_SPHERE")
# An environment map's texels (after every other record; its light record points to them): row y of
# W texels, then its alias tables, 2 entries a record (ENV_ALIAS).
ENV_TEXEL = Rows("environment texel", "ENVT", _r4("rgb_prob"),
                 "environment map texel (x, y) at record base + W y + x: its radiance r, g, b (linear, unscaled), "
                 "and (y < H - 1) the sampling probability of cell (x, y) (texels x..x+1 by y..y+1, weight the "
                 "mean of their luminance times sin theta; the cells' probabilities sum to one)")
ENV_ALIAS_ENTRIES = 2  # (keep probability, alias) entries of an environment alias table a record
ENV_ALIAS = Rows("environment alias table", "ENVA", _r4("four"),
                 "2 entries of an environment map's alias tables a record, after its texels (entry k of a table "
                 "at record table base + k / 2, components 2 (k % 2) and 2 (k % 2) + 1: the probability that "
                 "slot k keeps its own cell or row, and the one it gives otherwise): the rows' tables over their "
                 "W cells, W (H - 1) entries (row y's slot x at entry W y + x); the marginal's over the H - 1 "
                 "rows of cells")
LIGHT_TRI = Rows("mesh-light triangle", "LTRI", _r4("p_alias", "u_prob", "v"),
                 "triangle of a mesh light: v0.xyz, alias | v1 - v0, alias probability | v2 - v0, 0")

# TEXTURE kinds, wrap modes and filters (clpt/texture.py KINDS, WRAP_MODES, FILTERS, in order);
# texel record indices split in two reals (exact in float builds up to 2^24 * TEX_ROW_SPLIT).
TEX_BITMAP, TEX_CHECKERBOARD = 0, 1
TEX_REPEAT, TEX_MIRROR, TEX_CLAMP = 0, 1, 2
TEX_BILINEAR, TEX_NEAREST = 0, 1
TEX_ROW_SPLIT = 4096
UV_PLANAR, UV_SPHERE = 0, 1
TAN_PLANAR, TAN_SPHERE = 0, 1

# A rough plastic's transmittance table: clpt/coating.py TABLE_RES reals, COAT_TABLE_ROWS rows of 4.
COAT_TABLE_ROWS = 16

# Light kinds in LIGHT.p_kind.w.
KIND_QUAD, KIND_TRIANGLE, KIND_SPHERE, KIND_MESH = 0, 1, 2, 3
# Delta lights (no surface: sampled by next event estimation only, never hit):
# p.xyz, kind | spot axis.xyz, cos cutoff | cutoff angle, 1 / (cutoff - beam width) (0: none), cos beam
# width, 0 | 0, 0, 0, alias | 1, pick probability, alias probability, material (Le = the intensity).
# A point light's u and v rows are 0, 0, 0, -2 | 0, 0, -2, 0: every direction inside the full beam.
KIND_POINT, KIND_SPOT = 4, 5
# Lights at infinity (after the other lights; at most one environment, the last light record):
# an environment (Mitsuba's envmap or constant): bounding sphere center.xyz, kind | to_world's first column.xyz,
# width W (0: constant) | second column.xyz, height H | first texel record (ENV_TEXEL), handedness (+-1, the
# third column is that times first x second), 0, alias | pi R^2 (R the bounding sphere's radius), pick probability,
# alias probability, material (Le: the scale, or the constant's radiance).
# A directional light: bounding sphere center.xyz, kind | direction of travel.xyz, 0 | 0 | 0, 0, 0, alias | pi R^2,
# pick probability, alias probability, material (Le: the irradiance).
KIND_ENV, KIND_DIRECTIONAL = 6, 7
# Primitive kinds in PLANAR.wv_kind.w (a smooth triangle has its normals' record index there instead).
ITEM_FLAT_TRIANGLE, ITEM_QUAD, ITEM_SPHERE = -1, -2, -3
ITEM_EMPTY = -4  # an empty slot of a BVH leaf block
# A plain loop's quad or flat triangle that no shadow ray can cross (clpt/pack.py _mark_shadowless): the
# shadow query skips it (kernels/scene.h walk_planar); closest hits treat it as ITEM_QUAD or ITEM_FLAT_TRIANGLE.
ITEM_QUAD_NO_SHADOW, ITEM_TRIANGLE_NO_SHADOW = -5, -6

# --- launch records ----------------------------------------------------------------------------
# The scene's section sizes, in the order the sections are packed (clpt/pack.py).
COUNT_NAMES = ("materials", "spheres", "quads", "triangles", "planes", "lights", "caustics", "nodes")
SCENE_INFO = Record("SceneInfo", tuple((n, "uint") for n in COUNT_NAMES) + (("eps_abs", "real"),),
                    "the scene's section sizes (records of each kind; nodes: BVH nodes) and the absolute "
                    "floor of ray-origin offsets")
CAMERA = Record("CameraRec", (("origin", "real4"), ("corner", "real4"), ("dx", "real4"), ("dy", "real4")),
                "pinhole camera: origin; direction to the image's top-left corner (plane at distance 1); one "
                "pixel right; one pixel down")
FILTER = Record("FilterRec", (("radius", "real"), ("sample_border", "uint")),
                "the pixel filter (kernels/camera.h; its kind is CLPT_PIXEL_FILTER): radius in pixels (a gaussian's "
                "is 4 stddev); whether samples may leave the film")
PHOTON_LOOKUP = Record("PhotonLookup", (
    ("mask", "uint"), ("max_photons", "uint"), ("budget", "uint"), ("occ_mask", "uint"),
    ("merge_vertices", "uint"), ("aim", "uint"),
    ("merge", "uint"), ("gather", "uint"), ("owns", "uint"), ("stop_at_x", "uint"), ("moments", "uint"),
    ("radius", "real"), ("inv_cell", "real"), ("cone_k", "real"), ("mis_k", "real"), ("merge_p", "real")),
    "the photon map as trace_paths reads it (kernels/photon_grid.h) and what a launch does with it: merge at "
    "non-delta vertices (merge), gather at the first one (gather), the paths the map owns not path traced "
    "(owns), camera paths ending there (stop_at_x: the offline pre-pass), merges that also estimate path "
    "tracing's second moment in the caustic plane (moments: the pilot's trial, with feature buffers)")
TRACE_LAUNCH = Record("TraceLaunch", (
    ("scene", SCENE_INFO), ("camera", CAMERA), ("photons", PHOTON_LOOKUP), ("lum_scale", "real"),
    ("width", "uint"), ("height", "uint"), ("group_offset", "uint"), ("sample_begin", "uint"),
    ("n_samples", "uint"), ("max_depth", "uint"), ("rr_depth", "uint"), ("seed", "uint"), ("n_list", "uint"),
    ("wi_entries", "uint"), ("pull_runs", "uint"),
    ("aux_specular", "uint"), ("hide_emitters", "uint"), ("pixel_filter", FILTER)),
    "one trace_paths launch (kernels/trace.cl)")
PHOTON_LAUNCH = Record("PhotonLaunch", (("scene", SCENE_INFO), ("seed", "uint"), ("n_emit", "uint"),
                                        ("aim", "uint")),
                       "one trace_photons launch (kernels/photons.cl)")


def scene_records() -> tuple:
    """The scene's records (Rows), as this module holds them now."""
    return (MATERIAL, SPHERE, PLANAR, PLANE, LIGHT, CAUSTIC, BVH_NODE, BVH_LEAF, NORMALS, LIGHT_TRI, TEXTURE_SLOTS, TEXTURE, UV,
            TANGENT, ENV_TEXEL, ENV_ALIAS)


def launch_records() -> tuple:
    """The structs (Record), nested ones before those that hold them."""
    return (SCENE_INFO, CAMERA, FILTER, PHOTON_LOOKUP, TRACE_LAUNCH, PHOTON_LAUNCH)


def c_source() -> str:
    """The C side of the layout: row constants and typedefs for every record."""
    parts = ["// Generated by clpt/layout.py: the records the host packs (do not edit)."]
    parts += [r.c_source() for r in scene_records() + launch_records()]
    parts += [f"#define KIND_QUAD {KIND_QUAD}", f"#define KIND_TRIANGLE {KIND_TRIANGLE}",
              f"#define KIND_SPHERE {KIND_SPHERE}", f"#define KIND_MESH {KIND_MESH}",
              f"#define KIND_POINT {KIND_POINT}", f"#define KIND_SPOT {KIND_SPOT}",
              f"#define KIND_ENV {KIND_ENV}", f"#define KIND_DIRECTIONAL {KIND_DIRECTIONAL}",
              f"#define ITEM_FLAT_TRIANGLE {ITEM_FLAT_TRIANGLE}", f"#define ITEM_QUAD {ITEM_QUAD}",
              f"#define ITEM_SPHERE {ITEM_SPHERE}", f"#define ITEM_EMPTY {ITEM_EMPTY}",
              f"#define ITEM_QUAD_NO_SHADOW {ITEM_QUAD_NO_SHADOW}",
              f"#define ITEM_TRIANGLE_NO_SHADOW {ITEM_TRIANGLE_NO_SHADOW}",
              f"#define BVHL_WIDTH {BVH_LEAF_WIDTH}", f"#define COAT_TABLE_ROWS {COAT_TABLE_ROWS}",
              f"#define ENVA_ENTRIES {ENV_ALIAS_ENTRIES}"]
    parts += [f"#define {k} {v}" for k, v in (("TEX_BITMAP", TEX_BITMAP), ("TEX_CHECKERBOARD", TEX_CHECKERBOARD),
                                              ("TEX_REPEAT", TEX_REPEAT), ("TEX_MIRROR", TEX_MIRROR),
                                              ("TEX_CLAMP", TEX_CLAMP), ("TEX_BILINEAR", TEX_BILINEAR),
                                              ("TEX_NEAREST", TEX_NEAREST), ("TEX_ROW_SPLIT", TEX_ROW_SPLIT),
                                              ("UV_PLANAR", UV_PLANAR), ("UV_SPHERE", UV_SPHERE),
                                              ("TAN_PLANAR", TAN_PLANAR), ("TAN_SPHERE", TAN_SPHERE))]
    return "\n".join(parts) + "\n"
