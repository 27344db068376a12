"""Scene -> the packed record array the kernels read (layout: kernels/scene.h).

This is the only module that knows the buffer layout. Records are 4-vectors
of the kernel's real type (float32, or float64 for double-precision builds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .scene import Camera, Material, Plane, Quad, Scene, Sphere, Triangle, length_scale

MAT_STRIDE = 6
SPHERE_STRIDE = 2
PLANAR_STRIDE = 4
PLANE_STRIDE = 2
LIGHT_STRIDE = 5
CAUSTIC_STRIDE = 1

LIGHT_KIND_QUAD, LIGHT_KIND_TRIANGLE, LIGHT_KIND_SPHERE = 0, 1, 2
COUNT_NAMES = ("materials", "spheres", "quads", "triangles", "planes", "lights", "caustics")


@dataclass(frozen=True)
class PackedScene:
    records: np.ndarray          # (n, 4) float64; cast to the kernel's real type on upload
    counts: tuple                # materials, spheres, quads, triangles, planes, lights, caustic objects
    materials: tuple             # the distinct surfaces, in material-id order
    light_kinds: frozenset       # {"quad", "triangle", "sphere"}
    extent: float                # diagonal of the scene's bounds, camera included
    size: float                  # diagonal of the geometry's bounds: the unit of relative photon radii
    max_flux: float              # total emitted power (pi * area * max Le * sides), for photon sum scales
    max_radiance: float = 1.0    # the brightest emission's largest channel
    length_scale: float = 1.0    # the records' lengths are the scene's times this (see length_scale)

    @property
    def lum_scale(self) -> float:
        """The power of two that brings the brightest emission near 1: the
        kernels square luminance times this for the per-pixel variance, which
        then neither overflows nor goes subnormal in float, whatever the
        scene's units of radiance (the image itself is not scaled)."""
        return 2.0 ** -round(math.log2(self.max_radiance)) if self.max_radiance > 0 else 1.0

    def count(self, name: str) -> int:
        return self.counts[COUNT_NAMES.index(name)]

    @property
    def has_phong(self) -> bool:
        return any(max(m.ks) > 0 for m in self.materials)

    @property
    def has_mirror(self) -> bool:
        return any(max(m.kr) > 0 for m in self.materials)

    @property
    def has_glass(self) -> bool:
        return any(max(m.kt) > 0 for m in self.materials)

    @property
    def has_caustics(self) -> bool:
        return self.count("caustics") > 0

    @property
    def max_brdf(self) -> float:
        """Largest value the non-delta lobes of any material can take."""
        return max(max(m.kd) / math.pi + max(m.ks) * (m.shininess + 2) / (2 * math.pi) for m in self.materials)


def lobe_probabilities(m: Material):
    """Russian-roulette probabilities of the diffuse, Phong, mirror and refraction
    lobes: each lobe's largest channel, scaled down if they sum past one.
    Absorption takes the rest, so a lobe's throughput weight k / p is <= 1."""
    p = np.array([max(m.kd), max(m.ks), max(m.kr), max(m.kt)], dtype=np.float64)
    return p / max(1.0, p.sum())


def _material_records(m: Material):
    p_d, p_s, p_r, p_t = lobe_probabilities(m)
    nondelta = 1.0 if p_d > 0 or p_s > 0 else 0.0
    return [
        (*m.kd, p_d),
        (*m.ks, p_s),
        (*m.kr, p_r),
        (*m.kt, p_t),
        (*m.emission, 1.0 if m.two_sided else 0.0),
        (m.shininess, m.ior, nondelta, 1.0 if m.is_emissive else 0.0),
    ]


def _planar_records(corner, u, v, mat_id):
    n_raw = np.cross(u, v)
    nn = float(n_raw @ n_raw)
    n = n_raw / math.sqrt(nn)
    # Dual vectors: for q = a u + b v in the plane, a = q.wu and b = q.wv.
    wu = np.cross(v, n_raw) / nn
    wv = np.cross(n_raw, u) / nn
    return [(*corner, mat_id), (*n, 0.0), (*wu, 0.0), (*wv, 0.0)], n, math.sqrt(nn)


def is_caustic_caster(m: Material) -> bool:
    """Purely specular (mirror and/or refraction, no diffuse or Phong part):
    the surfaces photons pass through on their way to a caustic. Surfaces
    that mix in a diffuse or Phong part are left to the path tracer."""
    return (max(m.kr) > 0 or max(m.kt) > 0) and max(m.kd) == 0 and max(m.ks) == 0


def _caustic_objects(scene: Scene):
    """Bounding spheres (center, radius) of the caustic casters, one per shape
    (a box is one object); radius -1 marks an unbounded one (a plane)."""
    groups: dict[int, list] = {}
    for i, p in scene.primitives():
        if is_caustic_caster(scene.surface(p)):
            groups.setdefault(i, []).append(p)
    out = []
    for prims in groups.values():
        if any(isinstance(p, Plane) for p in prims):
            out.append((0.0, 0.0, 0.0, -1.0))
            continue
        if len(prims) == 1 and isinstance(prims[0], Sphere):
            out.append((*prims[0].center, prims[0].radius))
            continue
        pts = []
        for p in prims:
            if isinstance(p, Sphere):
                c = np.array(p.center, dtype=np.float64)
                pts += [c - p.radius, c + p.radius]
            elif isinstance(p, Triangle):
                pts += [np.array(v, dtype=np.float64) for v in p.vertices]
            else:
                pts += p.vertices()
        pts = np.array(pts)
        c = 0.5 * (pts.min(0) + pts.max(0))
        out.append((*c, float(np.linalg.norm(pts - c, axis=1).max()) * (1 + 1e-6)))
    return out


def pack_scene(scene: Scene) -> PackedScene:
    scene.check()
    k = length_scale(scene.extent())
    if k != 1.0:
        scene = scene.scaled(k)
    surfaces: dict[Material, int] = {}

    def mat_id(shape) -> float:
        m = scene.surface(shape)
        return float(surfaces.setdefault(m, len(surfaces)))

    spheres, quads, tris, planes, lights = [], [], [], [], []  # lights: (power, records)
    for _, p in scene.primitives():
        mid = mat_id(p)
        m = scene.surface(p)
        sides = 2.0 if m.two_sided else 1.0
        # The primitive's light record index + 1 (0: not a light), for the
        # light pdf of BSDF-sampled hits (multiple importance sampling).
        light1 = float(len(lights) + 1) if m.is_emissive else 0.0
        if isinstance(p, Sphere):
            c = np.array(p.center, dtype=np.float64)
            spheres += [(*c, p.radius), (mid, light1, 0.0, 0.0)]
            if m.is_emissive:
                area = 4 * math.pi * p.radius ** 2
                lights.append((sides, area, m, [(*c, LIGHT_KIND_SPHERE), (p.radius, 0.0, 0.0, 0.0),
                                                 (0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0)], mid))
        elif isinstance(p, (Quad, Triangle)):
            if isinstance(p, Quad):
                c, u, v = (np.array(a, dtype=np.float64) for a in (p.corner, p.edge_u, p.edge_v))
            else:
                v0, v1, v2 = (np.array(a, dtype=np.float64) for a in p.vertices)
                c, u, v = v0, v1 - v0, v2 - v0
            recs, n, area = _planar_records(c, u, v, mid)
            recs[1] = (*n, light1)
            kind = LIGHT_KIND_QUAD if isinstance(p, Quad) else LIGHT_KIND_TRIANGLE
            if kind == LIGHT_KIND_TRIANGLE:
                area *= 0.5
            (quads if kind == LIGHT_KIND_QUAD else tris).extend(recs)
            if m.is_emissive:
                lights.append((sides, area, m, [(*c, kind), (*u, 0.0), (*v, 0.0), (*n, 0.0)], mid))
        elif isinstance(p, Plane):
            n = np.array(p.normal, dtype=np.float64)
            planes += [(*p.point, mid), (*(n / np.linalg.norm(n)), 0.0)]

    # Pick lights in proportion to their power: pi * area * mean(Le) per side.
    powers = np.array([sides * math.pi * area * float(np.mean(m.emission)) for sides, area, m, _, _ in lights])
    probs = powers / powers.sum()
    cdf = np.cumsum(probs)
    cdf[-1] = 1.0
    light_recs = []
    for (sides, area, m, recs, mid), pr, cd in zip(lights, probs, cdf):
        light_recs += recs + [(area, pr, cd, mid)]

    caustics = _caustic_objects(scene)
    mat_recs = [r for m in surfaces for r in _material_records(m)]
    records = np.array(mat_recs + spheres + quads + tris + planes + light_recs + caustics,
                       dtype=np.float64).reshape(-1, 4)
    counts = (len(surfaces), len(spheres) // SPHERE_STRIDE, len(quads) // PLANAR_STRIDE,
              len(tris) // PLANAR_STRIDE, len(planes) // PLANE_STRIDE, len(lights), len(caustics))
    kinds = {LIGHT_KIND_QUAD: "quad", LIGHT_KIND_TRIANGLE: "triangle", LIGHT_KIND_SPHERE: "sphere"}
    lo, hi = scene.bounds(camera=False)
    flux = sum(sides * math.pi * area * max(m.emission) for sides, area, m, _, _ in lights)
    return PackedScene(records=records, counts=counts, materials=tuple(surfaces),
                       light_kinds=frozenset(kinds[int(r[0][3])] for _, _, _, r, _ in lights),
                       extent=scene.extent(), size=float(np.linalg.norm(hi - lo)) or 1.0, max_flux=flux,
                       max_radiance=max((max(m.emission) for _, _, m, _, _ in lights), default=1.0),
                       length_scale=k)


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
