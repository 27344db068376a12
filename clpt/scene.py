"""Scenes: the data model, the TOML scene format, and validation.

A scene is a camera, named materials and a list of shapes; any shape with
emission is an area light. The same classes are the Python API
(``clpt.Scene(camera=..., shapes=[clpt.Sphere(...)])``) and what
``parse_scene`` builds from a TOML file's text (format: scenes/README.md;
``clpt.load_scene``, clpt/loading.py, reads a file of either format).

Every mistake in a user's scene is reported as a ``SceneError`` whose message
names the file, the key path and the reason, e.g.::

    scenes/bad.toml: shapes[3] "light".radius: must be > 0 (got -0.5)
"""

from __future__ import annotations

import difflib
import hashlib
import math
import tomllib
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Union

import numpy as np

from .errors import ImageError, MeshError, SceneError, SceneWarning, SettingsError  # noqa: F401 - importable
from .hostio import open_regular_file
from .meshio import check_mesh, compose, cross_rows, norm_rows, read_mesh, transform_mesh
from .presets import PRESETS
from .spectrum import conductor_ior
from .constants import LUMA
from .errors import ImageError
from .texture import FILTERS, KINDS, WRAP_MODES, Texture, _eval_mean, _texels_per_unit, load_bitmap

# Material.textures slots: "reflectance" (kd, or kp of a plastic), "specular" (km, kgr of a rough
# dielectric, or kr), "alpha" (a rough conductor's roughness: the texture's luminance), "transmittance"
# (kgt of a rough dielectric, or kt).
TEXTURE_SLOTS = ("reflectance", "specular", "alpha", "transmittance")
# An area light's radiance varying over its surface by (u, v): the light's own slot (its LIGHT record
# points to the texture; the material's texture slots above are the BSDF's).
EMISSION_SLOT = "emission"
# The start of the error a scene without any light fails with (scene.check).
NO_LIGHT = "the scene has no light"
# A planar primitive's default (u, v): the corner's, and its change along
# edge_u and along edge_v (a triangle's: its barycentrics of v1 and v2, as
# Mitsuba gives a mesh without texture coordinates).
DEFAULT_UV = ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))

Vec3 = tuple[float, float, float]

FOV_AXES = ("x", "y", "smaller", "larger")


# --- data model --------------------------------------------------------------------


@dataclass(frozen=True)
class Material:
    """The paper's material model, per RGB channel.

    kd: diffuse albedo; ks and shininess: modified-Phong specular lobe
    (f = ks (n+2)/(2 pi) cos^n alpha); kr: perfect mirror; kt and ior:
    refraction through a dielectric interface with exact Fresnel. Absorption
    is what remains, 1 - (kd + ks + km + kr + kt), which must not be negative.
    km, alpha, distribution, eta and k: a rough conductor's microfacet lobe
    as Mitsuba 3's `roughconductor` defines it (f = km F D G / (4 cos_o
    cos_i)): roughness alpha, distribution "beckmann" (Mitsuba's default) or "ggx",
    conductor Fresnel of the complex index eta + i k per channel (eta 0, k 1:
    F = 1); `Material.rough_conductor` fills them from a named conductor.
    plastic, kp, kps, plastic_eta, nonlinear (with alpha and distribution):
    Mitsuba 3's `roughplastic` (alpha > 0) or smooth `plastic` (alpha 0), a
    dielectric coating of relative index plastic_eta (inside over outside)
    with specular_reflectance kps over a diffuse base of diffuse_reflectance
    kp, with its internal scattering (clpt/coating.py); the material's only
    lobe (`Material.rough_plastic`, `Material.smooth_plastic`).
    rough_dielectric_lobe, kgr, kgt, sample_visible (with ior, alpha and
    distribution): Mitsuba 3's `roughdielectric`, a microfacet interface of
    relative index ior (inside over outside) that reflects (specular_reflectance
    kgr) and refracts (specular_transmittance kgt) through the same microfacet
    normal; the material's only lobe (`Material.rough_dielectric`).
    textures: ((slot, clpt.texture.Texture), ...): "reflectance" varies kd
    (kp of a plastic), "specular" km (kgr of a rough dielectric, or kr),
    "transmittance" kgt of a rough dielectric (or kt) over the surface by its
    (u, v); the colour field then holds the texture's largest value per
    channel (the bound lobe probabilities and energy checks use). "alpha"
    varies a rough conductor's roughness (the texture's luminance, within
    ALPHA_RANGE; alpha holds its mean). "emission" varies an area light's
    radiance (Mitsuba 3's textured `area` emitter: the texture's value at the
    point's (u, v)); emission then holds the texture's largest value per
    channel, and the light is picked by the texture's mean over its surface
    by area (clpt.texture surface_mean_*) times its area.
    alpha_v: a rough conductor's or rough dielectric's roughness along the
    shading frame's bitangent, alpha then being its roughness along the
    tangent (Mitsuba's alpha_u), the surface's dp/du as Mitsuba's shapes
    parametrise it (None: alpha_v = alpha, isotropic).
    emission is radiance leaving the surface (on the side its normal points
    to, or both sides if two_sided). one_sided makes the surface black from
    behind (the side its normal points away from): no reflection, no
    transmission, as Mitsuba's BSDFs outside a twosided wrapper.
    """

    kd: Vec3 = (0.0, 0.0, 0.0)
    ks: Vec3 = (0.0, 0.0, 0.0)
    shininess: float = 0.0
    kr: Vec3 = (0.0, 0.0, 0.0)
    kt: Vec3 = (0.0, 0.0, 0.0)
    ior: float = 1.5
    emission: Vec3 = (0.0, 0.0, 0.0)
    two_sided: bool = False
    one_sided: bool = False
    km: Vec3 = (0.0, 0.0, 0.0)
    alpha: float = 0.1
    alpha_v: float | None = None
    distribution: str = "beckmann"
    eta: Vec3 = (0.0, 0.0, 0.0)
    k: Vec3 = (1.0, 1.0, 1.0)
    plastic: bool = False
    kp: Vec3 = (0.5, 0.5, 0.5)
    kps: Vec3 = (1.0, 1.0, 1.0)
    plastic_eta: float = 1.49 / 1.000277
    nonlinear: bool = False
    rough_dielectric_lobe: bool = False
    kgr: Vec3 = (1.0, 1.0, 1.0)
    kgt: Vec3 = (1.0, 1.0, 1.0)
    sample_visible: bool = True
    textures: tuple = ()

    def __post_init__(self):
        # Types now (a clear TypeError at the mistake); ranges in check_material.
        for key in ("kd", "ks", "kr", "kt", "emission", "km", "eta", "k", "kp", "kps", "kgr", "kgt"):
            v = getattr(self, key)
            if isinstance(v, (str, bytes)) or not hasattr(v, "__len__") or len(v) != 3 or \
                    not all(_is_number(c) for c in v):
                raise TypeError(f"Material.{key} must be 3 numbers, e.g. (0.5, 0.5, 0.5) (got {v!r})")
        if not isinstance(self.distribution, str):
            raise TypeError(f"Material.distribution must be a string, one of {', '.join(DISTRIBUTIONS)} "
                            f"(got {self.distribution!r})")
        for key in ("shininess", "ior", "alpha", "plastic_eta"):
            if not _is_number(getattr(self, key)):
                raise TypeError(f"Material.{key} must be a number (got {getattr(self, key)!r})")
        if self.alpha_v is not None and not _is_number(self.alpha_v):
            raise TypeError(f"Material.alpha_v must be a number or None (got {self.alpha_v!r})")
        for key in ("two_sided", "plastic", "nonlinear", "rough_dielectric_lobe", "sample_visible"):
            if not isinstance(getattr(self, key), (bool, np.bool_)):
                raise TypeError(f"Material.{key} must be True or False (got {getattr(self, key)!r})")
        slots = [s for s, _ in self.textures] if isinstance(self.textures, tuple) and \
            all(isinstance(x, tuple) and len(x) == 2 for x in self.textures) else None
        known = TEXTURE_SLOTS + (EMISSION_SLOT,)
        if slots is None or any(s not in known for s in slots) or len(set(slots)) != len(slots) or \
                not all(isinstance(t, Texture) for _, t in self.textures):
            raise TypeError(f"Material.textures must be ((slot, clpt.texture.Texture), ...) with slots among "
                            f"{', '.join(known)}, each once (got {self.textures!r})")

    @property
    def anisotropic(self) -> bool:
        """A microfacet lobe (rough conductor or rough dielectric) with alpha_v != alpha."""
        return self.alpha_v is not None and self.alpha_v != self.alpha and \
            (max(self.km) > 0 or self.rough_dielectric_lobe)

    def texture(self, slot: str):
        """The Texture in a slot ("reflectance": kd, or kp of a plastic; "specular": km, or kr; "alpha": a
        rough conductor's alpha), or None."""
        return next((t for s, t in self.textures if s == slot), None)

    @classmethod
    def preset(cls, name: str, **overrides) -> "Material":
        """A named preset (see clpt.presets.PRESETS), with fields overridden."""
        if name not in PRESETS:
            raise SceneError(f"unknown material preset {name!r}{_suggest(name, PRESETS)}")
        return cls(**{**PRESETS[name], **overrides})

    @classmethod
    def rough_conductor(cls, material: str = "none", alpha: float = 0.1, distribution: str = "beckmann",
                        specular_reflectance: Vec3 = (1.0, 1.0, 1.0), **overrides) -> "Material":
        """A rough conductor (Mitsuba 3's `roughconductor`, one-sided): a named
        conductor's eta and k as Mitsuba's RGB variants use them (`clpt
        check` on an XML scene lists the names; "none": F = 1)."""
        eta, k = conductor_ior(material)
        base = dict(km=tuple(float(c) for c in specular_reflectance), alpha=alpha, distribution=distribution,
                    eta=eta, k=k, one_sided=True)
        return cls(**{**base, **overrides})

    @classmethod
    def rough_plastic(cls, diffuse_reflectance: Vec3 = (0.5, 0.5, 0.5), alpha: float = 0.1,
                      distribution: str = "beckmann", int_ior: float = 1.49, ext_ior: float = 1.000277,
                      specular_reflectance: Vec3 = (1.0, 1.0, 1.0), nonlinear: bool = False,
                      **overrides) -> "Material":
        """Mitsuba 3's `roughplastic` (one-sided; its defaults: Beckmann,
        alpha 0.1, polypropylene in air). alpha=0 is the smooth `plastic`."""
        _check_iors("rough_plastic", int_ior, ext_ior)
        base = dict(plastic=True, kp=tuple(float(c) for c in diffuse_reflectance),
                    kps=tuple(float(c) for c in specular_reflectance), alpha=alpha, distribution=distribution,
                    plastic_eta=int_ior / ext_ior, nonlinear=nonlinear, one_sided=True)
        return cls(**{**base, **overrides})

    @classmethod
    def smooth_plastic(cls, diffuse_reflectance: Vec3 = (0.5, 0.5, 0.5), **kw) -> "Material":
        """Mitsuba 3's smooth `plastic` (the keywords of rough_plastic but alpha)."""
        return cls.rough_plastic(diffuse_reflectance, alpha=0.0, **kw)

    @classmethod
    def rough_dielectric(cls, alpha: float = 0.1, distribution: str = "beckmann", int_ior: float = 1.5046,
                         ext_ior: float = 1.000277, specular_reflectance: Vec3 = (1.0, 1.0, 1.0),
                         specular_transmittance: Vec3 = (1.0, 1.0, 1.0), sample_visible: bool = True,
                         **overrides) -> "Material":
        """Mitsuba 3's `roughdielectric` (its defaults: Beckmann, alpha 0.1,
        BK7 glass in air)."""
        _check_iors("rough_dielectric", int_ior, ext_ior)
        base = dict(rough_dielectric_lobe=True, kgr=tuple(float(c) for c in specular_reflectance),
                    kgt=tuple(float(c) for c in specular_transmittance), alpha=alpha, distribution=distribution,
                    ior=int_ior / ext_ior, sample_visible=sample_visible)
        return cls(**{**base, **overrides})

    @property
    def is_emissive(self) -> bool:
        return max(self.emission) > 0.0

    @property
    def mean_emission(self) -> tuple:
        """The emission's mean over the surface's texture space: a textured
        emitter's texture mean over texture space, else emission (light
        selection by power uses the mean over the surface by area: clpt.pack)."""
        t = self.texture(EMISSION_SLOT)
        return t.mean() if t is not None else tuple(self.emission)

    @property
    def bsdf_textures(self) -> tuple:
        """The textures of the BSDF's slots (TEXTURE_SLOTS): those the material record points to."""
        return tuple((s, t) for s, t in self.textures if s != EMISSION_SLOT)

    @property
    def is_specular(self) -> bool:
        """Has a delta lobe (mirror or refraction): a caustic caster."""
        return max(self.kr) > 0.0 or max(self.kt) > 0.0


MaterialRef = Union[str, Material]


def _check_iors(who: str, int_ior, ext_ior):
    for name, v in (("int_ior", int_ior), ("ext_ior", ext_ior)):
        if not _is_number(v) or not IOR_RANGE[0] <= v <= IOR_RANGE[1]:
            raise SceneError(f"{who}: {name} must be a number in [{IOR_RANGE[0]:g}, {IOR_RANGE[1]:g}] (got {v!r})")


def _is_number(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


PIXEL_FILTERS = ("box", "tent", "gaussian")
FILTER_MAX_RADIUS = 256.0  # pixels


@dataclass(frozen=True)
class PixelFilter:
    """How a camera sample's position is spread over the image: Mitsuba 3's
    reconstruction filters, with its parameters and defaults.

    - "box": a uniform position in the pixel (radius 0.5, no parameters).
    - "tent": max(0, 1 - |x| / radius), radius 1 pixel by default.
    - "gaussian": exp(-x^2 / (2 stddev^2)) minus its value at 4 stddev, cut
      off there (radius = 4 stddev); stddev 0.5 pixels by default. Mitsuba's
      default filter.

    Filters are separable (w(x) w(y)) and importance sampled: each sample's
    offset from its pixel's centre is drawn from the normalized filter, so a
    pixel is a plain mean of its own samples whose expectation is the
    filter-weighted mean Mitsuba's splatting gives (sum w L / sum w).
    sample_border: as Mitsuba's film option, whether samples may land
    outside the film (False: a pixel near the edge has its filter cut at the
    edge, as Mitsuba does by default)."""

    kind: str = "box"
    radius: float | None = None   # tent only (default 1)
    stddev: float | None = None   # gaussian only (default 0.5)
    sample_border: bool = False

    @property
    def extent(self) -> float:
        """The filter's radius in pixels."""
        if self.kind == "tent":
            return 1.0 if self.radius is None else float(self.radius)
        if self.kind == "gaussian":
            return 4.0 * self.sigma
        return 0.5

    @property
    def sigma(self) -> float:
        return 0.5 if self.stddev is None else float(self.stddev)

    def check(self, src: str, path: str):
        if self.kind not in PIXEL_FILTERS:
            _fail(src, f"{path}.kind", f"must be one of {', '.join(PIXEL_FILTERS)} (got {self.kind!r})")
        for key, owner in (("radius", "tent"), ("stddev", "gaussian")):
            v = getattr(self, key)
            if v is None:
                continue
            if self.kind != owner:
                _fail(src, f"{path}.{key}", f"only the {owner} filter has a {key} (this one is {self.kind!r})")
            hi = FILTER_MAX_RADIUS / (4 if key == "stddev" else 1)
            _finite(src, f"{path}.{key}", v, lo=0.0)
            if not 1e-3 <= v <= hi:
                _fail(src, f"{path}.{key}", f"must be from 0.001 to {hi:g} pixels (got {v:g})")
        if not isinstance(self.sample_border, (bool, np.bool_)):
            _fail(src, f"{path}.sample_border", f"must be true or false (got {self.sample_border!r})")


@dataclass(frozen=True)
class Camera:
    """Pinhole camera looking from origin towards target.

    fov is the full field of view in degrees along fov_axis: "x", "y", or the
    "smaller"/"larger" image dimension (Mitsuba's convention).
    """

    origin: Vec3 = (0.0, 0.0, 3.9)
    target: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 = (0.0, 1.0, 0.0)
    fov: float = 39.3077
    fov_axis: str = "smaller"
    width: int = 256
    height: int = 256
    pixel_filter: PixelFilter = PixelFilter()


SHADING_NORMALS = ("mirror", "mitsuba")  # RenderSettings.shading_normals


@dataclass(frozen=True)
class RenderSettings:
    """Defaults a scene file may set; render() keywords override them.

    max_depth counts scattering events (pbrt's convention): 0 shows emitters
    only, 1 adds direct light. Mitsuba's max_depth is this plus one.
    rr_depth is the depth from which Russian roulette may absorb a path.
    hide_emitters (Mitsuba 3's integrator option): camera rays see no
    emission (an emitter seen directly is black, as is the environment
    behind the scene); the light emitters cast is unchanged.
    shading_normals: how smooth triangles' interpolated normals shade.
    "mirror" (clpt's own): a scattered ray a tilted shading normal sends
    across the geometric surface is mirrored back, and a shading normal the
    incoming ray sees from behind is turned to the geometric normal's side.
    "mitsuba" (Mitsuba 3's, which the XML loader sets): the ray goes on
    across, and where the incoming ray is behind the shading normal a
    two-sided material shades with the normal turned to the ray, a one-sided
    one is black (its delta lobes still reflect and refract).
    """

    spp: int = 64
    max_depth: int = 8
    seed: int = 0
    rr_depth: int = 2
    hide_emitters: bool = False
    shading_normals: str = "mirror"

    def __post_init__(self):
        if self.shading_normals not in SHADING_NORMALS:
            raise SettingsError(f"shading_normals must be one of {', '.join(SHADING_NORMALS)} "
                                f"(got {self.shading_normals!r})")


@dataclass(frozen=True)
class _ShapeBase:
    """What every shape has. Each kind defines, once, its own geometry:
    check (validation, SceneError naming src and path), area, points (what
    its bounds enclose), primitives (what the packer sees: itself, or a
    Box's quads) and, for primitives, pack (clpt/pack.py's builder)."""

    material: MaterialRef = "white"
    emission: Vec3 | None = None   # overrides the material's emission
    two_sided: bool | None = None  # overrides the material's two_sided
    name: str | None = None

    can_emit = True  # class attributes: may this kind be a light? has it finite bounds?
    bounded = True

    def primitives(self):
        return [self]

    def points(self) -> np.ndarray:
        raise NotImplementedError

    def area(self) -> float:
        raise NotImplementedError

    def check(self, src: str, path: str):
        raise NotImplementedError


@dataclass(frozen=True)
class Sphere(_ShapeBase):
    """uv_frame: the rows of the rotation from world to the sphere's own
    frame, in which (u, v) = (phi / 2 pi, theta / pi) of the direction from
    its centre (Mitsuba 3's sphere parametrisation)."""

    center: Vec3 = (0.0, 0.0, 0.0)
    radius: float = 1.0
    uv_frame: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))

    def check(self, src, path):
        _finite_vec(src, f"{path}.center", self.center)
        _finite(src, f"{path}.radius", self.radius, lo=0.0)

    def area(self):
        return 4 * math.pi * self.radius ** 2

    def points(self):
        c = np.array(self.center, dtype=np.float64)
        return np.array([c - self.radius, c + self.radius])

    def pack(self, b, mat):
        b.sphere(self, mat)


@dataclass(frozen=True)
class Triangle(_ShapeBase):
    """Triangle v0 v1 v2; its front face is given by the right-hand rule."""

    vertices: tuple[Vec3, Vec3, Vec3] = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    uv: tuple = DEFAULT_UV  # (u, v) at v0, and its change towards v1 and towards v2

    def check(self, src, path):
        if len(self.vertices) != 3:
            _fail(src, f"{path}.vertices", f"must be 3 points (got {len(self.vertices)})")
        v = [_finite_vec(src, f"{path}.vertices[{k}]", p) for k, p in enumerate(self.vertices)]
        _planar_area(src, path, v[1] - v[0], v[2] - v[0], "triangle")

    def area(self):
        v0, v1, v2 = self.points()
        return 0.5 * float(np.linalg.norm(np.cross(v1 - v0, v2 - v0)))

    def points(self):
        return np.array(self.vertices, dtype=np.float64)

    def pack(self, b, mat):
        v0, v1, v2 = self.points()
        b.planar(v0, v1 - v0, v2 - v0, mat, triangle=True, light=True, uv=self.uv)


@dataclass(frozen=True)
class Quad(_ShapeBase):
    """Parallelogram corner + a edge_u + b edge_v, a and b in [0, 1].

    Its normal is edge_u x edge_v (the front face, for one-sided emitters).
    """

    corner: Vec3 = (0.0, 0.0, 0.0)
    edge_u: Vec3 = (1.0, 0.0, 0.0)
    edge_v: Vec3 = (0.0, 1.0, 0.0)
    uv: tuple = DEFAULT_UV  # (u, v) at the corner, and its change along edge_u and along edge_v

    @classmethod
    def from_vertices(cls, vertices, **kw) -> "Quad":
        """From four corners in order around the quad (a parallelogram)."""
        try:
            v = [tuple(float(c) for c in p) for p in vertices]
        except (TypeError, ValueError):
            raise SceneError(f"a quad's vertices must be 4 points of 3 numbers (got {vertices!r})") from None
        if len(v) != 4 or any(len(p) != 3 for p in v):
            raise SceneError(f"a quad needs 4 vertices of 3 numbers, got {vertices!r}")
        p0, p1, p2, p3 = (np.array(p) for p in v)
        ext = max(np.linalg.norm(a - b) for a in (p0, p1, p2, p3) for b in (p0, p1, p2, p3))
        if not np.linalg.norm(p0 + p2 - p1 - p3) <= 1e-6 * ext:
            raise SceneError("the 4 corners are not a parallelogram (v0 + v2 must equal v1 + v3); "
                             "split it into triangles")
        return cls(corner=v[0], edge_u=tuple(p1 - p0), edge_v=tuple(p3 - p0), **kw)

    def vertices(self):
        c, u, v = (np.array(a, dtype=np.float64) for a in (self.corner, self.edge_u, self.edge_v))
        return [c, c + u, c + u + v, c + v]

    def check(self, src, path):
        _finite_vec(src, f"{path}.corner", self.corner)
        u = _finite_vec(src, f"{path}.edge_u", self.edge_u)
        v = _finite_vec(src, f"{path}.edge_v", self.edge_v)
        _planar_area(src, path, u, v, "quad")

    def area(self):
        return float(np.linalg.norm(np.cross(self.edge_u, self.edge_v)))

    def points(self):
        return np.array(self.vertices())

    def pack(self, b, mat):
        c, u, v = (np.array(a, dtype=np.float64) for a in (self.corner, self.edge_u, self.edge_v))
        b.planar(c, u, v, mat, triangle=False, light=True, uv=self.uv)


@dataclass(frozen=True)
class Plane(_ShapeBase):
    """Infinite plane through point with the given normal. It cannot emit."""

    point: Vec3 = (0.0, 0.0, 0.0)
    normal: Vec3 = (0.0, 1.0, 0.0)

    can_emit = False
    bounded = False

    def check(self, src, path):
        _finite_vec(src, f"{path}.point", self.point)
        if np.linalg.norm(_finite_vec(src, f"{path}.normal", self.normal)) == 0.0:
            _fail(src, f"{path}.normal", "must not be zero")

    def area(self):
        return 0.0

    def points(self):
        return np.array([self.point], dtype=np.float64)

    def pack(self, b, mat):
        b.plane(self, mat)


@dataclass(frozen=True)
class Box(_ShapeBase):
    """Axis-aligned box of the given size, rotated (degrees, about x then y
    then z) and moved to center: six quads facing out, or in if inward."""

    center: Vec3 = (0.0, 0.0, 0.0)
    size: Vec3 = (1.0, 1.0, 1.0)
    rotation: Vec3 = (0.0, 0.0, 0.0)
    inward: bool = False

    def check(self, src, path):
        _finite_vec(src, f"{path}.center", self.center)
        _finite_vec(src, f"{path}.rotation", self.rotation)
        size = _finite_vec(src, f"{path}.size", self.size)
        if (size <= 0).any():
            _fail(src, f"{path}.size", f"must be > 0 in every axis (got {list(self.size)})")

    def area(self):
        x, y, z = self.size
        return 2 * (x * y + y * z + x * z)

    def points(self):
        return np.concatenate([q.points() for q in self.quads()])

    def primitives(self):
        return self.quads()

    def quads(self) -> list[Quad]:
        rx, ry, rz = (math.radians(a) for a in self.rotation)
        cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
        mx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        my = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        mz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        m = mz @ my @ mx
        h = 0.5 * np.array(self.size, dtype=np.float64)
        c = np.array(self.center, dtype=np.float64)
        out = []
        # For each axis and side: the face's corner and two edges, ordered so
        # that edge_u x edge_v points out of the box.
        for axis in range(3):
            a1, a2 = (axis + 1) % 3, (axis + 2) % 3
            for side in (-1.0, 1.0):
                corner = np.zeros(3)
                corner[axis] = side * h[axis]
                corner[a1] = -h[a1]
                corner[a2] = -h[a2]
                eu = np.zeros(3)
                ev = np.zeros(3)
                eu[a1] = 2 * h[a1]
                ev[a2] = 2 * h[a2]
                if (side < 0) != self.inward:
                    eu, ev = ev, eu
                out.append(Quad(corner=tuple(m @ corner + c), edge_u=tuple(m @ eu), edge_v=tuple(m @ ev),
                                material=self.material, emission=self.emission, two_sided=self.two_sided,
                                name=self.name))
        return out


@dataclass(frozen=True, eq=False)
class Mesh(_ShapeBase):
    """A triangle mesh in world space (any transform already applied).

    vertices (N, 3) floats, triangles (M, 3) vertex indices (front faces by
    the right-hand rule), normals (N, 3) per-vertex shading normals or None
    (flat shading), uvs (N, 2) per-vertex texture coordinates or None (each
    triangle's barycentrics of v1 and v2, as Mitsuba). The arrays are checked
    and copied (float64, int64, read-only); degenerate triangles are dropped
    with one warning. Mesh.from_file reads OBJ or PLY (clpt.meshio)."""

    vertices: np.ndarray = None
    triangles: np.ndarray = None
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None

    def __post_init__(self):
        v, t, n = check_mesh(self.vertices, self.triangles, self.normals,
                             source=f"mesh {self.name!r}" if self.name else "mesh")
        uv = None
        if self.uvs is not None:
            uv = np.array(self.uvs, dtype=np.float64)
            if uv.shape != (len(v), 2) or not np.isfinite(uv).all():
                raise MeshError(f"mesh {self.name!r}: uvs must be finite, one (u, v) per vertex, shape "
                                f"{(len(v), 2)} (got {uv.shape})")
            uv.setflags(write=False)
        object.__setattr__(self, "uvs", uv)
        for a in (v, t, n):
            if a is not None:
                a.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "triangles", t)
        object.__setattr__(self, "normals", n)

    def check(self, src, path):
        pass  # checked (and degenerate triangles dropped) on construction

    def triangle_areas(self) -> np.ndarray:
        v, t = self.vertices, self.triangles
        a = v[t[:, 0]]
        return 0.5 * norm_rows(cross_rows(v[t[:, 1]] - a, v[t[:, 2]] - a))

    def area(self):
        # The arrays are read-only, so the sum is computed once.
        if "_area" not in self.__dict__:
            object.__setattr__(self, "_area", float(self.triangle_areas().sum()))
        return self.__dict__["_area"]

    def points(self):
        return self.vertices

    def pack(self, b, mat):
        b.mesh(self, mat)

    @classmethod
    def from_file(cls, path, transform=None, **kw) -> "Mesh":
        """Read an OBJ or PLY file; transform: a 4x4 matrix applied to it."""
        v, t, n = read_mesh(path)
        if transform is not None:
            v, n = transform_mesh(v, n, transform)
        return cls(vertices=v, triangles=t, normals=n, **kw)

    def __repr__(self):
        return (f"Mesh({len(self.triangles)} triangles, {len(self.vertices)} vertices"
                f"{', normals' if self.normals is not None else ''}, material={self.material!r}"
                f"{f', name={self.name!r}' if self.name else ''})")


@dataclass(frozen=True)
class PointLight(_ShapeBase):
    """A point light (Mitsuba 3's ``point``): radiant intensity ``intensity``
    (W/sr per channel) from ``position`` into every direction. A delta light:
    found by next event estimation only (irradiance I cos / d^2 at distance
    d), never by a BSDF-sampled ray, and a source of caustic photons. It has
    no surface: ``material``, ``emission`` and ``two_sided`` do not apply."""

    position: Vec3 = (0.0, 0.0, 0.0)
    intensity: Vec3 = (1.0, 1.0, 1.0)

    bounded = True
    delta = True

    def check(self, src, path):
        _finite_vec(src, f"{path}.position", self.position)
        _emission(src, f"{path}.intensity", self.intensity)
        if self.emission is not None or self.two_sided is not None:
            _fail(src, path, "a point or spot light has an intensity, not emission or two_sided")

    def area(self):
        return 0.0

    def points(self):
        return np.array([self.position], dtype=np.float64)

    def solid_angle(self) -> float:
        """The integral of the intensity profile over the sphere of directions (4 pi)."""
        return 4 * math.pi

    def power(self) -> float:
        """Emitted power per channel, averaged over the channels."""
        return self.solid_angle() * float(np.mean(self.intensity))

    def light_material(self) -> "Material":
        return Material(emission=tuple(float(c) for c in self.intensity))

    def pack(self, b, mat):
        b.delta_light(self, mat)


@dataclass(frozen=True)
class SpotLight(PointLight):
    """A spot light (Mitsuba 3's ``spot``): intensity ``intensity`` along
    ``direction`` from ``position``, full up to ``beam_width`` degrees off the
    axis, falling linearly in angle to zero at ``cutoff_angle`` degrees (by
    default 20, and a beam width of 3/4 of the cutoff), as Mitsuba's
    ``falloff_curve``: 1 for theta <= beam, (cutoff - theta) / (cutoff - beam)
    between, 0 from the cutoff on.

    ``texture`` (Mitsuba's ``texture``: a clpt.texture.Texture, or an
    H x W x 3 array of linear RGB for a bilinear, repeating bitmap) is
    projected through the cone: the intensity towards direction w is
    multiplied by the texture at (u, v) = (1/2 + x / (2 z tan(cutoff)),
    1/2 + y / (2 z tan(cutoff))), (x, y, z) the coordinates of w in the
    light's frame. ``texture_axes`` = (x axis, y axis) is that frame's x and
    y axes in world space (Mitsuba's to_world's first two columns, over the
    length of its third; perpendicular to ``direction``); None: Mitsuba's
    look_at frame with up = +y (+z when the direction is along y): x = up
    x direction, normalized, y = direction x x."""

    direction: Vec3 = (0.0, 0.0, 1.0)
    cutoff_angle: float = 20.0
    beam_width: float | None = None
    texture: Texture | None = None
    texture_axes: tuple | None = None

    def __post_init__(self):
        if self.texture is not None and not isinstance(self.texture, Texture):
            object.__setattr__(self, "texture", Texture("bitmap", data=self.texture, name="spot light texture"))
        if self.texture_axes is not None:
            object.__setattr__(self, "texture_axes", tuple(tuple(float(c) for c in np.broadcast_to(
                np.asarray(a, dtype=np.float64), 3)) for a in self.texture_axes))

    @property
    def beam(self) -> float:
        return 0.75 * float(self.cutoff_angle) if self.beam_width is None else float(self.beam_width)

    def frame(self) -> np.ndarray:
        """The light's frame as the columns of a 3x3 matrix: texture_axes and the unit direction."""
        d = np.asarray(self.direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        if self.texture_axes is not None:
            x, y = (np.asarray(a, dtype=np.float64) for a in self.texture_axes)
        else:
            up = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 1 - 1e-6 else np.array([0.0, 0.0, 1.0])
            x = np.cross(up, d)
            x /= np.linalg.norm(x)
            y = np.cross(d, x)
        return np.stack([x, y, d], axis=1)

    def texture_rows(self) -> np.ndarray:
        """(2, 3): rows a, b with (u, v) = 1/2 + (a . w, b . w) / (axis . w) for a unit direction w in the
        cone (the first two rows of the frame's inverse over the length of the third, over 2 tan(cutoff))."""
        inv = np.linalg.inv(self.frame())
        return inv[:2] / (np.linalg.norm(inv[2]) * 2 * math.tan(math.radians(self.cutoff_angle)))

    def texture_cone_mean(self) -> tuple:
        """The texture's mean over the cone weighted by the falloff, per channel:
        (integral of falloff T(uv) over directions) / solid_angle(). The
        midpoint rule on a grid over (u, v) (the cone is the disk of radius 1/2
        around (1/2, 1/2)), about 4 points per texel (64 to 1024 a side), each
        point weighted by its direction's solid angle, (2 tan g)^2 / (1 + r^2)^(3/2)
        du dv for r = tan theta, and by the falloff."""
        n = int(np.clip(math.ceil(4 * _texels_per_unit(self.texture)), 64, 1024))
        t = (np.arange(n) + 0.5) / n
        uv = np.stack(np.meshgrid(t, t), axis=-1).reshape(-1, 2)
        g = math.radians(self.cutoff_angle)
        r = np.hypot(uv[:, 0] - 0.5, uv[:, 1] - 0.5) * 2 * math.tan(g)  # tan theta
        w = self.falloff(1 / np.sqrt(1 + r * r)) / (1 + r * r) ** 1.5
        if not w.sum() > 0:
            return tuple(float(x) for x in self.texture.eval(np.array([0.5, 0.5])))
        return tuple(float(x) for x in _eval_mean(self.texture, uv, w))

    def power(self) -> float:
        if self.texture is None:
            return super().power()
        return self.solid_angle() * float(np.mean(np.asarray(self.intensity) * np.asarray(self.texture_cone_mean())))

    def check(self, src, path):
        super().check(src, path)
        d = _finite_vec(src, f"{path}.direction", self.direction)
        if not np.linalg.norm(d) > 0:
            _fail(src, f"{path}.direction", "must not be zero")
        _finite(src, f"{path}.cutoff_angle", self.cutoff_angle, lo=0.0, hi=90.0, hi_open=False)
        if self.beam_width is not None:
            _finite(src, f"{path}.beam_width", self.beam_width, lo=0.0, lo_open=False, hi=self.cutoff_angle,
                    hi_open=False)
        if self.texture_axes is not None:
            if len(self.texture_axes) != 2:
                _fail(src, f"{path}.texture_axes", "must be two vectors (the frame's x and y axes)")
            for k, a in enumerate(self.texture_axes):
                _finite_vec(src, f"{path}.texture_axes[{k}]", a)
            if not abs(np.linalg.det(self.frame())) > 1e-12:
                _fail(src, f"{path}.texture_axes", "with the direction, must span space")
        if self.texture is not None and self.cutoff_angle >= 90:
            _fail(src, f"{path}.cutoff_angle", "a textured spot's cutoff must be below 90 degrees")

    def falloff(self, cos_theta):
        """Mitsuba 3's spot falloff at the cosine of the angle from the axis."""
        c = np.asarray(cos_theta, dtype=np.float64)
        cut, beam = math.radians(self.cutoff_angle), math.radians(self.beam)
        inv = 1.0 / (cut - beam) if cut > beam else 0.0
        mid = (cut - np.arccos(np.clip(c, -1.0, 1.0))) * inv
        return np.where(c > math.cos(cut), np.where(c >= math.cos(beam), 1.0, mid), 0.0)

    def solid_angle(self) -> float:
        """The falloff integrated over directions: 2 pi (1 - (sin g - sin b) / (g - b)) for cutoff g, beam b
        (2 pi (1 - cos g) when they are equal)."""
        g, b = math.radians(self.cutoff_angle), math.radians(self.beam)
        if g - b < 1e-9:
            return 2 * math.pi * (1 - math.cos(g))
        return 2 * math.pi * (1 - (math.sin(g) - math.sin(b)) / (g - b))

    def pack(self, b, mat):
        b.delta_light(self, mat)


def _rotation_part(src, path, to_world) -> np.ndarray:
    """The 3x3 linear part of to_world (4x4 or 3x3), normalized to an
    orthogonal matrix: a rotation, possibly with a reflection, times a
    uniform scale (which does not change directions)."""
    try:
        m = np.asarray(to_world, dtype=np.float64)
    except (TypeError, ValueError):
        _fail(src, path, "must be a 3x3 or 4x4 matrix of numbers")
    if m.shape not in ((3, 3), (4, 4)) or not np.isfinite(m).all():
        _fail(src, path, f"must be a finite 3x3 or 4x4 matrix (got shape {m.shape})")
    r = m[:3, :3]
    g = r.T @ r
    s2 = float(np.trace(g)) / 3
    if not s2 > 0 or np.abs(g - s2 * np.eye(3)).max() > 1e-5 * s2:
        _fail(src, path, "must be a rotation (a reflection and a uniform scale allowed): an environment's "
                         "directions cannot be sheared or scaled unevenly")
    return r / math.sqrt(s2)


@dataclass(frozen=True, eq=False)
class EnvironmentLight(_ShapeBase):
    """Light from infinitely far away in every direction: Mitsuba 3's
    ``envmap`` (``image``: an equirectangular H x W x 3 array of linear
    radiance, times ``scale``) or ``constant`` (``image`` None: ``radiance``
    from every direction). ``to_world`` (3x3 or 4x4; its rotation counts)
    turns the map's frame into the world's. Mitsuba's orientation: the map's
    +y is up (row 0 at theta = 0), and pixel (x, y) is seen along
    (sin phi sin theta, cos theta, -cos phi sin theta) with phi = 2 pi (x +
    1/2) / W and theta = pi y / (H - 1), looked up bilinearly between pixels.
    A scene has at most one environment; it is sampled by its luminance times
    sin theta (next event estimation) and seen by rays that leave the scene,
    weighted against each other by multiple importance sampling. It has no
    surface: ``material``, ``emission`` and ``two_sided`` do not apply."""

    image: np.ndarray | None = None
    scale: float = 1.0
    radiance: Vec3 = (1.0, 1.0, 1.0)
    to_world: tuple | None = None
    filename: str | None = None

    bounded = False
    delta = False

    def __post_init__(self):
        if self.image is not None:
            a = np.array(self.image, dtype=np.float32)
            if a.ndim == 2:
                a = a[:, :, None]
            if a.ndim != 3 or a.shape[2] not in (1, 3, 4):
                raise SceneError(f"environment image: must be H x W x 3 (got shape {a.shape})")
            a = np.ascontiguousarray(a[:, :, :3] if a.shape[2] >= 3 else np.repeat(a, 3, axis=2))
            a.setflags(write=False)
            object.__setattr__(self, "image", a)

    def check(self, src, path):
        if self.emission is not None or self.two_sided is not None:
            _fail(src, path, "an environment has a radiance or an image, not emission or two_sided")
        if self.image is None:
            _emission(src, f"{path}.radiance", self.radiance)
        else:
            h, w = self.image.shape[:2]
            if w < 2 or h < 3:
                _fail(src, f"{path}.image", f"the environment map must be at least 2x3 pixels (got {w}x{h})")
            if w * h > MAX_ENV_PIXELS:
                _fail(src, f"{path}.image", f"{w}x{h} pixels is more than the {MAX_ENV_PIXELS} an environment "
                                            "map may have")
            if not np.isfinite(self.image).all() or (self.image < 0).any():
                _fail(src, f"{path}.image", "pixels must be finite and not negative")
            if self.image.max() * abs(self.scale) > MAX_EMISSION:
                _fail(src, f"{path}.image", f"radiance above {MAX_EMISSION:g}: lower scale")
            _finite(src, f"{path}.scale", self.scale, lo=0.0)
        if self.to_world is not None:
            _rotation_part(src, f"{path}.to_world", self.to_world)

    def rotation(self) -> np.ndarray:
        """to_world's rotation (3x3, orthogonal)."""
        return np.eye(3) if self.to_world is None else _rotation_part("", "to_world", self.to_world)

    def area(self):
        return 0.0

    def points(self):
        return np.zeros((0, 3))

    def mean_radiance(self) -> float:
        """The radiance averaged over directions and channels (the map's rows weighted by their solid angle)."""
        if self.image is None:
            return float(np.mean(self.radiance))
        h = self.image.shape[0]
        wt = np.sin(np.pi * np.arange(h) / (h - 1))
        return float(self.scale) * float((self.image.mean(axis=(1, 2)) * wt).sum() / max(wt.sum(), 1e-300))

    def max_radiance(self) -> float:
        return float(max(self.radiance)) if self.image is None else float(self.scale) * float(self.image.max())

    def power(self, radius: float = 1.0) -> float:
        """The power through a sphere of this radius from outside: 4 pi^2 R^2 times the mean radiance."""
        return 4 * math.pi ** 2 * radius ** 2 * self.mean_radiance()

    def light_material(self) -> "Material":
        e = self.radiance if self.image is None else (self.scale,) * 3
        return Material(emission=tuple(float(c) for c in e))

    def pack(self, b, mat):
        b.infinite_light(self, mat)


@dataclass(frozen=True)
class DirectionalLight(_ShapeBase):
    """Light from a direction at infinity (Mitsuba 3's ``directional``):
    ``irradiance`` (W/m^2 per channel) on a surface facing it, arriving along
    ``direction`` (the direction the light travels). A delta light: found by
    next event estimation only (irradiance times cos), never by a BSDF-sampled
    ray, and a source of caustic photons through a disk covering the scene."""

    direction: Vec3 = (0.0, -1.0, 0.0)
    irradiance: Vec3 = (1.0, 1.0, 1.0)

    bounded = False
    delta = True

    def check(self, src, path):
        if self.emission is not None or self.two_sided is not None:
            _fail(src, path, "a directional light has an irradiance, not emission or two_sided")
        d = _finite_vec(src, f"{path}.direction", self.direction)
        if not np.linalg.norm(d) > 0:
            _fail(src, f"{path}.direction", "must not be zero")
        _emission(src, f"{path}.irradiance", self.irradiance)

    def area(self):
        return 0.0

    def points(self):
        return np.zeros((0, 3))

    def power(self, radius: float = 1.0) -> float:
        """The power through the scene's cross-section pi R^2 (per channel, averaged)."""
        return math.pi * radius ** 2 * float(np.mean(self.irradiance))

    def light_material(self) -> "Material":
        return Material(emission=tuple(float(c) for c in self.irradiance))

    def pack(self, b, mat):
        b.infinite_light(self, mat)


# An environment map's pixels: 8k x 4k and a little more (float scenes index records below 2^24, and the
# map's texels follow them; clpt/layout.py ENV_TEXEL).
MAX_ENV_PIXELS = 1 << 26
INFINITE_LIGHTS = (EnvironmentLight, DirectionalLight)
LIGHT_TYPES = (PointLight, SpotLight) + INFINITE_LIGHTS


Shape = Union[Sphere, Triangle, Quad, Plane, Box, Mesh, PointLight, SpotLight, EnvironmentLight, DirectionalLight]
SHAPE_TYPES = {"sphere": Sphere, "triangle": Triangle, "quad": Quad, "plane": Plane, "box": Box, "mesh": Mesh}


@dataclass
class Scene:
    """A camera, named materials, shapes, and default render settings."""

    camera: Camera = field(default_factory=Camera)
    shapes: list = field(default_factory=list)
    materials: dict = field(default_factory=dict)
    render: RenderSettings = field(default_factory=RenderSettings)
    source: str = "<scene>"
    sha256: str | None = None  # of the scene file's text, when read from one

    def resolve_material(self, ref: MaterialRef) -> Material:
        if isinstance(ref, Material):
            return ref
        if ref in self.materials:
            return self.materials[ref]
        if ref in PRESETS:
            return Material.preset(ref)
        raise SceneError(f"unknown material {ref!r}{_suggest(ref, list(self.materials) + list(PRESETS))}")

    def surface(self, shape) -> Material:
        """The shape's material with the shape's emission overrides applied
        (a point or spot light: a material whose emission is its intensity)."""
        if isinstance(shape, LIGHT_TYPES):
            return shape.light_material()
        m = self.resolve_material(shape.material)
        if shape.emission is not None:
            m = replace(m, emission=tuple(float(c) for c in shape.emission))
        if shape.two_sided is not None:
            m = replace(m, two_sided=bool(shape.two_sided))
        return m

    def primitives(self):
        """(index of the shape in self.shapes, primitive) with boxes expanded."""
        for i, s in enumerate(self.shapes):
            for p in s.primitives():
                yield i, p

    def bounds(self, camera: bool = True):
        """Axis-aligned bounds of the finite geometry (and the camera)."""
        pts = [np.array([self.camera.origin], dtype=np.float64)] if camera else []
        pts += [s.points() for s in self.shapes]
        if not pts:
            return np.zeros(3), np.zeros(3)
        pts = np.concatenate(pts)
        return pts.min(axis=0), pts.max(axis=0)

    def extent(self) -> float:
        lo, hi = self.bounds()
        return float(np.linalg.norm(hi - lo)) or 1.0

    def check(self) -> "Scene":
        """Raise SceneError for the first problem found; return self."""
        check_scene(self)
        return self

    def scaled(self, k: float) -> "Scene":
        """The scene with every length (positions, edges, radii, the camera's
        position) times k; directions, angles and radiance unchanged, so the
        image is the same. A power of two k scales exactly."""
        def pts(v):
            return tuple(float(x) * k for x in v)

        shapes = []
        for sh in self.shapes:
            if isinstance(sh, Sphere):
                sh = replace(sh, center=pts(sh.center), radius=float(sh.radius) * k)
            elif isinstance(sh, Triangle):
                sh = replace(sh, vertices=tuple(pts(v) for v in sh.vertices))
            elif isinstance(sh, Quad):
                sh = replace(sh, corner=pts(sh.corner), edge_u=pts(sh.edge_u), edge_v=pts(sh.edge_v))
            elif isinstance(sh, Plane):
                sh = replace(sh, point=pts(sh.point))
            elif isinstance(sh, Box):
                sh = replace(sh, center=pts(sh.center), size=pts(sh.size))
            elif isinstance(sh, Mesh):
                sh = replace(sh, vertices=np.asarray(sh.vertices, dtype=np.float64) * k)
            elif isinstance(sh, INFINITE_LIGHTS):  # directions and radiance: unchanged
                pass
            elif isinstance(sh, LIGHT_TYPES):  # irradiance I / d^2: the intensity scales with the area
                sh = replace(sh, position=pts(sh.position), intensity=tuple(float(c) * k * k for c in sh.intensity))
            else:
                raise SceneError(f"{self.source}: cannot rescale a {type(sh).__name__} shape")
            shapes.append(sh)
        cam = replace(self.camera, origin=pts(self.camera.origin), target=pts(self.camera.target))
        return replace(self, camera=cam, shapes=shapes)


# --- validation of the model ---------------------------------------------------


def _suggest(name, choices) -> str:
    close = difflib.get_close_matches(str(name), [str(c) for c in choices], n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _fail(source, path, reason):
    raise SceneError(f"{source}: {path}: {reason}" if path else f"{source}: {reason}")


# Radiance is carried in float kernels (3.4e38 at most, normal down to
# 1.2e-38): emission must leave room for sums of samples above and for
# reflected light below.
MIN_EMISSION, MAX_EMISSION = 1e-30, 1e30


def _emission(source, path, v):
    a = _finite_vec(source, path, v, nonneg=True)
    if ((a > MAX_EMISSION) | ((a > 0) & (a < MIN_EMISSION))).any():
        _fail(source, path, f"must be 0 or between {MIN_EMISSION:g} and {MAX_EMISSION:g} (got {list(v)}): "
                            "radiance is carried in float; change the scene's units and use exposure instead")
    return a


# What reaches the kernels' float32 buffers: every number must be finite in
# float (FLOAT_MAX), lengths are packed rescaled so the scene's extent is
# near 1 (pack.length_scale) and must then keep their squares in float's range
# (LENGTH_RANGE of the extent, either way), and Phong exponents and indices of
# refraction are bounded where the kernels' formulas stay finite.
FLOAT_MAX = float(np.finfo(np.float32).max)
LENGTH_RANGE = 2.0 ** 60
MAX_SHININESS = 1e30
DISTRIBUTIONS = ("ggx", "beckmann")
ALPHA_RANGE = (1e-4, 10.0)  # float resolves the half vector to ~1e-7 rad: alpha below 1e-4 is a mirror
IOR_RANGE = (1e-6, 1e6)


def _finite_vec(source, path, v, nonneg=False):
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        _fail(source, path, f"must be 3 numbers (got {v!r})")
    if a.shape != (3,) or isinstance(v, str) or any(isinstance(x, (bool, str)) for x in np.ravel(v)):
        _fail(source, path, f"must be 3 numbers (got {v!r})")
    if not np.isfinite(a).all():
        _fail(source, path, f"must be finite (got {list(v)})")
    if (np.abs(a) > FLOAT_MAX).any():
        _fail(source, path, f"must be within float's range, |x| <= {FLOAT_MAX:.4g} (got {list(v)})")
    if nonneg and (a < 0).any():
        _fail(source, path, f"must not be negative (got {list(v)})")
    return a


def _finite(source, path, x, lo=None, lo_open=True, hi=None, hi_open=True):
    if isinstance(x, bool) or not isinstance(x, (int, float, np.floating, np.integer)):
        _fail(source, path, f"must be a number (got {x!r})")
    try:
        x = float(x)
    except OverflowError:
        _fail(source, path, f"must be within float's range, |x| <= {FLOAT_MAX:.4g} (got {x})")
    if not math.isfinite(x):
        _fail(source, path, f"must be finite (got {x})")
    if abs(x) > FLOAT_MAX:
        _fail(source, path, f"must be within float's range, |x| <= {FLOAT_MAX:.4g} (got {x:g})")
    if lo is not None and (x <= lo if lo_open else x < lo):
        _fail(source, path, f"must be {'>' if lo_open else '>='} {lo} (got {x})")
    if hi is not None and (x >= hi if hi_open else x > hi):
        _fail(source, path, f"must be {'<' if hi_open else '<='} {hi} (got {x})")
    return x


# A flat shape must span at least this fraction of its distance from the
# origin: float resolves positions to 6e-8 of their magnitude, and ray offsets
# are 2e-6 of it, so a smaller shape would be a few quantized points.
MIN_FLAT_SIZE = 2.0 ** -16


def _precise(source, path, size, position):
    if size < MIN_FLAT_SIZE * position:
        _fail(source, path, f"is too small for its distance from the origin ({size:.3g} at {position:.3g}): float "
                            f"needs shapes of at least {MIN_FLAT_SIZE:.2g} of that; move the scene near the origin")


# Scenes whose extent lies outside [2^-16, 2^16] are packed rescaled by a power
# of two (exact) that brings the extent near 1: the kernels square lengths
# (distances, areas, radii), and squares of 1e20 or 1e-20 leave float's range.
LENGTH_SCALE_RANGE = 16


def length_scale(extent: float) -> float:
    """The power of two a scene of this extent is packed at (1 for most scenes)."""
    e = math.frexp(extent)[1]
    return 1.0 if abs(e) <= LENGTH_SCALE_RANGE else math.ldexp(1.0, -e)


def _length_in_range(source, path, size, extent):
    """A shape's size (radius, edge) against the scene's extent: both must fit
    float together once the scene is packed at an extent near 1."""
    if size * LENGTH_RANGE < extent:
        _fail(source, path, f"is too small beside the scene's extent ({size:.3g} against {extent:.3g}): float "
                            f"keeps sizes down to {1 / LENGTH_RANGE:.2g} of the extent; remove the shape or "
                            f"split the scene")


def _reflectances(source, path, m: Material, what: str, keys):
    vals = [_finite_vec(source, f"{path}.{k}", getattr(m, k), nonneg=True) for k in keys]
    if max(v.max() for v in vals) > 1:
        _fail(source, path, f"{what} reflectances must be at most 1 ("
                            + ", ".join(f"{k} {tuple(getattr(m, k))}" for k in keys) + ")")


def _interface_eta(source, path, m: Material, key: str, what: str):
    eta = getattr(m, key)
    _finite(source, f"{path}.{key}", eta, lo=1.0 / 1e3, lo_open=False, hi=1e3, hi_open=False)
    if abs(eta - 1.0) < 1e-6:
        _fail(source, f"{path}.{key}", f"must differ from 1 ({what})")


def _distribution(source, path, m: Material):
    if m.distribution not in DISTRIBUTIONS:
        _fail(source, f"{path}.distribution", f"must be one of {', '.join(DISTRIBUTIONS)} "
                                               f"(got {m.distribution!r}){_suggest(m.distribution, DISTRIBUTIONS)}")


def check_material(source, path, m: Material):
    total = np.zeros(3)
    for key in ("kd", "ks", "km", "kr", "kt"):
        total += _finite_vec(source, f"{path}.{key}", getattr(m, key), nonneg=True)
    if max(m.km) > 0:
        _finite(source, f"{path}.alpha", m.alpha, lo=ALPHA_RANGE[0], lo_open=False, hi=ALPHA_RANGE[1],
                hi_open=False)
        _distribution(source, path, m)
        _finite_vec(source, f"{path}.eta", m.eta, nonneg=True)
        _finite_vec(source, f"{path}.k", m.k, nonneg=True)
    if m.alpha_v is not None and m.alpha_v != m.alpha:
        if m.plastic:
            _fail(source, f"{path}.alpha_v", "a plastic's roughness is isotropic (alpha_v must be None)")
        _finite(source, f"{path}.alpha_v", m.alpha_v, lo=ALPHA_RANGE[0], lo_open=False, hi=ALPHA_RANGE[1],
                hi_open=False)
        if m.texture("alpha") is not None:
            _fail(source, f"{path}.alpha_v", "an alpha texture is isotropic (alpha_v must be None)")
    if m.plastic:
        if total.max() > 0:
            _fail(source, path, "a plastic is the material's only lobe (kd, ks, km, kr and kt must be 0)")
        _reflectances(source, path, m, "plastic", ("kp", "kps"))
        if max(m.kp) + max(m.kps) == 0:
            _fail(source, path, "a plastic needs kp or kps above 0")
        if m.alpha != 0:
            _finite(source, f"{path}.alpha", m.alpha, lo=ALPHA_RANGE[0], lo_open=False, hi=ALPHA_RANGE[1],
                    hi_open=False)
        _distribution(source, path, m)
        _interface_eta(source, path, m, "plastic_eta", "a coating of the index around it")
    if m.rough_dielectric_lobe:
        if total.max() > 0 or m.plastic:
            _fail(source, path, "a rough dielectric is the material's only lobe (kd, ks, km, kr and kt must be 0, "
                                "plastic false)")
        _reflectances(source, path, m, "rough dielectric", ("kgr", "kgt"))
        _finite(source, f"{path}.alpha", m.alpha, lo=ALPHA_RANGE[0], lo_open=False, hi=ALPHA_RANGE[1],
                hi_open=False)
        _distribution(source, path, m)
        _interface_eta(source, path, m, "ior", "an interface between media of one index")
        if not isinstance(m.sample_visible, (bool, np.bool_)):
            _fail(source, f"{path}.sample_visible", f"must be True or False (got {m.sample_visible!r})")
    _emission(source, f"{path}.emission", m.emission)
    et = m.texture(EMISSION_SLOT)
    if et is not None and tuple(float(c) for c in m.emission) != et.max():
        _fail(source, f"{path}.emission", f"a textured emitter's emission must be its texture's largest value per "
                                          f"channel, {et.max()} (got {tuple(m.emission)})")
    _finite(source, f"{path}.shininess", m.shininess, lo=0.0, lo_open=False, hi=MAX_SHININESS, hi_open=False)
    _finite(source, f"{path}.ior", m.ior, lo=IOR_RANGE[0], lo_open=False, hi=IOR_RANGE[1], hi_open=False)
    if not isinstance(m.two_sided, (bool, np.bool_)):
        _fail(source, f"{path}.two_sided", f"must be True or False (got {m.two_sided!r})")
    if (total > 1.0 + 1e-6).any():
        c = "rgb"[int(np.argmax(total))]
        _fail(source, path, f"not energy conserving: kd + ks + km + kr + kt = {total.max():.6g} > 1 "
                            f"in the {c} channel (absorption would be negative)")


def _shape_path(i, s):
    return f"shapes[{i}]" + (f" {s.name!r}" if s.name else "")


def check_scene(scene: Scene):
    src = scene.source
    cam = scene.camera
    o = _finite_vec(src, "camera.origin", cam.origin)
    t = _finite_vec(src, "camera.target", cam.target)
    up = _finite_vec(src, "camera.up", cam.up)
    fwd = t - o
    if np.linalg.norm(fwd) == 0.0:
        _fail(src, "camera.target", "must differ from camera.origin")
    if np.linalg.norm(up) == 0.0:
        _fail(src, "camera.up", "must not be zero")
    if np.linalg.norm(np.cross(fwd / np.linalg.norm(fwd), up / np.linalg.norm(up))) < 1e-6:
        _fail(src, "camera.up", "is parallel to the view direction (target - origin); choose another up vector")
    _finite(src, "camera.fov", cam.fov, lo=0.0, hi=180.0)
    if cam.fov_axis not in FOV_AXES:
        _fail(src, "camera.fov_axis", f"must be one of {', '.join(FOV_AXES)} (got {cam.fov_axis!r})")
    for key in ("width", "height"):
        v = getattr(cam, key)
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 1 << 16:
            _fail(src, f"camera.{key}", f"must be an integer from 1 to 65536 (got {v!r})")
    if not isinstance(cam.pixel_filter, PixelFilter):
        _fail(src, "camera.pixel_filter", f"must be a PixelFilter (got {type(cam.pixel_filter).__name__})")
    cam.pixel_filter.check(src, "camera.pixel_filter")

    for name, m in scene.materials.items():
        if not isinstance(m, Material):
            _fail(src, f"materials.{name}", f"must be a Material (got {type(m).__name__})")
        check_material(src, f"materials.{name}", m)

    if not isinstance(scene.shapes, (list, tuple)) or not scene.shapes:
        _fail(src, "shapes", "the scene has no shapes")
    power = 0.0
    envs = 0
    sizes = []  # (key path, length) of every shape's smallest size
    for i, s in enumerate(scene.shapes):
        path = _shape_path(i, s)
        if not isinstance(s, tuple(SHAPE_TYPES.values()) + LIGHT_TYPES):
            _fail(src, path, f"is not a shape (got {type(s).__name__})")
        try:
            m = scene.surface(s)
        except SceneError as e:
            _fail(src, f"{path}.material", str(e))
        if s.emission is not None:
            _emission(src, f"{path}.emission", s.emission)
        if isinstance(s.material, Material):
            check_material(src, f"{path}.material", m)
        s.check(src, path)
        emissive = m.is_emissive
        if s.two_sided is not None and not isinstance(s.two_sided, (bool, np.bool_)):
            _fail(src, f"{path}.two_sided", f"must be True, False or None (got {s.two_sided!r})")
        # Sizes and precision: float must be able to hold each shape at its place.
        if isinstance(s, Sphere):
            sizes.append((f"{path}.radius", float(s.radius)))
        elif isinstance(s, Triangle):
            v = [np.asarray(p, dtype=np.float64) for p in s.vertices]
            size = min(np.linalg.norm(v[1] - v[0]), np.linalg.norm(v[2] - v[0]))
            sizes.append((f"{path}.vertices", size))
            _precise(src, f"{path}.vertices", size, float(np.abs(v).max()))
        elif isinstance(s, Quad):
            c, u, v = (np.asarray(a, dtype=np.float64) for a in (s.corner, s.edge_u, s.edge_v))
            sizes.append((f"{path}.edge_u", float(np.linalg.norm(u))))
            sizes.append((f"{path}.edge_v", float(np.linalg.norm(v))))
            far = float(np.abs(c).max() + np.abs(u).max() + np.abs(v).max())
            _precise(src, f"{path}.edge_u", float(np.linalg.norm(u)), far)
            _precise(src, f"{path}.edge_v", float(np.linalg.norm(v)), far)
        elif isinstance(s, Box):
            center, size = np.asarray(s.center, dtype=np.float64), np.asarray(s.size, dtype=np.float64)
            sizes.append((f"{path}.size", float(size.min())))
            _precise(src, f"{path}.size", float(size.min()), float(np.abs(center).max() + size.max()))
        if emissive and not s.can_emit:
            _fail(src, f"{path}.emission", f"an infinite {type(s).__name__.lower()} cannot be a light; use a quad")
        area = s.area()
        if isinstance(s, EnvironmentLight):
            envs += 1
            if envs > 1:
                _fail(src, path, "a scene has at most one environment (envmap or constant)")
        if isinstance(s, LIGHT_TYPES):
            power += s.power()
        elif emissive:
            power += area * float(np.mean(m.mean_emission))
    extent = scene.extent()
    lo, hi = scene.bounds()
    far = float(max(np.abs(lo).max(), np.abs(hi).max()))
    if not (extent <= FLOAT_MAX and far <= FLOAT_MAX):
        _fail(src, "shapes", f"the scene reaches {max(far, extent):.3g}, beyond float's range ({FLOAT_MAX:.4g})")
    if far * length_scale(extent) > LENGTH_RANGE:
        _fail(src, "shapes", f"the scene lies {far:.3g} from the origin, more than {LENGTH_RANGE:.2g} times its "
                             f"extent ({extent:.3g}): float cannot place it; move it near the origin")
    for path, size in sizes:
        _length_in_range(src, path, size, extent)
    if not math.isfinite(power):
        _fail(src, "shapes", "the lights' total power overflows; lower their emission or size")
    if power <= 0.0:
        _fail(src, "shapes", f"{NO_LIGHT}: give at least one shape (quad, triangle, sphere, "
                             "box or mesh) a positive emission, or add a point, spot, directional or environment light")


def _planar_area(src, path, u, v, what):
    lu, lv = np.linalg.norm(u), np.linalg.norm(v)
    area = float(np.linalg.norm(np.cross(u, v)))
    if lu == 0.0 or lv == 0.0 or area <= 1e-9 * lu * lv:
        _fail(src, path, f"degenerate {what}: its edges are zero or parallel (area {area:.3g})")
    return area


# --- the TOML format --------------------------------------------------------------


class _Reader:
    """Typed access to a parsed TOML table, with key paths in every error."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, path, reason):
        _fail(self.source, path, reason)

    def table(self, d, path, allowed):
        if not isinstance(d, dict):
            self.fail(path, f"must be a table (got {_tname(d)})")
        for k in d:
            if k not in allowed:
                self.fail(f"{path}.{k}" if path else k, f"unknown key{_suggest(k, allowed)}; "
                                                        f"allowed: {', '.join(sorted(allowed))}")
        return d

    def require(self, d, path, key):
        if key not in d:
            self.fail(path or "(top level)", f"missing required key {key!r}")
        return d[key]

    def number(self, v, path):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(path, f"must be a number (got {_tname(v)} {_short(v)})")
        if isinstance(v, int) and abs(v) > FLOAT_MAX:
            self.fail(path, f"must be within float's range, |x| <= {FLOAT_MAX:.4g} (got {_short(v)})")
        if not math.isfinite(v):
            self.fail(path, f"must be finite (got {v})")
        return float(v)

    def integer(self, v, path, lo=None, hi=2 ** 31 - 1):
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(path, f"must be an integer (got {_tname(v)} {_short(v)})")
        if lo is not None and v < lo:
            self.fail(path, f"must be >= {lo} (got {_short(v)})")
        if hi is not None and v > hi:
            self.fail(path, f"must be <= {hi} (got {_short(v)})")
        return v

    def boolean(self, v, path):
        if not isinstance(v, bool):
            self.fail(path, f"must be true or false (got {_tname(v)} {_short(v)})")
        return v

    def string(self, v, path):
        if not isinstance(v, str):
            self.fail(path, f"must be a string (got {_tname(v)} {_short(v)})")
        return v

    def vec3(self, v, path):
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            x = self.number(v, path)  # a grey value
            return (x, x, x)
        if not isinstance(v, list) or len(v) != 3:
            self.fail(path, f"must be a list of 3 numbers (got {_tname(v)} {_short(v)})")
        return tuple(self.number(x, f"{path}[{i}]") for i, x in enumerate(v))


def _short(v, n=60):
    """repr(v), cut to n characters (a 5000-deep array prints in one line)."""
    try:
        t = repr(v)
    except (RecursionError, ValueError):
        t = f"<{_tname(v)}>"
    return t if len(t) <= n else t[:n - 3] + "..."


def _tname(v):
    return {bool: "boolean", int: "integer", float: "float", str: "string", list: "array",
            dict: "table"}.get(type(v), type(v).__name__)


_MATERIAL_KEYS = {"preset", "kd", "ks", "shininess", "kr", "kt", "ior", "emission", "two_sided", "one_sided",
                  "km", "alpha", "alpha_v", "distribution", "eta", "k", "rough_dielectric", "kgr", "kgt",
                  "sample_visible"}
_COMMON_SHAPE_KEYS = {"type", "material", "emission", "two_sided", "name"}
_SHAPE_KEYS = {
    "sphere": {"center", "radius"},
    "triangle": {"vertices"},
    "quad": {"vertices", "corner", "edge_u", "edge_v"},
    "plane": {"point", "normal"},
    "box": {"center", "size", "rotation", "inward"},
    "mesh": {"file", "transform"},
}
_TRANSFORM_KEYS = {"translate", "rotate", "scale", "matrix"}
# Lights without a surface, as [[shapes]] entries: their keys are the Python classes' fields.
_LIGHT_KEYS = {
    "point": {"position", "intensity"},
    "spot": {"position", "direction", "intensity", "cutoff_angle", "beam_width", "texture", "texture_axes"},
    "directional": {"direction", "irradiance"},
    "envmap": {"file", "scale", "transform"},
    "constant": {"radiance"},
}


def _read_light(r: _Reader, d, kind, path, base_dir):
    """A point, spot, directional, envmap or constant light from its table
    (the Python API's parameters; an envmap's image from `file`, relative to
    base_dir, 8-bit formats sRGB-decoded as Mitsuba decodes them, turned by
    `transform`'s rotation)."""
    r.table(d, path, {"type", "name"} | _LIGHT_KEYS[kind])
    kw = {"name": r.string(d["name"], f"{path}.name")} if "name" in d else {}
    for k in ("position", "intensity", "direction", "irradiance", "radiance"):
        if k in d:
            kw[k] = r.vec3(d[k], f"{path}.{k}")
    for k in ("cutoff_angle", "beam_width", "scale"):
        if k in d:
            kw[k] = r.number(d[k], f"{path}.{k}")
    if kind == "spot":
        cut = kw.get("cutoff_angle", SpotLight.cutoff_angle)
        if not 0 < cut <= 90:
            r.fail(f"{path}.cutoff_angle", f"must be in (0, 90] degrees (got {cut:g})")
        beam = kw.get("beam_width", 0.75 * cut)
        if not 0 <= beam <= cut:
            r.fail(f"{path}.beam_width", f"must be in [0, cutoff_angle = {cut:g}] degrees (got {beam:g})")
        if "texture" in d:
            if not isinstance(d["texture"], dict):
                r.fail(f"{path}.texture", f"must be a texture table (got {_short(d['texture'])})")
            kw["texture"] = _read_texture(r, d["texture"], f"{path}.texture", base_dir)
        if "texture_axes" in d:
            a = d["texture_axes"]
            if not isinstance(a, list) or len(a) != 2:
                r.fail(f"{path}.texture_axes", f"must be two vectors (got {_short(a)})")
            kw["texture_axes"] = tuple(r.vec3(v, f"{path}.texture_axes[{k}]") for k, v in enumerate(a))
        return SpotLight(**kw)
    if kind == "point":
        return PointLight(**kw)
    if kind == "directional":
        return DirectionalLight(**kw)
    if kind == "constant":
        return EnvironmentLight(**kw)
    name = r.string(r.require(d, path, "file"), f"{path}.file")
    file = Path(name) if Path(name).is_absolute() or base_dir is None else Path(base_dir) / name
    try:
        img = load_bitmap(file)
    except (ImageError, OSError) as e:
        r.fail(f"{path}.file", str(e))
    if "scale" in kw and not kw["scale"] > 0:
        r.fail(f"{path}.scale", f"must be > 0 (got {kw['scale']:g})")
    if "transform" in d:
        kw["to_world"] = tuple(map(tuple, _read_transform(r, d["transform"], f"{path}.transform").tolist()))
    return EnvironmentLight(image=img, filename=str(file), **kw)


# A TOML material's keys that may be a texture table, and the Material.textures slot each fills.
_TEXTURED_KEYS = {"kd": "reflectance", "km": "specular", "kr": "specular", "kgr": "specular",
                  "kt": "transmittance", "kgt": "transmittance", "alpha": "alpha"}
_TEXTURE_KEYS = {"texture", "filename", "raw", "filter_type", "wrap_mode", "color0", "color1", "to_uv"}


def _read_texture(r: _Reader, d, path, base_dir) -> Texture:
    """A texture table: Mitsuba's bitmap (filename relative to base_dir, raw,
    filter_type, wrap_mode) or checkerboard (color0, color1), both with to_uv
    (2 or 3 rows of 3 numbers, or a 4x4 matrix as Mitsuba's)."""
    r.table(d, path, _TEXTURE_KEYS)
    kind = r.string(r.require(d, path, "texture"), f"{path}.texture")
    if kind not in KINDS:
        r.fail(f"{path}.texture", f"unknown texture {kind!r}{_suggest(kind, KINDS)}; known: {', '.join(KINDS)}")
    own = {"bitmap": {"filename", "raw", "filter_type", "wrap_mode"}, "checkerboard": {"color0", "color1"}}
    for k in set(d) & (own["bitmap"] | own["checkerboard"]) - own[kind]:
        r.fail(f"{path}.{k}", f"not a {kind} key; a {kind} takes {', '.join(sorted(own[kind]))}, to_uv")
    to_uv = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    if "to_uv" in d:
        m = d["to_uv"]
        if not isinstance(m, list) or len(m) not in (2, 3, 4) or \
                not all(isinstance(row, list) and len(row) == (4 if len(m) == 4 else 3) for row in m):
            r.fail(f"{path}.to_uv", f"must be 2 or 3 rows of 3 numbers, or 4 rows of 4 (got {_short(m)})")
        to_uv = [[r.number(x, f"{path}.to_uv[{i}][{j}]") for j, x in enumerate(row)] for i, row in enumerate(m)]
    try:
        if kind == "checkerboard":
            return Texture("checkerboard", color0=r.vec3(d.get("color0", 0.4), f"{path}.color0"),
                           color1=r.vec3(d.get("color1", 0.2), f"{path}.color1"), to_uv=to_uv, name=path)
        choice = {}
        for k, known, default in (("filter_type", FILTERS, "bilinear"), ("wrap_mode", WRAP_MODES, "repeat")):
            choice[k] = r.string(d.get(k, default), f"{path}.{k}")
            if choice[k] not in known:
                r.fail(f"{path}.{k}", f"unknown {k} {choice[k]!r}{_suggest(choice[k], known)}; "
                                      f"known: {', '.join(known)}")
        name = r.string(r.require(d, path, "filename"), f"{path}.filename")
        file = Path(name) if Path(name).is_absolute() or base_dir is None else Path(base_dir) / name
        try:
            data = load_bitmap(file, r.boolean(d.get("raw", False), f"{path}.raw"))
        except (ImageError, OSError) as e:
            r.fail(f"{path}.filename", f"cannot read {file}: {e}")
        return Texture("bitmap", data=data, filter=choice["filter_type"], wrap=choice["wrap_mode"], to_uv=to_uv,
                       name=path)
    except SceneError as e:
        if str(e).startswith(r.source):
            raise
        r.fail(path, str(e).removeprefix(f"{path}: "))


def _read_material(r: _Reader, d, path, base_dir=None) -> Material:
    r.table(d, path, _MATERIAL_KEYS)
    d = dict(d)
    textures = {}
    for k, slot in _TEXTURED_KEYS.items():
        if isinstance(d.get(k), dict):
            if slot in textures:
                r.fail(f"{path}.{k}", f"a second texture for the {slot} slot (one of "
                                      f"{', '.join(x for x, s in _TEXTURED_KEYS.items() if s == slot)})")
            t = textures[slot] = _read_texture(r, d[k], f"{path}.{k}", base_dir)
            if k == "alpha":  # the texture's luminance, as Mitsuba's eval_1; alpha its mean
                d[k] = float(np.dot(t.mean(), LUMA))
            else:
                if max(t.max()) > 1:
                    r.fail(f"{path}.{k}", f"a reflectance or transmittance texture must be at most 1 (its "
                                          f"largest value is {max(t.max()):g})")
                d[k] = list(t.max())
    base = {}
    if "preset" in d:
        name = r.string(d["preset"], f"{path}.preset")
        if name not in PRESETS:
            r.fail(f"{path}.preset", f"unknown preset {name!r}{_suggest(name, PRESETS)}; "
                                     f"presets: {', '.join(PRESETS)}")
        base = dict(PRESETS[name])
    for k in ("kd", "ks", "kr", "kt", "emission", "km", "eta", "k", "kgr", "kgt"):
        if k in d:
            base[k] = r.vec3(d[k], f"{path}.{k}")
    for k in ("shininess", "ior", "alpha", "alpha_v"):
        if k in d:
            base[k] = r.number(d[k], f"{path}.{k}")
    if "distribution" in d:
        base["distribution"] = r.string(d["distribution"], f"{path}.distribution")
    for k in ("two_sided", "one_sided", "sample_visible"):
        if k in d:
            base[k] = r.boolean(d[k], f"{path}.{k}")
    if "rough_dielectric" in d:
        base["rough_dielectric_lobe"] = r.boolean(d["rough_dielectric"], f"{path}.rough_dielectric")
    if textures:
        base["textures"] = tuple(textures.items())
    m = Material(**base)
    check_material(r.source, path, m)
    return m


def _read_transform(r: _Reader, d, path):
    """A transform table: a 4x4 `matrix` (rows), or translate/rotate/scale
    (scale first, then rotate in degrees about x, y, z, then translate)."""
    r.table(d, path, _TRANSFORM_KEYS)
    if "matrix" in d:
        if {"translate", "rotate", "scale"} & set(d):
            r.fail(path, "give either matrix or translate/rotate/scale, not both")
        m = d["matrix"]
        if not isinstance(m, list) or len(m) != 4 or not all(isinstance(row, list) and len(row) == 4 for row in m):
            r.fail(f"{path}.matrix", f"must be 4 rows of 4 numbers (got {_tname(m)} {m!r})")
        return np.array([[r.number(x, f"{path}.matrix[{i}][{j}]") for j, x in enumerate(row)]
                         for i, row in enumerate(m)])
    scale = d.get("scale", 1.0)
    return compose(translate=r.vec3(d.get("translate", [0.0, 0.0, 0.0]), f"{path}.translate"),
                   rotate=r.vec3(d.get("rotate", [0.0, 0.0, 0.0]), f"{path}.rotate"),
                   scale=r.vec3(scale, f"{path}.scale"))


def _read_mesh(r: _Reader, d, path, base_dir, kw):
    name = r.string(r.require(d, path, "file"), f"{path}.file")
    file = Path(name) if Path(name).is_absolute() or base_dir is None else Path(base_dir) / name
    matrix = _read_transform(r, d["transform"], f"{path}.transform") if "transform" in d else None
    try:
        return Mesh.from_file(file, transform=matrix, **kw)
    except MeshError as e:
        r.fail(f"{path}.file", str(e))
    except ValueError as e:
        r.fail(f"{path}.transform", str(e))


def _read_shape(r: _Reader, d, path, materials, base_dir=None):
    if not isinstance(d, dict):
        r.fail(path, f"must be a table (got {_tname(d)})")
    kind = r.string(r.require(d, path, "type"), f"{path}.type")
    if kind not in SHAPE_TYPES and kind not in _LIGHT_KEYS:
        known = list(SHAPE_TYPES) + list(_LIGHT_KEYS)
        r.fail(f"{path}.type", f"unknown shape type {kind!r}{_suggest(kind, known)}; types: {', '.join(known)}")
    if "name" in d:
        path = f"{path} {r.string(d['name'], f'{path}.name')!r}"
    if kind in _LIGHT_KEYS:
        return _read_light(r, d, kind, path, base_dir)
    r.table(d, path, _COMMON_SHAPE_KEYS | _SHAPE_KEYS[kind])
    kw = {}
    if "name" in d:
        kw["name"] = d["name"]
    mat = r.require(d, path, "material")
    if isinstance(mat, dict):
        kw["material"] = _read_material(r, mat, f"{path}.material", base_dir)
    else:
        name = r.string(mat, f"{path}.material")
        if name not in materials and name not in PRESETS:
            r.fail(f"{path}.material", f"unknown material {name!r}"
                                       f"{_suggest(name, list(materials) + list(PRESETS))}; define it "
                                       f"under [materials] or use a preset ({', '.join(PRESETS)})")
        kw["material"] = name
    if "emission" in d:
        kw["emission"] = r.vec3(d["emission"], f"{path}.emission")
    if "two_sided" in d:
        kw["two_sided"] = r.boolean(d["two_sided"], f"{path}.two_sided")

    def vec(key, default=None):
        if key not in d:
            if default is None:
                r.fail(path, f"missing required key {key!r}")
            return default
        return r.vec3(d[key], f"{path}.{key}")

    def points(key, n):
        v = r.require(d, path, key)
        if not isinstance(v, list) or len(v) != n:
            r.fail(f"{path}.{key}", f"must be a list of {n} points (got {_tname(v)} {_short(v)})")
        return tuple(r.vec3(p, f"{path}.{key}[{k}]") for k, p in enumerate(v))

    if kind == "sphere":
        return Sphere(center=vec("center"), radius=r.number(r.require(d, path, "radius"), f"{path}.radius"), **kw)
    if kind == "triangle":
        return Triangle(vertices=points("vertices", 3), **kw)
    if kind == "quad":
        if "vertices" in d:
            if {"corner", "edge_u", "edge_v"} & set(d):
                r.fail(path, "give either vertices or corner/edge_u/edge_v, not both")
            v = [np.array(p) for p in points("vertices", 4)]
            try:
                return Quad.from_vertices(v, **kw)
            except SceneError as e:
                r.fail(f"{path}.vertices", str(e))
        return Quad(corner=vec("corner"), edge_u=vec("edge_u"), edge_v=vec("edge_v"), **kw)
    if kind == "mesh":
        return _read_mesh(r, d, path, base_dir, kw)
    if kind == "plane":
        return Plane(point=vec("point"), normal=vec("normal"), **kw)
    return Box(center=vec("center"), size=vec("size"), rotation=vec("rotation", (0.0, 0.0, 0.0)),
               inward=r.boolean(d.get("inward", False), f"{path}.inward"), **kw)


def parse_scene(text: str, source: str = "<string>", base_dir=None) -> Scene:
    """Build and check a Scene from TOML text; errors name `source`. Mesh
    files are found relative to base_dir (default: the working directory)."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{source}: TOML syntax error: {e}") from None
    except RecursionError:
        raise SceneError(f"{source}: arrays or tables nested too deeply") from None
    r = _Reader(source)
    r.table(doc, "", {"camera", "materials", "shapes", "render"})
    cd = r.table(r.require(doc, "", "camera"), "camera",
                 {"origin", "target", "up", "fov", "fov_axis", "width", "height"})
    cam = Camera(
        origin=r.vec3(r.require(cd, "camera", "origin"), "camera.origin"),
        target=r.vec3(r.require(cd, "camera", "target"), "camera.target"),
        up=r.vec3(cd.get("up", [0.0, 1.0, 0.0]), "camera.up"),
        fov=r.number(r.require(cd, "camera", "fov"), "camera.fov"),
        fov_axis=r.string(cd.get("fov_axis", "smaller"), "camera.fov_axis"),
        width=r.integer(cd.get("width", 256), "camera.width", lo=1, hi=1 << 16),
        height=r.integer(cd.get("height", 256), "camera.height", lo=1, hi=1 << 16),
    )
    rd = r.table(doc.get("render", {}), "render", {"spp", "max_depth", "seed", "rr_depth", "hide_emitters"})
    defaults = RenderSettings()
    settings = RenderSettings(
        spp=r.integer(rd.get("spp", defaults.spp), "render.spp", lo=1, hi=2 ** 32 - 1),
        max_depth=r.integer(rd.get("max_depth", defaults.max_depth), "render.max_depth", lo=0),
        seed=r.integer(rd.get("seed", defaults.seed), "render.seed", lo=0, hi=2 ** 32 - 1),
        rr_depth=r.integer(rd.get("rr_depth", defaults.rr_depth), "render.rr_depth", lo=0),
        hide_emitters=r.boolean(rd.get("hide_emitters", defaults.hide_emitters), "render.hide_emitters"),
    )
    mats = {}
    md = doc.get("materials", {})
    if not isinstance(md, dict):
        r.fail("materials", f"must be a table (got {_tname(md)})")
    for name, m in md.items():
        mats[name] = _read_material(r, m, f"materials.{name}", base_dir)
    sd = r.require(doc, "", "shapes")
    if not isinstance(sd, list):
        r.fail("shapes", f"must be an array of tables ([[shapes]]), got {_tname(sd)}")
    shapes = [_read_shape(r, s, f"shapes[{i}]", mats, base_dir) for i, s in enumerate(sd)]
    scene = Scene(camera=cam, shapes=shapes, materials=mats, render=settings, source=source,
                  sha256=hashlib.sha256(text.encode("utf-8")).hexdigest())
    check_scene(scene)
    return scene


MAX_SCENE_BYTES = 16 << 20


def read_file_bytes(p: Path, name, what: str = "scene file", limit: int = MAX_SCENE_BYTES) -> bytes:
    """The bytes of a file clpt reads whole (a scene, an included scene, a
    spectrum), of at most `limit` bytes (open_regular_file)."""
    with open_regular_file(p, name, what, limit) as f:
        try:
            data = f.read(limit + 1)
        except OSError as e:
            raise SceneError(f"{name}: cannot read the {what}: {e.strerror or e}") from None
    if len(data) > limit:
        raise SceneError(f"{name}: too large for a {what} (at most {limit >> 20} MiB)")
    return data


def _read_scene_text(p: Path, name) -> str:
    """The file's text (read_file_bytes), which must be UTF-8."""
    data = read_file_bytes(p, name)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise SceneError(f"{name}: not UTF-8 text ({e.reason} at byte {e.start})") from None
