"""Scene -> the packed record array the kernels read.

The records' layout is clpt/layout.py's (the kernels get the same from it);
this module fills them by field name. Records are runs of 4-vectors of the
kernel's real type (float32, or float64 for double-precision builds), in
sections:

  materials, spheres, quads, triangles, planes, lights, caustic casters,
  then BVH nodes and leaf blocks (which hold their items' records), vertex
  normals, mesh-light triangles, rough plastics' tables and, in scenes with
  textures, the materials' TEXTURE_SLOTS, the TEXTURE records, one UV record per primitive and last the
  texels (3 reals each, every texture from a row of its own).

Scenes with fewer than BVH_MIN_PRIMS bounded primitives keep them in the
plain sections, which the kernels loop over; larger ones put every sphere,
quad and triangle in a BVH (clpt/bvh.py) and leave those sections empty.
Pointers between sections are absolute real4 indices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import bvh as bvh_mod
from . import coating, layout
from .constants import OFFSET_FLOOR, OFFSET_REL, dot_rows
from .layout import (COUNT_NAMES, ITEM_FLAT_TRIANGLE, ITEM_QUAD, ITEM_QUAD_NO_SHADOW, ITEM_SPHERE,
                     ITEM_TRIANGLE_NO_SHADOW, KIND_DIRECTIONAL, KIND_ENV, KIND_MESH,
                     KIND_POINT, KIND_QUAD, KIND_SPHERE, KIND_SPOT, KIND_TRIANGLE, Rows)
from .meshio import cross_rows
from .scene import (DEFAULT_UV, EMISSION_SLOT, TEXTURE_SLOTS, Camera, EnvironmentLight, Material, Scene,
                    SceneError, Sphere, SpotLight, length_scale)
from .texture import FILTERS, KINDS, WRAP_MODES, surface_mean_planar, surface_mean_sphere

# Records are referred to as layout.NAME where they are filled (a test reorders their fields).
MAT_STRIDE = layout.MATERIAL.stride
SPHERE_STRIDE = layout.SPHERE.stride
PLANAR_STRIDE = layout.PLANAR.stride
PLANE_STRIDE = layout.PLANE.stride
LIGHT_STRIDE = layout.LIGHT.stride
CAUSTIC_STRIDE = layout.CAUSTIC.stride

LIGHT_KIND_QUAD, LIGHT_KIND_TRIANGLE, LIGHT_KIND_SPHERE, LIGHT_KIND_MESH = KIND_QUAD, KIND_TRIANGLE, KIND_SPHERE, KIND_MESH
# The sections before the BVH, in packing order, with their records.
_SECTIONS = (("materials", "MATERIAL"), ("spheres", "SPHERE"), ("quads", "PLANAR"), ("triangles", "PLANAR"),
             ("planes", "PLANE"), ("lights", "LIGHT"), ("caustics", "CAUSTIC"))

# Below this many bounded primitives (spheres, quads, triangles) the kernels'
# plain loops beat the BVH (measured: README, "BVH").
BVH_MIN_PRIMS = 64
# Records are indexed by reals: exact integers below 2^24 in float builds.
MAX_FLOAT_RECORDS = 1 << 24


@dataclass(frozen=True)
class PackedScene:
    records: np.ndarray          # (n, 4) float64; cast to the kernel's real type on upload
    counts: tuple                # materials, spheres, quads, triangles, planes, lights, caustic objects
    materials: tuple             # the distinct surfaces, in material-id order
    light_kinds: frozenset       # {"quad", "triangle", "sphere", "mesh", "point", "spot"}
    extent: float                # diagonal of the scene's bounds, camera included
    size: float                  # diagonal of the geometry's bounds: the unit of relative photon radii
    max_flux: float              # power the lights that emit photons emit (pi * area * max Le * sides), for the pilot
    max_radiance: float = 1.0    # the brightest emission's largest channel
    length_scale: float = 1.0    # the records' lengths are the scene's times this (see length_scale)
    smooth: bool = False         # some triangles have vertex normals
    bvh: object = None           # the clpt.bvh.Tree, when the scene has one
    primitives: int = 0          # bounded primitives (spheres, quads, triangles)
    pixel_filter: str = "box"    # the camera's pixel filter kind (its parameters go in each launch record)
    textures: tuple = ()         # the distinct clpt.texture.Texture objects the materials use
    texel_rows: int = 0          # the textures' texels, after the other records (not indexed by reals)
    env_texels: int = 0          # the environment map's records, last (indexed by integers, not by reals)
    anisotropic: bool = False    # some microfacet lobe has alpha_v != alpha (a TANGENT section after the texels)
    textured_spots: bool = False  # some spot light has a texture (its LIGHT_TEX row names it)
    mitsuba_shading: bool = False  # RenderSettings.shading_normals == "mitsuba"

    @property
    def lum_scale(self) -> float:
        """The power of two that brings the brightest emission near 1: the
        kernels square luminance times this for the per-pixel variance, which
        then neither overflows nor goes subnormal in float, whatever the
        scene's units of radiance (the image itself is not scaled)."""
        return 2.0 ** -round(math.log2(self.max_radiance)) if self.max_radiance > 0 else 1.0

    def count(self, name: str) -> int:
        return self.counts[COUNT_NAMES.index(name)]

    def section(self, name: str) -> np.ndarray:
        """The records of one section before the BVH ("materials", "spheres",
        "quads", "triangles", "planes", "lights", "caustics"), by field name
        (a view of self.records)."""
        first = 0
        for sec, rec in _SECTIONS:
            r = getattr(layout, rec)
            n = self.count(sec) * r.stride
            if sec == name:
                return r.view(self.records[first:first + n])
            first += n
        raise KeyError(f"no section {name!r}")

    @property
    def has_phong(self) -> bool:
        return any(max(m.ks) > 0 for m in self.materials)

    @property
    def has_microfacet(self) -> bool:
        return any(max(m.km) > 0 for m in self.materials)

    @property
    def has_plastic(self) -> bool:
        return any(m.plastic for m in self.materials)

    @property
    def has_rough_dielectric(self) -> bool:
        return any(m.rough_dielectric_lobe for m in self.materials)

    @property
    def has_mirror(self) -> bool:
        return any(max(m.kr) > 0 for m in self.materials)

    @property
    def has_glass(self) -> bool:
        return any(max(m.kt) > 0 for m in self.materials)

    @property
    def indexed_rows(self) -> int:
        """The records indexed by reals (every one but the textures' and the environment map's texels)."""
        return len(self.records) - self.texel_rows - self.env_texels

    @property
    def has_textured_emitters(self) -> bool:
        return any(m.texture(EMISSION_SLOT) is not None and m.is_emissive for m in self.materials)

    @property
    def has_caustics(self) -> bool:
        return self.count("caustics") > 0

    @property
    def max_brdf(self) -> float:
        """Largest value the non-delta lobes of any material can take."""
        return max(max(m.kd) / math.pi + max(m.ks) * (m.shininess + 2) / (2 * math.pi) for m in self.materials)


def lobe_probabilities(m: Material):
    """Russian-roulette probabilities of the diffuse, Phong, mirror, refraction
    and microfacet lobes: each lobe's largest channel, scaled down if they sum past one.
    Absorption takes the rest, so a lobe's throughput weight k / p is <= 1."""
    p = np.array([max(m.kd), max(m.ks), max(m.kr), max(m.kt), max(m.km)], dtype=np.float64)
    return p / max(1.0, p.sum())


def plastic_probability(m: Material) -> float:
    """Russian-roulette probability of a plastic's lobe (it is the material's
    only one): its largest channel of the average albedo, specular
    Fdr_e kps plus diffuse (1 - Fdr_e)^2 / eta^2 kp / (1 - Fdr_i [kp])
    (Mitsuba's fitted diffuse Fresnel reflectances from outside and inside),
    so a path's weight stays near 1 where the plastic reflects little."""
    if not m.plastic:
        return 0.0
    eta = float(m.plastic_eta)
    fe, fi = coating.fresnel_diffuse_reflectance(eta), coating.fresnel_diffuse_reflectance(1.0 / eta)
    kp = np.asarray(m.kp, dtype=np.float64)
    diffuse = kp * (1 - fe) ** 2 / (eta * eta) / (1 - fi * (kp if m.nonlinear else 1.0))
    albedo = fe * np.asarray(m.kps, dtype=np.float64) + diffuse
    return float(np.clip(albedo.max(), 0.05, 1.0))


def _coat_tables(mat_recs, materials, base: int) -> np.ndarray:
    """COAT_TABLE_ROWS rows per rough plastic (its transmittance table), from
    record index base; each material record's coat_tab.x points to its own."""
    rows = []
    for rec, m in zip(mat_recs, materials):
        if m.plastic and m.alpha > 0:
            t, _ = coating.rough_tables(float(m.alpha), m.distribution, float(m.plastic_eta))
            rec["coat_tab"][0] = base + layout.COAT_TABLE_ROWS * len(rows)
            rows.append(np.asarray(t, dtype=np.float64).reshape(layout.COAT_TABLE_ROWS, 4))
    return np.concatenate(rows) if rows else np.zeros((0, 4))


def _material_records(materials) -> np.ndarray:
    """MATERIAL records of the materials, in order (texture pointers: _texture_records)."""
    out = layout.MATERIAL.zeros(len(materials))
    for rec, m in zip(out, materials):
        p_d, p_s, p_r, p_t, p_m = lobe_probabilities(m)
        rec["kd_pd"] = (*m.kd, p_d)
        rec["ks_ps"] = (*m.ks, p_s)
        rec["kr_pr"] = (*m.kr, p_r)
        rec["kt_pt"] = (*m.kt, p_t)
        rec["le_sides"] = (*m.emission, 1.0 if m.two_sided else 0.0)
        rec["params"] = (m.shininess, m.ior, 1.0 if p_d > 0 or p_s > 0 or p_m > 0 else 0.0,
                         1.0 if m.one_sided else 0.0)
        if m.plastic:
            eta = float(m.plastic_eta)
            if m.alpha > 0:
                _, fdr = coating.rough_tables(float(m.alpha), m.distribution, eta)
            else:
                fdr = coating.fresnel_diffuse_reflectance(1.0 / eta)
            kp_tex = m.texture("reflectance")
            d_mean, s_mean = float(np.mean(kp_tex.mean() if kp_tex else m.kp)), float(np.mean(m.kps))
            w = s_mean / (d_mean + s_mean) if d_mean + s_mean > 0 else 0.5
            rec["kp_pp"] = (*m.kp, plastic_probability(m))
            rec["kps_w"] = (*m.kps, w)
            rec["coat"] = (eta, fdr, m.alpha, 1.0 if m.distribution == "beckmann" else 0.0)
            rec["coat_tab"] = (0.0, 1.0 if m.nonlinear else 0.0, 0.0, 0.0)
            rec["params"][2] = 1.0
        if p_m > 0:
            rec["km_pm"] = (*m.km, p_m)
            rec["eta_alpha"] = (*m.eta, m.alpha)
            rec["k_dist"] = (*m.k, 1.0 if m.distribution == "beckmann" else 0.0)
            rec["aniso"][0] = m.alpha if m.alpha_v is None else m.alpha_v
        if m.rough_dielectric_lobe:
            # Its weight is kgr or kgt times G1 <= 1 (radiance: kgt / eta^2 across,
            # eta^2 back): the lobe's largest channel is its probability.
            p_g = min(1.0, max(*m.kgr, *m.kgt))
            rec["gr_pg"] = (*m.kgr, p_g)
            rec["gt"] = (*m.kgt, 0.0)
            # Anisotropic: always from the visible normals (the same expected image; kernels/bsdf.h).
            rec["glass_rough"] = (m.ior, m.alpha, 1.0 if m.distribution == "beckmann" else 0.0,
                                  1.0 if m.sample_visible or m.anisotropic else 0.0)
            rec["aniso"][0] = m.alpha if m.alpha_v is None else m.alpha_v
            rec["params"][2] = 1.0 if p_g > 0 else 0.0
    return out


def _texture_records(mat_recs, materials, base: int, extra=()):
    """From record index base: a TEXTURE_SLOTS record per textured material
    (its record's coat_tab.z points to it), then a TEXTURE record per
    distinct texture: (textures, slot records, texture records). The UV
    section follows them (its first row goes in each slot record's .w, set
    by the caller), then the texels. extra: more textures (spot lights')."""
    textures = []
    for t in [t for m in materials for _, t in m.textures] + list(extra):
        if not any(t is x for x in textures):
            textures.append(t)
    textured = [(rec, m) for rec, m in zip(mat_recs, materials) if m.bsdf_textures]
    slots = layout.TEXTURE_SLOTS.zeros(len(textured))
    first_tex = base + layout.TEXTURE_SLOTS.stride * len(textured)
    for k, (rec, m) in enumerate(textured):
        rec["coat_tab"][2] = base + layout.TEXTURE_SLOTS.stride * k
        for slot, (row, col) in zip(TEXTURE_SLOTS, (("slots", 0), ("slots", 1), ("slots", 2), ("more", 0))):
            t = m.texture(slot)
            if t is not None:
                slots[k][row][col] = first_tex + layout.TEXTURE.stride * next(i for i, x in enumerate(textures)
                                                                                  if x is t)
    return textures, slots, layout.TEXTURE.zeros(len(textures))


def _texel_rows(textures, recs, texel_base: int) -> np.ndarray:
    """The textures' texels as rows of 4 reals from record index texel_base
    (each texture from a row of its own), filling their records."""
    rows, at = [], texel_base
    for rec, t in zip(recs, textures):
        h, w = (t.data.shape[:2] if t.data is not None else (0, 0))
        rec["kind_size"] = (KINDS.index(t.kind), w, h, WRAP_MODES.index(t.wrap))
        rec["data"] = (at // layout.TEX_ROW_SPLIT, at % layout.TEX_ROW_SPLIT, FILTERS.index(t.filter), 0.0)
        rec["uv_u"][:3], rec["uv_v"][:3] = t.to_uv
        rec["color0"][:3], rec["color1"][:3] = t.color0, t.color1
        if t.data is not None:
            flat = t.data.reshape(-1).astype(np.float64)
            flat = np.concatenate([flat, np.zeros(-len(flat) % 4)])
            rows.append(flat.reshape(-1, 4))
            at += len(rows[-1])
    return np.concatenate(rows) if rows else np.zeros((0, 4))


def _planar_uv(uv, m: int) -> np.ndarray:
    """UV records of m planar primitives of one (u, v) parametrisation
    ((u0, v0), change along edge u, change along edge v), or of (m, 3, 2)."""
    a = np.broadcast_to(np.asarray(uv, dtype=np.float64), (m, 3, 2))
    out = layout.UV.zeros(m)
    out["a"] = np.concatenate([a[:, 0], a[:, 1]], axis=1)
    out["b"][:, :2] = a[:, 2]
    out["b"][:, 3] = layout.UV_PLANAR
    return out


def _planar_tangents(u, v, uv) -> np.ndarray:
    """TANGENT records of planar primitives with edges u, v (M, 3) and (u, v)
    ((u0, v0), change along edge u, change along edge v) (M, 3, 2): dp/du as
    Mitsuba 3 (3.9) computes a mesh's, from the (u, v); where those are
    degenerate, and so for a mesh without them (its barycentric (u, v)),
    edge u itself."""
    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    uv = np.broadcast_to(np.asarray(uv, dtype=np.float64), (len(u), 3, 2))
    d0, d1 = uv[:, 1], uv[:, 2]
    det = d0[:, 0] * d1[:, 1] - d0[:, 1] * d1[:, 0]
    ok = det != 0
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    dpdu = (d1[:, 1:2] * u - d0[:, 1:2] * v) * inv[:, None]
    out = layout.TANGENT.zeros(len(u))
    out["dpdu"][:, :3] = np.where(ok[:, None], dpdu, u)
    out["dpdu"][:, 3] = layout.TAN_PLANAR
    return out


def _planar_array(c, u, v, mat, kind, prim, light1):
    """PLANAR records (M, structured) of parallelograms or triangles corner c
    with edges u, v (M, 3 each), and their unit normals and areas of the
    parallelogram. kind: ITEM_QUAD or ITEM_FLAT_TRIANGLE."""
    out = layout.PLANAR.zeros(len(c))
    n_raw = cross_rows(u, v)
    nn = n_raw[:, 0] * n_raw[:, 0] + n_raw[:, 1] * n_raw[:, 1] + n_raw[:, 2] * n_raw[:, 2]
    ln = np.sqrt(nn)
    n = n_raw / ln[:, None]
    out["n_light"][:, :3] = n
    # Dual vectors: for q = a u + b v in the plane, a = q.wu and b = q.wv.
    out["wu_prim"][:, :3] = cross_rows(v, n_raw) / nn[:, None]
    out["wv_kind"][:, :3] = cross_rows(n_raw, u) / nn[:, None]
    out["corner_mat"][:, :3], out["corner_mat"][:, 3] = c, mat
    out["n_light"][:, 3] = light1
    out["wu_prim"][:, 3] = prim
    out["wv_kind"][:, 3] = kind
    return out, n, ln


def alias_table(weights):
    """Walker's alias table (Vose's construction) for weights > 0: slot j
    keeps j with probability prob[j], else gives alias[j]."""
    w = np.asarray(weights, dtype=np.float64)
    n = len(w)
    p = w * (n / w.sum())
    prob = np.ones(n)
    alias = np.arange(n)
    small = [i for i in range(n) if p[i] < 1.0] if n < 4096 else list(np.flatnonzero(p < 1.0))
    large = [i for i in range(n) if p[i] >= 1.0] if n < 4096 else list(np.flatnonzero(p >= 1.0))
    while small and large:
        s, g = small.pop(), large[-1]
        prob[s], alias[s] = p[s], g
        p[g] -= 1.0 - p[s]
        if p[g] < 1.0:
            small.append(large.pop())
    return prob, alias


def env_luminance(image: np.ndarray) -> np.ndarray:
    """Per-pixel luminance of an H x W x 3 linear RGB image (Mitsuba's weights), float64."""
    return dot_rows(image.astype(np.float64), np.array([0.212671, 0.715160, 0.072169]))


def env_cell_weights(image: np.ndarray) -> np.ndarray:
    """The environment's sampling cells, (H - 1) x W: cell (x, y) spans
    texels x..x+1 (x+1 wrapping to 0) and rows y..y+1, and weighs the mean of
    its four corners' luminance times sin theta (theta = pi y / (H - 1)): the
    integral of their bilinear interpolation, as the radiance is looked up."""
    h = image.shape[0]
    lum = env_luminance(image) * np.sin(np.pi * np.arange(h) / (h - 1))[:, None]
    lum = np.maximum(lum, 0.0)
    row = lum + np.roll(lum, -1, axis=1)
    return 0.25 * (row[:-1] + row[1:])


def alias_rows(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Walker's alias tables of the rows of weights (..., n) >= 0, all rows
    at once: slot j of a row keeps j with probability prob[..., j], else
    gives alias[..., j]. Each row's weights are sorted ascending; while a
    row has unpaired slots, its largest left (the donor) fills either its
    smallest one (if the donor still holds at least a slot's mass) or,
    having fallen below, its own slot from the next largest, so every row
    needs at most n steps and a step is a few array operations across the
    rows. A row of zeros gets uniform slots."""
    w = np.atleast_2d(np.asarray(weights, dtype=np.float64))
    rows, n = w.shape
    tot = w.sum(axis=1, keepdims=True)
    p = np.where(tot > 0, w * (n / np.where(tot > 0, tot, 1.0)), 1.0)
    order = np.argsort(p, axis=1, kind="stable")
    q = np.take_along_axis(p, order, axis=1)
    prob = np.ones((rows, n))
    alias = np.tile(np.arange(n), (rows, 1))
    r = np.arange(rows)
    i = np.zeros(rows, dtype=np.int64)
    j = np.full(rows, n - 1, dtype=np.int64)
    for _ in range(n):
        act = i < j
        if not act.any():
            break
        donor = q[r, j]
        fill = act & (donor >= 1.0)  # the donor fills the smallest slot i
        own = act & ~fill            # the donor fell below a slot: the next largest fills its slot
        rf, rs = r[fill], r[own]
        fi, fj = i[fill], j[fill]
        prob[rf, fi] = np.clip(q[rf, fi], 0.0, 1.0)
        alias[rf, fi] = fj
        q[rf, fj] -= 1.0 - q[rf, fi]
        i[fill] += 1
        sj = j[own]
        prob[rs, sj] = np.clip(q[rs, sj], 0.0, 1.0)
        alias[rs, sj] = sj - 1
        q[rs, sj - 1] -= 1.0 - q[rs, sj]
        j[own] -= 1
    out_p, out_a = np.empty_like(prob), np.empty_like(alias)
    np.put_along_axis(out_p, order, prob, axis=1)
    np.put_along_axis(out_a, order, np.take_along_axis(order, alias, axis=1), axis=1)
    shape = np.shape(weights)
    return out_p.reshape(shape), out_a.reshape(shape)


def env_records(image: np.ndarray) -> np.ndarray:
    """The texel records (ENV_TEXEL) of an environment map and its alias
    tables (ENV_ALIAS: the rows of cells', then the marginal's over the
    rows), as float64 rows."""
    h, w = image.shape[:2]
    cells = env_cell_weights(image)
    rows = cells.sum(axis=1)
    row_prob, row_alias = np.empty(cells.shape), np.empty(cells.shape, dtype=np.int64)
    step = max(1, (1 << 22) // w)  # rows at a time: alias_rows' working arrays stay near 0.4 GB
    for y in range(0, h - 1, step):
        row_prob[y:y + step], row_alias[y:y + step] = alias_rows(cells[y:y + step])
    marg_prob, marg_alias = alias_rows(rows)
    tables = []
    for prob, alias in ((row_prob.reshape(-1), row_alias.reshape(-1)), (marg_prob, marg_alias)):
        t = np.zeros(2 * len(prob))
        t[0:2 * len(prob):2], t[1:2 * len(prob):2] = prob, alias
        tables.append(t)
    sizes = [-(-len(t) // 4) for t in tables]  # records: ENV_ALIAS_ENTRIES (keep, alias) pairs each
    out = np.zeros((w * h + sum(sizes), 4))
    tex = layout.ENV_TEXEL.view(out[:w * h])["rgb_prob"]
    tex[:, :3] = image.reshape(-1, 3)
    tex[:w * (h - 1), 3] = (cells / cells.sum()).reshape(-1)
    first = w * h
    for t, n in zip(tables, sizes):
        layout.ENV_ALIAS.view(out[first:first + n])["four"].reshape(-1)[:len(t)] = t
        first += n
    return out


def bounding_sphere(scene: Scene):
    """Center and radius of the sphere around the scene's geometry (the
    infinite lights' disk and distance); a scene of planes only gets its
    extent's."""
    lo, hi = scene.bounds(camera=False)
    r = 0.5 * float(np.linalg.norm(hi - lo))
    if not r > 0:
        lo, hi = scene.bounds(camera=True)
        r = max(0.5 * float(np.linalg.norm(hi - lo)), 1.0)
    return 0.5 * (lo + hi), r


def is_caustic_caster(m: Material) -> bool:
    """Purely specular (mirror and/or refraction, no diffuse, Phong or microfacet part):
    the surfaces photons pass through on their way to a caustic. Surfaces
    that mix in a diffuse or Phong part are left to the path tracer."""
    return (max(m.kr) > 0 or max(m.kt) > 0) and max(m.kd) == 0 and max(m.ks) == 0 and max(m.km) == 0 and \
        not m.plastic and not m.rough_dielectric_lobe


def _caustic_objects(scene: Scene):
    """Bounding spheres (center, radius) of the caustic casters, one per shape
    (a box is one object); radius -1 marks an unbounded one (a plane)."""
    groups: dict[int, list] = {}
    for i, p in scene.primitives():
        if is_caustic_caster(scene.surface(p)):
            groups.setdefault(i, []).append(p)
    out = []
    for prims in groups.values():
        if not all(p.bounded for p in prims):
            out.append((0.0, 0.0, 0.0, -1.0))
            continue
        if len(prims) == 1 and isinstance(prims[0], Sphere):
            out.append((*prims[0].center, prims[0].radius))  # exact, not the box's sphere
            continue
        pts = np.concatenate([p.points() for p in prims])
        c = 0.5 * (pts.min(0) + pts.max(0))
        out.append((*c, float(np.linalg.norm(pts - c, axis=1).max()) * (1 + 1e-6)))
    return out


class _Builder:
    """Collects primitives as shapes pack themselves (Shape.pack calls
    sphere, planar, plane or mesh); pack_scene then lays out the sections."""

    def __init__(self):
        self.spheres = []   # (center, radius, material id, prim id)
        self.blocks = {KIND_QUAD: [], KIND_TRIANGLE: []}  # PLANAR record blocks
        self.normals = []   # (PLANAR records of smooth triangles, their (M, 3, 3) vertex normals)
        self.planes = []    # (point, unit normal, material id, prim id)
        self.lights = []    # (sides, area, material, LIGHT fields {name: row}, material id, LIGHT_TRI records or None)
        self.delta_power = {}  # light index -> power of a point or spot light (area lights: pi area Le sides)
        self.surface_mean = {}  # light index -> a textured area light's radiance, its mean over the surface by area
        self.spot_textures = {}  # light index -> a textured spot light's clpt.texture.Texture
        self.infinite = []  # (directional or environment light, material): packed after every other light
        self.n_prims = 0    # every primitive, planes included, has an id
        self.n_bounded = 0
        self.bounds = []    # (lo, hi) blocks of the bounded primitives, in prim order
        self.uvs = None     # UV record blocks in prim order (a list, when the scene has textures)
        self.tangents = None  # TANGENT record blocks in prim order (a list, when a material is anisotropic)

    def _light1(self, m):
        """The light record index + 1 a primitive of material m will have (0: none)."""
        return float(len(self.lights) + 1) if m.is_emissive else 0.0

    def _prims(self, m, bounded=True):
        first = self.n_prims
        self.n_prims += m
        self.n_bounded += m if bounded else 0
        return np.arange(first, first + m, dtype=np.float64)

    def sphere(self, p, mat):
        mid, m = mat
        c = np.array(p.center, dtype=np.float64)
        prim = self._prims(1)[0]
        self.spheres.append((c, float(p.radius), mid, prim, self._light1(m)))
        if self.uvs is not None:
            f = np.asarray(p.uv_frame, dtype=np.float64)
            rec = layout.UV.zeros(1)
            rec["a"] = (*f[0], 1.0 if np.linalg.det(f) >= 0 else -1.0)
            rec["b"] = (*f[1], layout.UV_SPHERE)
            self.uvs.append(rec)
        if self.tangents is not None:  # dp/du = z x n, z the sphere's own axis (Mitsuba's (-y, x, 0))
            f = np.asarray(p.uv_frame, dtype=np.float64)
            rec = layout.TANGENT.zeros(1)
            rec["dpdu"] = (*np.cross(f[0], f[1]), layout.TAN_SPHERE)
            self.tangents.append(rec)
        self.bounds.append((c[None] - p.radius, c[None] + p.radius))
        if m.is_emissive:
            tex = m.texture(EMISSION_SLOT)
            if tex is not None:
                self.surface_mean[len(self.lights)] = surface_mean_sphere(tex)
            self.lights.append((_sides(m), p.area(), m, {"p_kind": (*c, LIGHT_KIND_SPHERE),
                                                         "u": (p.radius, 0.0, 0.0, 0.0),
                                                         "tex": (0.0, prim, 0.0, 0.0)}, mid, None))

    def planar(self, c, u, v, mat, triangle: bool, light: bool, uv=DEFAULT_UV):
        mid, m = mat
        if self.uvs is not None:
            self.uvs.append(_planar_uv(uv, 1))
        if self.tangents is not None:
            self.tangents.append(_planar_tangents(u[None], v[None], uv))
        kind = KIND_TRIANGLE if triangle else KIND_QUAD
        prim = self._prims(1)
        recs, n, ln = _planar_array(c[None], u[None], v[None], mid, ITEM_FLAT_TRIANGLE if triangle else ITEM_QUAD,
                                    prim, self._light1(m) if light else 0.0)
        self.blocks[kind].append(recs)
        pts = np.array([c, c + u, c + v] + ([] if triangle else [c + u + v]))
        self.bounds.append((pts.min(0)[None], pts.max(0)[None]))
        area = float(ln[0]) * (0.5 if triangle else 1.0)
        if light and m.is_emissive:
            tex = m.texture(EMISSION_SLOT)
            if tex is not None:
                self.surface_mean[len(self.lights)] = surface_mean_planar(tex, uv, [area], triangle)
            self.lights.append((_sides(m), area, m, {"p_kind": (*c, kind), "u": (*u, 0.0), "v": (*v, 0.0),
                                                     "n": (*n[0], 0.0), "tex": (0.0, prim[0], 0.0, 0.0)}, mid, None))

    def delta_light(self, p, mat):
        """A point or spot light: no primitive, a LIGHT record of area 1 (its
        pdf_area is its pick probability) whose material's Le is the intensity."""
        mid, m = mat
        pos = tuple(float(x) for x in p.position)
        if isinstance(p, SpotLight):
            d = np.asarray(p.direction, dtype=np.float64)
            d = d / np.linalg.norm(d)
            cut, beam = math.radians(p.cutoff_angle), math.radians(p.beam)
            fields = {"p_kind": (*pos, KIND_SPOT), "u": (*d, math.cos(cut)),
                      "v": (cut, 1.0 / (cut - beam) if cut > beam else 0.0, math.cos(beam), 0.0)}
            if p.texture is not None:  # (u, v) = 1/2 + (n.xyz . w, tex.yzw . w) / (axis . w); tex.x: later
                a, c = p.texture_rows()
                fields["n"] = (*a, 0.0)
                fields["tex"] = (0.0, *c)
                self.spot_textures[len(self.lights)] = p.texture
        else:
            fields = {"p_kind": (*pos, KIND_POINT), "u": (0.0, 0.0, 0.0, -2.0), "v": (0.0, 0.0, -2.0, 0.0)}
        self.delta_power[len(self.lights)] = p.power()
        self.lights.append((1.0, 1.0, m, fields, mid, None))

    def infinite_light(self, p, mat):
        self.infinite.append((p, mat))

    def add_infinite_lights(self, center, radius: float, texel_base: int):
        """The directional lights, then the environment (the last light
        record), around the bounding sphere (center, radius); the environment
        map's texels start at record texel_base. Returns its texel records."""
        texels = np.zeros((0, 4))
        area = math.pi * radius * radius
        for p, (mid, m) in sorted(self.infinite, key=lambda pm: isinstance(pm[0], EnvironmentLight)):
            self.delta_power[len(self.lights)] = p.power(radius)
            if isinstance(p, EnvironmentLight):
                r = p.rotation()
                hand = 1.0 if np.linalg.det(r) > 0 else -1.0
                w, h = (0, 0) if p.image is None else p.image.shape[1::-1]
                fields = {"p_kind": (*center, KIND_ENV), "u": (*r[:, 0], w), "v": (*r[:, 1], h),
                          "n": (float(texel_base), hand, 0.0, 0.0)}
                if p.image is not None:
                    texels = env_records(p.image)
            else:
                d = np.asarray(p.direction, dtype=np.float64)
                fields = {"p_kind": (*center, KIND_DIRECTIONAL), "u": (*(d / np.linalg.norm(d)), 0.0)}
            self.lights.append((1.0, area, m, fields, mid, None))
        return texels

    def plane(self, p, mat):
        mid, _ = mat
        n = np.array(p.normal, dtype=np.float64)
        self.planes.append((p.point, n / np.linalg.norm(n), mid, self._prims(1, bounded=False)[0]))
        if self.uvs is not None:
            self.uvs.append(_planar_uv(((0.0, 0.0), (0.0, 0.0), (0.0, 0.0)), 1))  # no parametrisation
        if self.tangents is not None:
            self.tangents.append(layout.TANGENT.zeros(1))

    def mesh(self, p, mat):
        mid, m = mat
        v, t = p.vertices, p.triangles
        v0, v1, v2 = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
        u, w = v1 - v0, v2 - v0
        prims = self._prims(len(t))
        recs, n, ln = _planar_array(v0, u, w, mid, ITEM_FLAT_TRIANGLE, prims, self._light1(m))
        self.blocks[KIND_TRIANGLE].append(recs)
        if self.uvs is not None or self.tangents is not None:
            tri_uv = DEFAULT_UV
            if p.uvs is not None:
                t0 = p.uvs[t[:, 0]]
                tri_uv = np.stack([t0, p.uvs[t[:, 1]] - t0, p.uvs[t[:, 2]] - t0], axis=1)
            if self.uvs is not None:
                self.uvs.append(_planar_uv(tri_uv, len(t)))
            if self.tangents is not None:
                self.tangents.append(_planar_tangents(u, w, tri_uv))
        self.bounds.append((np.minimum(np.minimum(v0, v1), v2), np.maximum(np.maximum(v0, v1), v2)))
        if p.normals is not None:
            # Triangles whose three vertex normals are their face normal (a
            # box's faces given smooth normals) shade as flat ones: no
            # interpolation, and the BVH may keep a big one out of its tree.
            nv = p.normals[t]
            cos = np.einsum("mkj,mj->mk", nv, n) / np.maximum(np.linalg.norm(nv, axis=2), 1e-300)
            curved = ~(cos >= 1.0 - FLAT_NORMAL_EPS).all(axis=1)
            if curved.any():
                self.normals.append((recs[curved], nv[curved]))
        if m.is_emissive:
            areas = 0.5 * ln
            prob, alias = alias_table(areas)
            tris = layout.LIGHT_TRI.zeros(len(t))
            tris["p_alias"][:, :3], tris["p_alias"][:, 3] = v0, alias
            tris["u_prob"][:, :3], tris["u_prob"][:, 3] = u, prob
            tris["v"][:, :3] = w
            tex = m.texture(EMISSION_SLOT)
            if tex is not None:
                uvs = DEFAULT_UV
                if p.uvs is not None:
                    t0 = p.uvs[t[:, 0]]
                    uvs = np.stack([t0, p.uvs[t[:, 1]] - t0, p.uvs[t[:, 2]] - t0], axis=1)
                self.surface_mean[len(self.lights)] = surface_mean_planar(tex, uvs, areas, True)
            # u.xy of the light record: first triangle record (set on layout), count.
            self.lights.append((_sides(m), float(areas.sum()), m,
                                {"p_kind": (0.0, 0.0, 0.0, LIGHT_KIND_MESH), "u": (0.0, float(len(t)), 0.0, 0.0),
                                 "tex": (0.0, prims[0], 0.0, 0.0)},
                                mid, tris))


def _sides(m: Material) -> float:
    return 2.0 if m.two_sided else 1.0


def _sphere_records(spheres):
    """SPHERE records (plain section) and PLANAR-shaped BVH items of spheres."""
    plain = layout.SPHERE.zeros(len(spheres))
    items = layout.PLANAR.zeros(len(spheres))
    for k, (c, r, mid, prim, light1) in enumerate(spheres):
        plain[k]["center_radius"] = (*c, r)
        plain[k]["mat"] = (mid, light1, prim, 0.0)
        items[k]["corner_mat"] = (*c, mid)
        items[k]["n_light"] = (r, 0.0, 0.0, light1)
        items[k]["wu_prim"] = (0.0, 0.0, 0.0, prim)
        items[k]["wv_kind"] = (0.0, 0.0, 0.0, ITEM_SPHERE)
    return plain, items


# Primitives whose box has at least this share of the scene's box surface
# area stay in the plain loops when there is a BVH, at most BIG_MAX of them.
BIG_SHARE = 0.05
BIG_MAX = 16
# Smooth triangles whose vertex normals all lie within about 1.4e-6 rad (1 - cos
# below this) of their face normal are packed as flat ones (_Builder.mesh).
FLAT_NORMAL_EPS = 1e-12


def _big_primitives(lo, hi, exclude):
    """Mask of the (at most BIG_MAX) primitives, boxes lo..hi, not excluded,
    whose box surface is at least BIG_SHARE of the whole's; at least one
    primitive is left out of it."""
    area = bvh_mod._area(hi - lo)
    whole = float(bvh_mod._area(hi.max(0) - lo.min(0)))
    cand = np.flatnonzero((area >= BIG_SHARE * whole) & ~exclude)
    cand = cand[np.argsort(-area[cand], kind="stable")][:min(BIG_MAX, len(lo) - 1)]
    big = np.zeros(len(lo), dtype=bool)
    big[cand] = True
    return big


def _scene_points(scene: Scene) -> np.ndarray:
    """Points whose convex hull holds every point a path can reach or start
    from: the shapes' vertices, the corners of spheres' boxes, point and spot
    lights' positions, and the camera."""
    pts = [np.array([scene.camera.origin], dtype=np.float64)]
    for s in scene.shapes:
        p = np.asarray(s.points(), dtype=np.float64).reshape(-1, 3)
        if isinstance(s, Sphere) and len(p):  # its box's two corners: all eight
            lo, hi = p.min(0), p.max(0)
            p = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                          for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        pts.append(p)
    return np.concatenate(pts)


def _mark_shadowless(recs: np.ndarray, kind: float, no_shadow: float, pts: np.ndarray) -> int:
    """Gives the PLANAR records of the given kind that no shadow ray can cross
    the kind no_shadow, in place; returns how many. Such a primitive has every
    one of pts (_scene_points) on one side of its plane, or in it: shadow
    rays run between points of their convex hull (a surface point, offset a
    little off its surface on the side it was reached from, and a point on a
    light), which lies in that closed half-space, so they never cross the
    plane (a room's walls, the camera inside or in front). A point counts as
    in the plane within 1e-9 of its and the primitive's coordinates'
    magnitudes (float64 rounding). The points off the plane must also lie
    farther from it than any ray origin's offset can move a point
    (kernels/scene.h offset_distance, bounded by the largest coordinate):
    a ground sphere of radius 1e6 gives the points on it offsets of several
    units, which can carry a shadow ray's origin across a ceiling 0.01 above
    a lamp."""
    cand = np.flatnonzero(recs["wv_kind"][:, 3] == kind) if len(recs) else np.zeros(0, dtype=np.int64)
    if not len(cand) or not len(pts):
        return 0
    n = recs["n_light"][cand, :3]
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    mag = np.abs(pts).max(1)
    # offset_distance's bound: (|p| + err) * OFFSET_REL + floor, err = |origin| + the primitive's magnitude.
    reach = 3 * float(mag.max()) * OFFSET_REL["float"] + OFFSET_FLOOR["float"]
    marked = 0
    for k in range(0, len(cand), 64):  # (points x primitives) in blocks
        c, nk = cand[k:k + 64], n[k:k + 64]
        corner = recs["corner_mat"][c, :3]
        s = pts @ nk.T - np.sum(corner * nk, axis=1)[None, :]
        tol = 1e-9 * (mag[:, None] + np.abs(corner).max(1)[None, :])
        near = (np.abs(s) > tol) & (np.abs(s) < reach)  # off the plane, within an offset of it
        one_side = ((s >= -tol).all(0) | (s <= tol).all(0)) & ~near.any(0)
        recs["wv_kind"][c[one_side], 3] = no_shadow
        marked += int(one_side.sum())
    return marked


def pack_scene(scene: Scene, bvh: str | None = "auto", bvh_method: str = "lbvh",
               shadowless: bool = True) -> PackedScene:
    """bvh: "auto" (a BVH from BVH_MIN_PRIMS bounded primitives), True/"on"
    (always), False/"off" (never: plain loops). shadowless: mark the walls no
    shadow ray of a path can cross (_mark_shadowless); False for queries of
    arbitrary segments (the tests' probes), which may cross them."""
    scene.check()
    scale = length_scale(scene.extent())
    if scale != 1.0:
        scene = scene.scaled(scale)
    surfaces: dict[Material, int] = {}
    b = _Builder()
    if any(scene.surface(p).textures for _, p in scene.primitives()):
        b.uvs = []
    anisotropic = any(scene.surface(p).anisotropic for _, p in scene.primitives())
    if anisotropic:
        b.tangents = []
    for _, p in scene.primitives():
        m = scene.surface(p)
        p.pack(b, (float(surfaces.setdefault(m, len(surfaces))), m))
    if bvh not in ("auto", "on", "off", True, False, None):
        raise ValueError(f"bvh must be 'auto', 'on' or 'off' (got {bvh!r})")
    use_bvh = (b.n_bounded >= BVH_MIN_PRIMS) if bvh == "auto" else bvh in ("on", True)
    use_bvh = use_bvh and b.n_bounded > 0

    sphere_plain, sphere_items = _sphere_records(b.spheres)
    quads = np.concatenate(b.blocks[KIND_QUAD]) if b.blocks[KIND_QUAD] else layout.PLANAR.zeros(0)
    tris = np.concatenate(b.blocks[KIND_TRIANGLE]) if b.blocks[KIND_TRIANGLE] else layout.PLANAR.zeros(0)
    planes = layout.PLANE.zeros(len(b.planes))
    for rec, (point, n, mid, prim) in zip(planes, b.planes):
        rec["point_mat"] = (*point, mid)
        rec["n"] = (*n, prim)

    # Lights at infinity last, around the geometry's bounding sphere; an
    # environment map's texels after every other record.
    env_texels = np.zeros((0, 4))
    if b.infinite:
        center, radius = bounding_sphere(scene)
        env_texels = b.add_infinite_lights(center, radius, 0)

    # Pick lights in proportion to their power: pi * area * mean(Le) per side;
    # a point or spot light's: its intensity's mean times its beam's solid angle;
    # a directional light's: its irradiance through the scene's cross-section
    # pi R^2 (R: the bounding sphere's radius); an environment's: 4 pi^2 R^2
    # times its mean radiance over directions, the power that crosses the
    # bounding sphere inwards.
    lights = b.lights
    # A textured emitter's: its radiance's mean over its surface by area
    # (clpt.texture surface_mean_sphere, surface_mean_planar) for Le.
    powers = np.array([b.delta_power[k] if k in b.delta_power else
                       sides * math.pi * area * float(np.mean(b.surface_mean.get(k, m.mean_emission)))
                       for k, (sides, area, m, *_) in enumerate(lights)])
    probs = powers / powers.sum()
    # Walker's alias table over them: light j's record keeps slot j's
    # probability (info.z) and its alias (n.w), for an O(1) pick.
    keep, alias = alias_table(powers) if len(lights) else (np.zeros(0), np.zeros(0, dtype=np.int64))
    caustics = layout.CAUSTIC.zeros(0)
    objects = _caustic_objects(scene)
    if objects:
        caustics = layout.CAUSTIC.zeros(len(objects))
        caustics["sphere"] = objects

    n_mat = len(surfaces)
    mat_recs = _material_records(list(surfaces))
    if use_bvh:
        # Items in prim order, as the bounds are (spheres, quads and
        # triangles are interleaved in scene order).
        items = np.concatenate([sphere_items, quads, tris]) if len(sphere_items) or len(quads) else tris
        prim = items["wu_prim"][:, 3]
        if not (np.diff(prim) > 0).all():
            items = items[np.argsort(prim, kind="stable")]
        lo = np.concatenate([x for x, _ in b.bounds])
        hi = np.concatenate([y for _, y in b.bounds])
        # The few primitives as big as the scene (a room's walls) stay in the
        # plain loops, which test them against all lanes at once and give the
        # walk a near tmax; in the tree their boxes would overlap everything.
        smooth_prims = np.concatenate([r["wu_prim"][:, 3] for r, _ in b.normals]) if b.normals else np.zeros(0)
        big = _big_primitives(lo, hi, np.isin(items["wu_prim"][:, 3], smooth_prims))
        big_ids = items["wu_prim"][big, 3]
        sphere_plain = sphere_plain[np.isin(sphere_plain["mat"][:, 2], big_ids)]
        quads = quads[np.isin(quads["wu_prim"][:, 3], big_ids)]
        tris = tris[np.isin(tris["wu_prim"][:, 3], big_ids)]
        items, lo, hi = items[~big], lo[~big], hi[~big]
    # The plain loops' walls that no shadow ray can cross, skipped by shadow rays. Not with lights at
    # infinity (a shadow ray towards one leaves the hull) or infinite planes (no hull).
    if shadowless and not b.infinite and not len(planes) and (len(quads) or len(tris)):
        pts = _scene_points(scene)
        _mark_shadowless(quads, ITEM_QUAD, ITEM_QUAD_NO_SHADOW, pts)
        _mark_shadowless(tris, ITEM_FLAT_TRIANGLE, ITEM_TRIANGLE_NO_SHADOW, pts)
    light_recs = layout.LIGHT.zeros(len(lights))  # filled below, once the mesh lights' triangles are placed
    sections = [mat_recs, sphere_plain, quads, tris, planes, light_recs, caustics]
    head = sum(len(Rows.rows(x)) for x in sections)
    # The BVH starts on a 64-byte boundary (4 real4 records; scene.h OFF_BVH),
    # so that a node's rows of 8 floats never straddle cache lines.
    pad = (-head) % 4 if use_bvh else 0
    head += pad
    tree = None
    nodes = np.zeros((0, 4))
    if use_bvh:
        tree = bvh_mod.build(lo, hi, method=bvh_method)
        wide = bvh_mod.collapse(tree)
        if bvh_mod.stack_need(wide) > bvh_mod.MAX_STACK:  # the kernels' traversal stack
            raise SceneError(f"{scene.source}: the BVH is {wide.levels} wide levels deep, more than the kernels' "
                             f"traversal stack holds; try bvh_method='lbvh'")
        # Nodes, then leaf blocks, which hold their items' records whole.
        leaf_base = head + layout.BVH_NODE.stride * wide.n_nodes
        nodes, leaves = bvh_mod.flatten(tree, wide, head, leaf_base, double=False)
        items = items[tree.order]
        bvh_end = leaf_base + layout.BVH_LEAF.stride * len(leaves)
    else:
        bvh_end = head
    # Vertex normals: one NORMALS record per smooth triangle, pointed to by
    # its planar record's kind (wv_kind.w, which the blocks above share).
    normals_base = bvh_end
    smooth = bool(b.normals)
    normal_recs = []
    if smooth:
        if use_bvh:
            slot_prims = items["wu_prim"][:, 3].astype(np.int64)
            prim_to_slot = np.full(b.n_prims, -1, dtype=np.int64)
            prim_to_slot[slot_prims] = np.arange(len(slot_prims))
        k = 0
        for recs, nv in b.normals:
            idx = normals_base + layout.NORMALS.stride * (k + np.arange(len(recs)))
            prims = recs["wu_prim"][:, 3]
            if use_bvh:
                items["wv_kind"][prim_to_slot[prims.astype(np.int64)], 3] = idx
            else:
                tris["wv_kind"][np.searchsorted(tris["wu_prim"][:, 3], prims), 3] = idx
            block = layout.NORMALS.zeros(len(recs))
            for j, f in enumerate(("n0", "n1", "n2")):
                block[f][:, :3] = nv[:, j]
            normal_recs.append(Rows.rows(block))
            k += len(recs)
    normal_recs = np.concatenate(normal_recs) if normal_recs else np.zeros((0, 4))
    if use_bvh:  # the items' records (smooth ones now pointing to their normals) into the leaf blocks
        nodes = np.concatenate([nodes, bvh_mod.leaf_blocks(tree, leaves, items)])
    ltri_base = normals_base + len(normal_recs)
    ltri_recs = []
    for rec, (sides, area, m, fields, mid, ltris), pr, kp, al in zip(light_recs, lights, probs, keep, alias):
        for f, v in fields.items():
            rec[f] = v
        if ltris is not None:
            rec["u"][0] = ltri_base + sum(len(x) for x in ltri_recs)
            ltri_recs.append(Rows.rows(ltris))
        rec["n"][3] = float(al)
        rec["info"] = (area, pr, kp, mid)
    ltri_recs = np.concatenate(ltri_recs) if ltri_recs else np.zeros((0, 4))

    # Rough plastics' transmittance tables (clpt/coating.py), pointed to by their material records.
    coat_base = ltri_base + len(ltri_recs)
    coat_recs = _coat_tables(mat_recs, list(surfaces), coat_base)

    # Textures: their records, the primitives' (u, v) and the texels (scenes with textures only).
    tex_base = coat_base + len(coat_recs)
    textures, slot_recs, tex_recs = _texture_records(mat_recs, list(surfaces), tex_base,
                                                     extra=b.spot_textures.values())
    uv_recs = np.concatenate(b.uvs) if textures and b.uvs else layout.UV.zeros(0)
    uv_base = tex_base + len(Rows.rows(slot_recs)) + len(Rows.rows(tex_recs))
    slot_recs["slots"][:, 3] = uv_base
    # The primitives' dp/du (scenes with an anisotropic material), pointed to by those materials' records.
    tan_base = uv_base + len(Rows.rows(uv_recs))
    tan_recs = np.concatenate(b.tangents) if anisotropic else layout.TANGENT.zeros(0)
    for rec, m in zip(mat_recs, surfaces):
        if m.anisotropic:
            rec["aniso"][1] = tan_base
    texel_base = tan_base + len(Rows.rows(tan_recs))
    texels = _texel_rows(textures, tex_recs, texel_base)
    tex_recs["data"][:, 3] = uv_base
    for k, (rec, (_, _, m, *_)) in enumerate(zip(light_recs, lights)):  # textured emitters: their TEXTURE records
        t = b.spot_textures[k] if k in b.spot_textures else m.texture(EMISSION_SLOT)
        if t is not None:
            rec["tex"][0] = tex_base + len(Rows.rows(slot_recs)) + layout.TEXTURE.stride * next(
                i for i, x in enumerate(textures) if x is t)

    # The environment map's texels and tables last (its light record points to them).
    parts = [Rows.rows(x) for x in sections] + [np.zeros((pad, 4)), nodes, normal_recs, ltri_recs, coat_recs,
                                                Rows.rows(slot_recs), Rows.rows(tex_recs), Rows.rows(uv_recs),
                                                Rows.rows(tan_recs), texels]
    if len(env_texels):
        light_recs["n"][-1, 0] = sum(len(x) for x in parts)
        parts = [Rows.rows(x) for x in sections] + parts[len(sections):] + [env_texels]
    records = np.concatenate(parts)
    n_nodes = wide.n_nodes if use_bvh else 0
    counts = (n_mat, len(sphere_plain), len(quads), len(tris), len(planes), len(lights), len(caustics), n_nodes)
    kinds = {LIGHT_KIND_QUAD: "quad", LIGHT_KIND_TRIANGLE: "triangle", LIGHT_KIND_SPHERE: "sphere",
             LIGHT_KIND_MESH: "mesh", KIND_POINT: "point", KIND_SPOT: "spot", KIND_ENV: "environment",
             KIND_DIRECTIONAL: "directional"}
    lo, hi = scene.bounds(camera=False)
    # The power photons can carry (an environment's: what crosses the bounding sphere inwards).
    flux = sum(b.delta_power[k] / max(float(np.mean(m.emission)), 1e-300) * max(m.emission) if k in b.delta_power
               else sides * math.pi * area * max(m.emission) for k, (sides, area, m, f, *_) in enumerate(lights))
    return PackedScene(records=records, counts=counts, materials=tuple(surfaces),
                       light_kinds=frozenset(kinds[int(f["p_kind"][3])] for _, _, _, f, _, _ in lights),
                       extent=scene.extent(), size=float(np.linalg.norm(hi - lo)) or 1.0, max_flux=flux,
                       max_radiance=max([max(m.emission) * (max(b.spot_textures[k].max()) if k in b.spot_textures
                                                            else 1.0)
                                         for k, (_, _, m, f, *_) in enumerate(lights) if f["p_kind"][3] != KIND_ENV] +
                                        [p.max_radiance() for p, _ in b.infinite if isinstance(p, EnvironmentLight)],
                                        default=1.0),
                       smooth=smooth, bvh=tree, primitives=b.n_bounded, length_scale=scale,
                       pixel_filter=scene.camera.pixel_filter.kind, textures=tuple(textures),
                       texel_rows=len(texels), env_texels=len(env_texels), anisotropic=anisotropic,
                       textured_spots=bool(b.spot_textures),
                       mitsuba_shading=scene.render.shading_normals == "mitsuba")


@dataclass(frozen=True)
class CameraFrame:
    origin: np.ndarray
    corner: np.ndarray  # direction to the image's top-left corner (plane at distance 1)
    dx: np.ndarray      # one pixel to the right
    dy: np.ndarray      # one pixel down


def camera_frame(cam: Camera, width: int, height: int, scale: float = 1.0) -> CameraFrame:
    """The camera's rays; its origin in lengths times scale (PackedScene.length_scale)."""
    o = np.array(cam.origin, dtype=np.float64)
    f = np.array(cam.target, dtype=np.float64) - o
    f /= np.linalg.norm(f)
    right = np.cross(f, np.array(cam.up, dtype=np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    t = math.tan(math.radians(cam.fov) / 2)
    axis = cam.fov_axis
    if axis == "smaller":
        axis = "x" if width <= height else "y"
    elif axis == "larger":
        axis = "x" if width >= height else "y"
    tx, ty = (t, t * height / width) if axis == "x" else (t * width / height, t)
    return CameraFrame(origin=o * scale, corner=f - tx * right + ty * up, dx=right * (2 * tx / width),
                       dy=-up * (2 * ty / height))
