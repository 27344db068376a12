"""Mitsuba 3 XML scenes: a documented subset, read into a clpt Scene.

``load_mitsuba("scene.xml", params={"spp": "16"})`` (or ``clpt.load_scene``
on a ``.xml`` file) returns a checked ``Scene``. The subset and how each
Mitsuba plugin maps onto clpt's materials is documented in scenes/README.md
("Mitsuba 3 XML"). Anything outside it is reported, never dropped quietly:
a ``SceneWarning`` (once per kind of problem, naming the file, the line and
the element, with a count of further cases) where clpt renders an
approximation or leaves the element out, and a ``SceneError`` for what
cannot be read at all (bad XML, unknown tags, missing files, bad numbers,
include cycles, undefined ids or parameters), e.g.::

    scenes/box.xml:12: <float name="fov">: bad number 'wide'
"""

from __future__ import annotations

import math
import re
import warnings
import xml.parsers.expat
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .scene import (ALPHA_RANGE, DISTRIBUTIONS, FILTER_MAX_RADIUS, Camera, Material, Mesh, PixelFilter, PointLight, Quad,
                    RenderSettings, Scene, SceneError, SceneWarning, Sphere, SpotLight, _suggest, read_file_bytes)
from .scene import EMISSION_SLOT, NO_LIGHT, DirectionalLight, EnvironmentLight
from .errors import ImageError
from .image import load_image
from .meshio import read_mesh_uv, transform_mesh, vertex_normals
from .constants import LUMA
from .texture import FILTERS, WRAP_MODES, Texture, load_bitmap
from .spectrum import conductor_ior, ior_data as _ior_data, constant_spectrum_to_rgb, parse_spectrum_pairs, spectrum_to_rgb_checked


# Mitsuba counts path segments (1: emitters only); clpt counts scattering events.
# max_depth -1 (unlimited) becomes this many scattering events: a cap that only
# lossless loops (facing perfect mirrors) ever reach.
UNLIMITED_DEPTH = 1024

# Mitsuba 0.6's global-illumination integrators that Mitsuba 3 dropped. Their
# maxDepth and rrDepth mean what path's do (path segments), so a 0.6 scene set up
# for one of them (17 of the 78 real scenes in shared/REAL_SCENES.md use sppm)
# keeps its depth; clpt renders it with its own path tracer and photon merging.
LEGACY_INTEGRATORS = ("sppm", "ppm", "photonmapper", "bdpt", "pssmlt", "mlt", "erpt", "volpath_simple")

# Mitsuba 3's reconstruction filters with negative lobes: importance sampling
# cannot draw them, so they are rendered with the box (with a warning).
NEGATIVE_LOBED_FILTERS = ("mitchell", "catmullrom", "lanczos")

# Segments of the triangle fan a disk becomes (its radius is scaled so that the
# fan keeps the disk's area, and so a light's power).
DISK_SEGMENTS = 96

# Mitsuba's sun and sky emitters (3: sunsky; 0.6: sky, sun and sunsky), which clpt does not implement.
SKY_EMITTERS = ("sunsky", "sky", "sun")
OBJECT_TAGS = ("scene", "shape", "bsdf", "emitter", "sensor", "film", "sampler", "integrator", "texture",
               "rfilter", "medium", "phase", "volume")
PROPERTY_TAGS = ("float", "integer", "boolean", "string", "rgb", "spectrum", "point", "vector", "transform", "ref")
TRANSFORM_TAGS = ("translate", "rotate", "scale", "matrix", "lookat")
OTHER_TAGS = ("default", "include", "alias", "path")
KNOWN_TAGS = set(OBJECT_TAGS + PROPERTY_TAGS + TRANSFORM_TAGS + OTHER_TAGS)
_XYZ = ("value", "x", "y", "z")
ATTRIBUTES = {**{t: ("type", "id", "name") for t in OBJECT_TAGS}, "scene": ("version", "type", "id"),
              **{t: ("name", "value") for t in ("float", "integer", "boolean", "string", "rgb")},
              "spectrum": ("name", "value", "filename"), "point": ("name", *_XYZ), "vector": ("name", *_XYZ),
              "transform": ("name",), "ref": ("id", "name"), "translate": _XYZ, "scale": _XYZ,
              "rotate": (*_XYZ, "angle"), "matrix": ("value",), "lookat": ("origin", "target", "up"),
              "default": ("name", "value"), "include": ("filename",), "alias": ("id", "as"), "path": ("value",)}

_PARAM = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


# --- XML with line numbers -----------------------------------------------------------


@dataclass
class _Node:
    tag: str
    attrs: dict
    file: str
    line: int
    children: list = field(default_factory=list)
    via: str = ""  # where the file was included from (itself with its own via), if it was

    def where(self) -> str:
        return f"{self.file}:{self.line}"

    def label(self) -> str:
        keys = [k for k in ("type", "name", "id") if k in self.attrs]
        return "<" + " ".join([self.tag] + [f'{k}="{self.attrs[k]}"' for k in keys]) + ">"

    def fail(self, reason):
        raise SceneError(f"{self.where()}: {self.label()}: {reason}")


# Elements nested deeper than this are refused: the loader walks the tree
# recursively, and real scenes nest a handful of levels.
MAX_DEPTH = 64


def _read_xml(path: Path, shown: str, via: str = "") -> _Node:
    """The file's element tree. Every problem is a one-line SceneError with the
    line: bad XML, an encoding the XML declaration names but Python lacks,
    elements nested deeper than MAX_DEPTH, and DTD entity declarations (no
    Mitsuba scene has them, and entities that expand to entities blow up)."""
    data = read_file_bytes(path, shown)
    p = xml.parsers.expat.ParserCreate()
    stack: list[_Node] = []
    root: list[_Node] = []

    def start(tag, attrs):
        if len(stack) >= MAX_DEPTH:
            raise SceneError(f"{shown}:{p.CurrentLineNumber}: <{tag}>: elements are nested more than "
                             f"{MAX_DEPTH} deep")
        n = _Node(tag, dict(attrs), shown, p.CurrentLineNumber, via=via)
        (stack[-1].children if stack else root).append(n)
        stack.append(n)

    def end(tag):
        stack.pop()

    def entity(name, *args):
        raise SceneError(f"{shown}:{p.CurrentLineNumber}: entity declarations (<!ENTITY {name} ...>) are not "
                         "supported")

    p.StartElementHandler = start
    p.EndElementHandler = end
    p.EntityDeclHandler = entity
    try:
        p.Parse(data, True)
    except SceneError:
        raise
    except xml.parsers.expat.ExpatError as e:
        raise SceneError(f"{shown}:{e.lineno}: XML syntax error: {xml.parsers.expat.ErrorString(e.code)} "
                         f"(column {e.offset + 1})") from None
    except (LookupError, UnicodeError, ValueError) as e:  # an encoding="..." Python cannot decode
        raise SceneError(f"{shown}:{p.CurrentLineNumber}: cannot decode the file: {e}") from None
    return root[0]


# --- numbers -------------------------------------------------------------------------------


def _numbers(node: _Node, text: str, what: str = "value") -> list[float]:
    out = []
    for tok in re.split(r"[,\s]+", text.strip()):
        if not tok:
            continue
        try:
            x = float(tok)
        except ValueError:
            node.fail(f"bad number {tok!r} in {what}")
        if not math.isfinite(x):
            node.fail(f"{what} must be finite (got {tok})")
        out.append(x)
    return out


def _number(node: _Node, text: str, what: str = "value") -> float:
    """Exactly one number."""
    v = _numbers(node, text, what)
    if len(v) != 1:
        node.fail(f"{what} must be one number (got {len(v)})")
    return v[0]


def _attr(node: _Node, key: str) -> str:
    if key not in node.attrs:
        node.fail(f"missing attribute '{key}'")
    return node.attrs[key]


def _vec3(node: _Node, default=None, *, attrs=("x", "y", "z")) -> np.ndarray:
    """value="x, y, z" (or one number for all three) or x/y/z attributes."""
    if "value" in node.attrs:
        v = _numbers(node, node.attrs["value"])
        if len(v) == 1:
            v = v * 3
        if len(v) != 3:
            node.fail(f"value must be 1 or 3 numbers (got {len(v)})")
        return np.array(v)
    if not any(a in node.attrs for a in attrs):
        if default is None:
            node.fail("needs value=\"x, y, z\" or x, y, z attributes")
        return np.array(default, dtype=np.float64)
    d = default if default is not None else (0.0, 0.0, 0.0)
    return np.array([_number(node, node.attrs[a], a) if a in node.attrs else d[i]
                     for i, a in enumerate(attrs)])


# --- transforms --------------------------------------------------------------------------


def rotation_matrix(axis, angle_deg) -> np.ndarray:
    """4x4 rotation by angle_deg degrees about axis (right-handed)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    t = math.radians(angle_deg)
    c, s = math.cos(t), math.sin(t)
    x, y, z = a
    m = np.eye(4)
    m[:3, :3] = [[c + x * x * (1 - c), x * y * (1 - c) - z * s, x * z * (1 - c) + y * s],
                 [y * x * (1 - c) + z * s, c + y * y * (1 - c), y * z * (1 - c) - x * s],
                 [z * x * (1 - c) - y * s, z * y * (1 - c) + x * s, c + z * z * (1 - c)]]
    return m


def look_at_matrix(origin, target, up) -> np.ndarray:
    """Mitsuba's look_at: columns left, up, forward, origin (camera looks along +z)."""
    o, t, u = (np.asarray(v, dtype=np.float64) for v in (origin, target, up))
    d = t - o
    if np.linalg.norm(d) == 0:
        raise ValueError("origin and target coincide")
    d /= np.linalg.norm(d)
    left = np.cross(u, d)
    if np.linalg.norm(left) < 1e-9:
        raise ValueError("up is parallel to the view direction")
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, o
    return m


def _transform(node: _Node) -> np.ndarray:
    """A <transform>: its operations in document order, each applied after the ones before."""
    m = np.eye(4)
    for op in node.children:
        if op.tag == "translate":
            t = np.eye(4)
            t[:3, 3] = _vec3(op, (0.0, 0.0, 0.0))
        elif op.tag == "scale":
            t = np.diag([*_vec3(op, (1.0, 1.0, 1.0)), 1.0])
        elif op.tag == "rotate":
            axis = _vec3(op, (0.0, 0.0, 0.0))
            if np.linalg.norm(axis) == 0:
                op.fail("needs an axis: value=\"x, y, z\" or x, y, z attributes")
            t = rotation_matrix(axis, _number(op, _attr(op, "angle"), "angle"))
        elif op.tag == "matrix":
            v = _numbers(op, _attr(op, "value"))
            if len(v) == 16:
                t = np.array(v).reshape(4, 4)
            elif len(v) == 9:
                t = np.eye(4)
                t[:3, :3] = np.array(v).reshape(3, 3)
            else:
                op.fail(f"value must be 16 (or 9) numbers, row by row (got {len(v)})")
        elif op.tag == "lookat":
            vecs = {}
            for k, default in (("origin", None), ("target", None), ("up", "0, 1, 0")):
                vals = _numbers(op, op.attrs.get(k, default) if default else _attr(op, k), k)
                if len(vals) != 3:
                    op.fail(f"{k} must be 3 numbers (got {len(vals)})")
                vecs[k] = vals
            try:
                t = look_at_matrix(vecs["origin"], vecs["target"], vecs["up"])
            except ValueError as e:
                op.fail(str(e))
        else:
            op.fail(f"is not a transform operation (expected one of {', '.join(TRANSFORM_TAGS)})")
        m = t @ m
    return m


def _cube_face_uv(axis: int, side: float, c, u, v) -> tuple:
    """(u, v) at corner c of a face of Mitsuba's cube and their changes along
    its edges u and v (local coordinates): Mitsuba maps each face onto
    [0, 1]^2, its four vertices (in its table's order) at (0, 1), (1, 1),
    (1, 0), (0, 0); as an affine map, uv(x) = ((x - p3).e_u, (x - p3).e_v) / 4
    with p3 the (0, 0) vertex, e_u = p2 - p3, e_v = p0 - p3."""
    p3, e_u, e_v = _CUBE_FACES[(axis, side)]
    f = lambda x: (float(np.dot(x - p3, e_u)) / 4, float(np.dot(x - p3, e_v)) / 4)  # noqa: E731
    c = np.asarray(c, dtype=np.float64)
    a, b, o = f(c + u), f(c + v), f(c)
    return (o, (a[0] - o[0], a[1] - o[1]), (b[0] - o[0], b[1] - o[1]))


def _cube_faces():
    """{(axis, side): (p3, p2 - p3, p0 - p3)} of Mitsuba 3's cube (src/shapes/cube.cpp): per face
    its vertices at uv (0, 1), (1, 1), (1, 0), (0, 0), in that order."""
    quads = (((1, -1, -1), (1, -1, 1), (-1, -1, 1), (-1, -1, -1)), ((1, 1, -1), (-1, 1, -1), (-1, 1, 1), (1, 1, 1)),
             ((1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1)), ((1, -1, 1), (1, 1, 1), (-1, 1, 1), (-1, -1, 1)),
             ((-1, -1, 1), (-1, 1, 1), (-1, 1, -1), (-1, -1, -1)), ((1, 1, -1), (1, -1, -1), (-1, -1, -1), (-1, 1, -1)))
    out = {}
    for q in quads:
        p0, _, p2, p3 = (np.array(x, dtype=np.float64) for x in q)
        axis = int(np.flatnonzero((p0 == p2) & (p2 == p3))[0])
        out[(axis, float(p0[axis]))] = (p3, p2 - p3, p0 - p3)
    return out


_CUBE_FACES = _cube_faces()

# The textures clpt evaluates (clpt/texture.py); others are replaced by a constant.
TEXTURE_KINDS = ("bitmap", "checkerboard")


def _slots(**textures) -> tuple:
    """Material.textures from slot=Texture-or-None keywords."""
    return tuple((k, t) for k, t in textures.items() if t is not None)


def coordinate_system(n) -> tuple:
    """The two tangents of the orthonormal basis Mitsuba 3 builds about unit n
    (coordinate_system, after Duff et al. 2017): its frames' x and y axes."""
    x, y, z = (float(c) for c in n)
    sign = 1.0 if z >= 0 else -1.0
    a = -1.0 / (sign + z)
    b = x * y * a
    return (np.array([1.0 + sign * x * x * a, sign * b, -sign * x]), np.array([b, sign + y * y * a, -y]))


def _floats3(v) -> tuple:
    return tuple(float(c) for c in v)


def _apply(m: np.ndarray, p) -> np.ndarray:
    return m[:3, :3] @ np.asarray(p, dtype=np.float64) + m[:3, 3]


# --- the loader ----------------------------------------------------------------------------


def fresnel_dielectric(cos_i: float, eta: float) -> float:
    """Unpolarized Fresnel reflectance for light arriving at cos_i from the side
    where the relative index (transmitted over incident) is eta."""
    cos_i = min(max(cos_i, 0.0), 1.0)
    sin_t2 = (1 - cos_i * cos_i) / (eta * eta)
    if sin_t2 >= 1:
        return 1.0
    cos_t = math.sqrt(1 - sin_t2)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp)


def _hemispherical(f, n: int = 2048) -> float:
    """2 int_0^1 f(mu) mu dmu (the cosine-weighted average over the hemisphere), midpoint rule."""
    mu = (np.arange(n) + 0.5) / n
    return float(2.0 * np.mean(np.array([f(m) for m in mu]) * mu))


def fresnel_diffuse_reflectance(eta: float) -> float:
    """The cosine-weighted hemispherical average of the Fresnel reflectance
    (Mitsuba's fdr) seen from the side with relative index eta."""
    return _hemispherical(lambda mu: fresnel_dielectric(mu, eta))


def fresnel_conductor(cos_i, eta: float, k: float):
    """Unpolarized Fresnel reflectance of a conductor of complex index eta + i k."""
    n = complex(eta, k)
    cos_i = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    cos_t = np.sqrt(1 - (1 - cos_i ** 2) / n ** 2 + 0j)
    rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def conductor_albedo(eta, k) -> tuple:
    """A conductor's Fresnel reflectance averaged over the cosine-weighted
    hemisphere, per channel: the energy it reflects of diffuse light."""
    mu = (np.arange(2048) + 0.5) / 2048
    return tuple(float(2.0 * np.mean(fresnel_conductor(mu, e, kk) * mu))
                 for e, kk in zip(np.broadcast_to(eta, 3), np.broadcast_to(k, 3)))


def plastic_approximation(m: Material) -> Material:
    """A plastic as diffuse + Phong (rough) or diffuse + mirror (smooth)
    lobes of the energy Mitsuba's reflects, for mixing with the paper's
    lobes (blendbsdf); other materials as they are."""
    if not m.plastic:
        return m
    eta = m.plastic_eta
    kd, spec = np.array(m.kp), np.array(m.kps)
    fdr_ext = fresnel_diffuse_reflectance(eta)
    fdr_int = fresnel_diffuse_reflectance(1.0 / eta)
    if m.nonlinear:
        kd_eff = kd / (1 - kd * fdr_int) * (1 - fdr_ext) ** 2 / (eta * eta)
    else:
        kd_eff = kd * (1 - fdr_ext) ** 2 / ((1 - fdr_int) * eta * eta)
    ks = spec * fdr_ext
    kd_eff = np.minimum(kd_eff, 1.0 - ks)
    if m.alpha == 0:
        return Material(kd=tuple(kd_eff), kr=tuple(ks), one_sided=m.one_sided)
    return Material(kd=tuple(kd_eff), ks=tuple(ks), shininess=phong_exponent(m.alpha), one_sided=m.one_sided)


def phong_exponent(alpha: float) -> float:
    """The modified-Phong exponent (lobe about the mirror direction) nearest a
    Beckmann/GGX lobe of roughness alpha: near its peak the microfacet lobe is
    exp(-theta_h^2 / alpha^2) in the half-vector angle, and theta_h is half the
    angle from the mirror direction, so cos^n matches for n = 1/(2 alpha^2)
    (Blinn's exponent 2/alpha^2 - 2, divided by 4, the half-angle change)."""
    return max(0.5 / (alpha * alpha) - 0.5, 0.0)


@dataclass
class _Props:
    """An object node's properties by name, tracking which ones were used."""

    node: _Node
    loader: "_Loader"
    props: dict = field(default_factory=dict)     # name -> property node
    objects: list = field(default_factory=list)   # (name or None, object node) of nested objects and refs
    used: set = field(default_factory=set)

    @property
    def type(self):
        return self.node.attrs.get("type", "")

    def has(self, name):
        return name in self.props

    def _get(self, name, tags):
        n = self.props.get(name)
        if n is None:
            return None
        self.used.add(name)
        if n.tag not in tags:
            n.fail(f"'{name}' must be {' or '.join(tags)} (got <{n.tag}>)")
        return n

    def float(self, name, default=None, lo=None):
        n = self._get(name, ("float", "integer"))
        if n is None:
            return default
        v = _numbers(n, _attr(n, "value"))
        if len(v) != 1:
            n.fail("value must be one number")
        if lo is not None and v[0] < lo:
            n.fail(f"must be >= {lo} (got {v[0]:g})")
        return v[0]

    def integer(self, name, default=None):
        n = self._get(name, ("integer",))
        if n is None:
            return default
        text = _attr(n, "value")  # a SceneError is a ValueError: not inside the try
        try:
            return int(text.strip())
        except ValueError:
            n.fail(f"bad integer {text!r}")

    def boolean(self, name, default=False):
        n = self._get(name, ("boolean",))
        if n is None:
            return default
        v = _attr(n, "value").strip().lower()
        if v not in ("true", "false", "1", "0"):
            n.fail(f"must be true or false (got {n.attrs['value']!r})")
        return v in ("true", "1")

    def string(self, name, default=None):
        n = self._get(name, ("string",))
        return default if n is None else _attr(n, "value")

    def point(self, name, default):
        n = self._get(name, ("point", "vector"))
        return np.array(default, dtype=np.float64) if n is None else _vec3(n)

    def transform(self, name="to_world"):
        n = self._get(name, ("transform",))
        return np.eye(4) if n is None else _transform(n)

    def ior(self, name, default: str):
        """A float, or a named material ("bk7", "water", ...)."""
        n = self.props.get(name)
        if n is None:
            return _ior_data()["ior"][default]
        self.used.add(name)
        if n.tag == "float":
            return self.float(name)
        if n.tag != "string":
            n.fail(f"'{name}' must be a float or the name of a material")
        key = _attr(n, "value").strip().lower()
        table = _ior_data()["ior"]
        if key not in table:
            n.fail(f"unknown index of refraction {key!r}{_suggest(key, table)}; known: {', '.join(table)}")
        return table[key]

    def color(self, name, default=None, *, emitter=False, bounded=True):
        """rgb, spectrum, float, or a texture (its mean, with a warning) -> RGB tuple."""
        n = self.props.get(name)
        obj = None
        if n is None:
            for nm, o in self.objects:
                if nm == name:
                    obj = o
            if obj is None:
                if default is None:
                    self.node.fail(f"missing property '{name}'")
                return tuple(float(c) for c in np.broadcast_to(np.asarray(default, dtype=np.float64), 3))
            self.used.add(name)
            return self.loader.texture_color(self.loader.deref(obj), self, name, emitter)
        self.used.add(name)
        if n.tag == "rgb":
            v = _numbers(n, _attr(n, "value"))
            if len(v) == 1:
                v = v * 3
            if len(v) != 3:
                n.fail(f"value must be 3 numbers (got {len(v)})")
            rgb = tuple(v)
        elif n.tag in ("float", "integer"):
            x = _numbers(n, _attr(n, "value"))
            if len(x) != 1:
                n.fail("value must be one number")
            rgb = (x[0],) * 3
        elif n.tag == "spectrum":
            rgb = self.loader.spectrum(n, emitter, bounded)
        else:
            n.fail(f"'{name}' must be rgb, spectrum, float or a texture (got <{n.tag}>)")
        if min(rgb) < 0:
            n.fail(f"must not be negative (got {list(rgb)})")
        if bounded and not emitter and max(rgb) > 1:
            n.fail(f"a reflectance must be at most 1 (got {list(rgb)})")
        return tuple(float(c) for c in rgb)

    def texture(self, name):
        """The Texture given as property `name` (nested or by reference) when
        it is a bitmap or checkerboard, else None."""
        obj = None
        if name not in self.props:
            obj = next((o for nm, o in self.objects if nm == name), None)
        elif self.props[name].tag == "ref":
            obj = self.props[name]
        tex = self.loader.deref(obj) if obj is not None else None
        if tex is None or tex.tag != "texture" or tex.attrs.get("type") not in TEXTURE_KINDS:
            return None
        self.used.add(name)
        return self.loader.texture(tex)

    def textured(self, name, default):
        """A reflectance that may be a texture: (its RGB, None), or, for a
        bitmap or checkerboard, (the texture's largest value per channel,
        the clpt.texture.Texture)."""
        t = self.texture(name)
        if t is None:
            return self.color(name, default), None
        if max(t.max()) > 1:
            raise SceneError(f"{t.name}: a reflectance texture must be at most 1 (its largest value is "
                             f"{max(t.max()):g})")
        return t.max(), t

    def nested(self, tag):
        """The nested objects (or refs resolving to them) of the given tag."""
        out = []
        for nm, o in self.objects:
            d = self.loader.deref(o)
            if d.tag == tag:
                out.append(d)
                self.used.add(("obj", id(o)))
        return out

    def finish(self, quiet=()):
        """Warn about properties and nested objects that were given but not used."""
        for name, n in self.props.items():
            if name not in self.used and name not in quiet:
                self.loader.warn(n, f"property '{name}' of {self.node.tag} '{self.type}' is not supported; ignored",
                                 key=("prop", self.node.tag, self.type, name))
        for nm, o in self.objects:
            if ("obj", id(o)) not in self.used and nm not in self.used:
                d = self.loader.deref(o)
                self.loader.warn(o, f"{d.tag} inside {self.node.tag} '{self.type}' is not supported; ignored",
                                 key=("obj", self.node.tag, d.tag))


class _Loader:
    def __init__(self, path: Path, shown: str, params: dict | None, strict: bool):
        self.root_path = path
        self.params = {str(k): str(v) for k, v in (params or {}).items()}
        self.given = set(self.params)
        self.used_params: set = set()
        self.declared: set = set()  # names with a <default>
        self.strict = strict
        self.ids: dict = {}
        self.materials: dict = {}  # id(bsdf node) -> Material, each BSDF mapped once
        self.warned: dict = {}
        self.left_out_emitters: list = []  # nodes of the top-level emitters left out (unsupported kinds)
        self.search_dirs = [path.parent]
        self.shown = shown

    # --- reporting -----------------------------------------------------------------------

    def warn(self, node: _Node, msg: str, key=None):
        key = key or msg
        if key in self.warned:
            self.warned[key][1] += 1
            return
        text = f"{node.where()}: {node.label()}: {msg}"
        if self.strict:
            raise SceneError(text + " (strict mode)")
        self.warned[key] = [text, 0]

    def emit_warnings(self):
        for text, more in self.warned.values():
            warnings.warn(text + (f" (and {more} more like it)" if more else ""), SceneWarning, stacklevel=4)

    # --- files, includes and parameters -------------------------------------------------------

    def resolve(self, node: _Node, filename: str) -> Path:
        """A file named in the scene: relative to the file that names it, then to
        the main file's folder and the <path> folders."""
        p = Path(filename)
        cands = [p] if p.is_absolute() else [Path(node.file).parent / p] + [d / p for d in self.search_dirs]
        for c in cands:
            if c.is_file():
                return c
        node.fail(f"file not found: {filename!r} (looked in {', '.join(sorted({str(c.parent) for c in cands}))})")

    def substitute(self, node: _Node):
        for k, v in node.attrs.items():
            if "$" in v:
                def rep(m):
                    name = m.group(1)
                    if name not in self.params:
                        node.fail(f"undefined parameter ${name} in {k}=\"{v}\"{_suggest(name, self.params)}: "
                                  f"declare it with <default name=\"{name}\" value=\"...\"/> or pass it "
                                  f"(-D {name}=VALUE)")
                    self.used_params.add(name)
                    return self.params[name]
                node.attrs[k] = _PARAM.sub(rep, v)

    def expand(self, node: _Node, stack: tuple, legacy: bool = False) -> list:
        """The node's children with parameters substituted and includes inlined,
        recursively, in document order (defaults take effect where they stand).
        legacy: the children come from a Mitsuba 0.x file, so they are
        upgraded to Mitsuba 3's names as they are read (_upgrade_node)."""
        out = []
        for c in node.children:
            self.substitute(c)
            if legacy:
                _upgrade_node(c)
            if c.tag not in KNOWN_TAGS:
                c.fail(f"unknown tag{_suggest(c.tag, KNOWN_TAGS)}")
            for a in c.attrs:
                if a not in ATTRIBUTES[c.tag]:
                    c.fail(f"unknown attribute '{a}'{_suggest(a, ATTRIBUTES[c.tag])}; "
                           f"<{c.tag}> takes {', '.join(ATTRIBUTES[c.tag])}")
            if c.tag == "default":
                name = _attr(c, "name")
                if "value" not in c.attrs:
                    c.fail("missing attribute 'value'")
                if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
                    c.fail(f"bad parameter name {name!r}")
                self.params.setdefault(name, c.attrs["value"])
                self.declared.add(name)
                continue
            if c.tag == "include":
                p = self.resolve(c, _attr(c, "filename"))
                key = p.resolve()
                if key in stack:
                    chain = " -> ".join(str(s) for s in (*stack, key))
                    c.fail(f"include cycle: {chain}")
                shown = str(p)
                sub = _read_xml(p, shown, via=c.where())
                if sub.tag != "scene":
                    sub.fail("an included file must have <scene> as its root")
                self.substitute(sub)
                # Each file is upgraded by its own version (as Mitsuba does); one without a
                # version is read as its includer.
                sub_legacy = legacy if "version" not in sub.attrs else _major_version(sub) < 2
                out += self.expand(sub, (*stack, key), sub_legacy)
                continue
            if c.tag == "path":
                d = Path(_attr(c, "value"))
                self.search_dirs.append(d if d.is_absolute() else Path(c.file).parent / d)
                continue
            c.children = self.expand(c, stack, legacy)
            if legacy:
                _upgrade_object(c)
            out.append(c)
        return out

    def register(self, nodes):
        for n in nodes:
            if n.tag == "alias":
                continue
            if n.tag in OBJECT_TAGS and "id" in n.attrs:
                i = n.attrs["id"]
                if i in self.ids:
                    first = self.ids[i]
                    if first.where() == n.where() and n.via:  # one file, included twice
                        raise SceneError(f"{n.via}: <include>: {n.file} is included a second time (first at "
                                         f"{first.via}), so its id {i!r} is defined twice")
                    n.fail(f"duplicate id {i!r} (first defined at {first.where()})")
                self.ids[i] = n
            self.register(n.children)
        for n in nodes:
            if n.tag == "alias":
                src, dst = _attr(n, "id"), _attr(n, "as")
                if src not in self.ids:
                    n.fail(f"alias of an undefined id {src!r}{_suggest(src, self.ids)}")
                self.ids[dst] = self.ids[src]

    def deref(self, node: _Node) -> _Node:
        seen = set()
        while node.tag == "ref":
            i = _attr(node, "id")
            if i not in self.ids:
                node.fail(f"reference to an undefined id {i!r}{_suggest(i, self.ids)}")
            if i in seen:
                node.fail(f"reference cycle through id {i!r}")
            seen.add(i)
            node = self.ids[i]
        return node

    def props(self, node: _Node) -> _Props:
        p = _Props(node, self)
        for c in node.children:
            if c.tag in PROPERTY_TAGS and c.tag != "ref":
                name = _attr(c, "name")
                if name in p.props:
                    c.fail(f"property '{name}' is given twice (also at line {p.props[name].line})")
                p.props[name] = c
            elif c.tag in OBJECT_TAGS or c.tag == "ref":
                p.objects.append((c.attrs.get("name"), c))
            elif c.tag in TRANSFORM_TAGS:
                c.fail("a transform operation must be inside <transform>")
            else:
                c.fail(f"is not allowed inside <{node.tag}>")
        return p

    # --- colours --------------------------------------------------------------------------

    def spectrum(self, n: _Node, emitter: bool, bounded: bool = True):
        if "filename" in n.attrs:
            path = self.resolve(n, n.attrs["filename"])
            wl, vals = [], []
            try:
                text = read_file_bytes(path, path, "spectrum file").decode("utf-8")
            except UnicodeDecodeError as e:
                n.fail(f"{path}: not UTF-8 text ({e.reason} at byte {e.start})")
            for i, line in enumerate(text.splitlines()):
                line = line.split("#", 1)[0].strip()
                if not line:
                    continue
                parts = line.split()
                try:
                    a, b = float(parts[0]), float(parts[1])
                except (ValueError, IndexError):
                    raise SceneError(f"{path}:{i + 1}: expected 'wavelength value' (got {line!r})") from None
                wl.append(a)
                vals.append(b)
        else:
            text = _attr(n, "value")
            if ":" not in text:
                v = _numbers(n, text)
                if len(v) != 1:
                    n.fail("value must be one number or wavelength:value pairs")
                return constant_spectrum_to_rgb(v[0], emitter=emitter)
            try:
                wl, vals = parse_spectrum_pairs(text)
            except ValueError as e:
                n.fail(str(e))
        try:
            rgb, clamped = spectrum_to_rgb_checked(wl, vals, emitter=emitter, bounded=bounded and not emitter)
        except ValueError as e:
            n.fail(str(e))
        if clamped:
            self.warn(n, "spectrum out of the sRGB gamut: clamped, as Mitsuba does", key=("gamut",))
        return rgb

    def texture_color(self, tex: _Node, owner: _Props, name: str, emitter: bool):
        if tex.tag != "texture":
            tex.fail(f"'{name}' must be a colour or a texture (got <{tex.tag}>)")
        tp = self.props(tex)
        if tp.type == "checkerboard":
            c0 = np.array(tp.color("color0", 0.4, emitter=emitter))
            c1 = np.array(tp.color("color1", 0.2, emitter=emitter))
            tp.transform("to_uv")
            tp.finish()
            self.warn(tex, f"a texture as '{name}' is not supported: the checkerboard's mean colour is used",
                      key=("texture", "checkerboard", name))
            return tuple(float(c) for c in 0.5 * (c0 + c1))
        if tp.type == "bitmap":
            rgb = self._bitmap_mean(tex, tp)
            tp.finish(quiet=("filter_type", "wrap_mode", "raw", "to_uv", "format"))
            self.warn(tex, f"a texture as '{name}' is not supported: the bitmap's mean colour is used",
                      key=("texture", "bitmap", name))
            return rgb
        self.warn(tex, f"texture '{tp.type}' is not supported: a grey of 0.5 is used", key=("texture", tp.type))
        return (0.5, 0.5, 0.5)

    def texture(self, tex: _Node) -> Texture:
        """The Texture of a bitmap or checkerboard node (one object per node:
        a texture referenced twice is stored once)."""
        key = ("texture", id(tex))
        if key in self.materials:
            return self.materials[key]
        tp = self.props(tex)
        name = f"{tex.where()}: {tex.label()}"
        to_uv = tp.transform("to_uv")
        try:
            if tp.type == "checkerboard":
                t = Texture("checkerboard", color0=tp.color("color0", 0.4), color1=tp.color("color1", 0.2),
                            to_uv=to_uv, name=name)
            else:
                filt = self._choice(tp, "filter_type", FILTERS, "bilinear")
                wrap = self._choice(tp, "wrap_mode", WRAP_MODES, "repeat")
                path = self.resolve(tex, tp.string("filename") or tex.fail("missing property 'filename'"))
                raw = tp.boolean("raw", False)
                try:
                    data = load_bitmap(path, raw)
                except (ImageError, OSError) as e:
                    tex.fail(f"cannot read {path}: {e}")
                t = Texture("bitmap", data=data, filter=filt, wrap=wrap, to_uv=to_uv, name=name)
        except SceneError as e:
            if str(e).startswith(name):
                raise
            tex.fail(str(e))
        tp.finish(quiet=("format",))
        self.materials[key] = t
        return t

    @staticmethod
    def _choice(tp: _Props, prop: str, known: tuple, default: str) -> str:
        v = tp.string(prop, default)
        if v not in known:
            tp.props[prop].fail(f"unknown {prop} {v!r}{_suggest(v, known)}; known: {', '.join(known)}")
        return v

    def _bitmap_mean(self, tex: _Node, tp: _Props):
        path = self.resolve(tex, tp.string("filename") or tex.fail("missing property 'filename'"))
        try:
            img = load_bitmap(path, tp.boolean("raw", False)).astype(np.float64)
        except (ImageError, OSError) as e:
            tex.fail(f"cannot read {path}: {e}")
        return tuple(float(c) for c in np.clip(img.reshape(-1, 3).mean(axis=0), 0.0, 1.0))

    # --- BSDFs ---------------------------------------------------------------------------------

    def bsdf(self, node: _Node) -> Material:
        node = self.deref(node)
        if node.tag != "bsdf":
            node.fail("expected a <bsdf>")
        key = id(node)
        if key not in self.materials:
            m = self._bsdf(node)
            self.materials[key] = replace(m, **{k: _floats3(getattr(m, k)) for k in ("kd", "ks", "kr", "kt")})
        return self.materials[key]

    def _bsdf(self, node: _Node) -> Material:
        p = self.props(node)
        t = p.type
        if t == "twosided":
            inner = p.nested("bsdf")
            if not inner:
                node.fail("needs a nested <bsdf>")
            if len(inner) > 1:
                self.warn(node, "different front and back BSDFs are not supported: the first is used on both "
                                "sides", key=("twosided2",))
            m = replace(self.bsdf(inner[0]), one_sided=False)
        elif t == "diffuse":
            kd, tex = p.textured("reflectance", 0.5)
            m = Material(kd=kd, one_sided=True, textures=_slots(reflectance=tex))
        elif t == "conductor":
            # A mirror of the conductor's hemispherical albedo (a texture scaled by it).
            spec, spec_tex = p.textured("specular_reflectance", 1.0)
            albedo = self._conductor_albedo(p)
            m = Material(kr=tuple(np.array(spec) * albedo), one_sided=True,
                         textures=_slots(specular=spec_tex.scaled(albedo) if spec_tex else None))
        elif t == "roughconductor":
            # The microfacet lobe itself (kernels/microfacet.h), Fresnel from eta + i k per channel.
            spec, spec_tex = p.textured("specular_reflectance", 1.0)
            eta, k = self._conductor_ior(p)
            dist = self._distribution(p)
            p.boolean("sample_visible", True)  # either way the same expectation; clpt samples visible normals
            alpha_tex = p.texture("alpha")  # the texture's luminance, as Mitsuba's eval_1
            au, av = (float(np.dot(alpha_tex.mean(), LUMA)),) * 2 if alpha_tex else self._alphas(p)
            m = Material(km=tuple(spec), alpha=float(np.clip(au, *ALPHA_RANGE)),
                         alpha_v=None if av == au else float(np.clip(av, *ALPHA_RANGE)), distribution=dist,
                         eta=eta, k=k, one_sided=True, textures=_slots(specular=spec_tex, alpha=alpha_tex))
        elif t in ("dielectric", "roughdielectric", "thindielectric"):
            eta = p.ior("int_ior", "bk7") / p.ior("ext_ior", "air")
            refl, refl_tex = p.textured("specular_reflectance", 1.0)
            trans, trans_tex = p.textured("specular_transmittance", 1.0)
            refl, trans = np.array(refl), np.array(trans)
            if t == "thindielectric":
                # Reflection summed over the slab's internal bounces, R' = 2R/(1+R), averaged over
                # the hemisphere; the rest passes straight through (ior 1: no bending, no Fresnel).
                r = _hemispherical(lambda mu: 2 * fresnel_dielectric(mu, eta) / (1 + fresnel_dielectric(mu, eta)))
                m = Material(kr=tuple(refl * r), kt=tuple(trans * (1 - r)), ior=1.0,
                             textures=_slots(specular=refl_tex.scaled(r) if refl_tex else None,
                                             transmittance=trans_tex.scaled(1 - r) if trans_tex else None))
            elif t == "roughdielectric":
                # The microfacet interface itself (kernels/bsdf.h rough_dielectric_*).
                if abs(eta - 1.0) < 1e-6:
                    node.fail(f"int_ior and ext_ior must differ (got eta {eta:g})")
                au, av = (min(a, ALPHA_RANGE[1]) for a in self._alphas(p))
                m = Material(rough_dielectric_lobe=True, kgr=tuple(refl), kgt=tuple(trans), ior=eta,
                             alpha=au, alpha_v=None if av == au else av, distribution=self._distribution(p),
                             sample_visible=p.boolean("sample_visible", True),
                             textures=_slots(specular=refl_tex, transmittance=trans_tex))
            else:
                if np.abs(refl - trans).max() > 1e-6 or refl_tex is not None:
                    self.warn(node, "specular_reflectance differs from specular_transmittance: clpt's "
                                    "dielectric has one colour for both; specular_transmittance is used",
                              key=("dielectric_colors",))
                m = Material(kt=tuple(trans), ior=eta, textures=_slots(transmittance=trans_tex))
        elif t in ("plastic", "roughplastic"):
            # The coated diffuse lobe itself (kernels/bsdf.h plastic_*, clpt/coating.py).
            eta = p.ior("int_ior", "polypropylene") / p.ior("ext_ior", "air")
            kd, kd_tex = p.textured("diffuse_reflectance", 0.5)
            spec = p.color("specular_reflectance", 1.0)
            nonlinear = p.boolean("nonlinear", False)
            if abs(eta - 1.0) < 1e-6:
                node.fail(f"int_ior and ext_ior must differ (got eta {eta:g})")
            alpha, dist = 0.0, "beckmann"
            if t == "roughplastic":
                dist = self._distribution(p)
                alpha = min(self._alpha(p), ALPHA_RANGE[1])
                p.boolean("sample_visible", True)  # the same expectation either way; clpt samples visible normals
            if max(kd) + max(spec) == 0:
                m = Material(one_sided=True)  # black
            else:
                m = Material(plastic=True, kp=tuple(kd), kps=tuple(spec), alpha=alpha, distribution=dist,
                             plastic_eta=eta, nonlinear=nonlinear, one_sided=True, textures=_slots(reflectance=kd_tex))
        elif t in ("bumpmap", "normalmap", "mask"):
            inner = p.nested("bsdf")
            if not inner:
                node.fail("needs a nested <bsdf>")
            self.warn(node, f"'{t}' is not supported: the nested BSDF is used as it is", key=("wrapper", t))
            p.used.update(p.props)
            p.used.update(("obj", id(o)) for _, o in p.objects)
            m = self.bsdf(inner[0])
        elif t == "blendbsdf":
            inner = p.nested("bsdf")
            if len(inner) != 2:
                node.fail(f"needs two nested BSDFs (got {len(inner)})")
            w = p.float("weight", 0.5)
            if not 0 <= w <= 1:
                node.fail(f"weight must be in [0, 1] (got {w})")
            a, b = self.bsdf(inner[0]), self.bsdf(inner[1])
            if a.plastic or b.plastic:
                self.warn(node, "blending a plastic: its diffuse + Phong approximation is blended",
                          key=("blend_plastic",))
                a, b = plastic_approximation(a), plastic_approximation(b)
            if a.rough_dielectric_lobe or b.rough_dielectric_lobe:
                self.warn(node, "blending a rough dielectric: a smooth one of its transmittance is blended",
                          key=("blend_roughdielectric",))
                a, b = (replace(x, rough_dielectric_lobe=False, kt=x.kgt) if x.rough_dielectric_lobe else x
                        for x in (a, b))
            if (a.shininess and b.shininess and a.shininess != b.shininess) or (
                    max(a.kt) > 0 and max(b.kt) > 0 and a.ior != b.ior):
                self.warn(node, "blending lobes of different shininess or ior: the weighted mean is used",
                          key=("blend",))
            mix = lambda x, y: tuple((1 - w) * np.asarray(x) + w * np.asarray(y))  # noqa: E731
            m = Material(kd=mix(a.kd, b.kd), ks=mix(a.ks, b.ks), kr=mix(a.kr, b.kr), kt=mix(a.kt, b.kt),
                         shininess=(1 - w) * a.shininess + w * b.shininess if a.shininess and b.shininess
                         else a.shininess or b.shininess, ior=a.ior if max(a.kt) > 0 else b.ior,
                         one_sided=a.one_sided and b.one_sided)
        else:
            self.warn(node, f"BSDF '{t}' is not supported: a one-sided grey diffuse (0.5) is used",
                      key=("bsdf", t))
            p.used.update(p.props)
            p.used.update(("obj", id(o)) for _, o in p.objects)
            m = Material(kd=(0.5, 0.5, 0.5), one_sided=True)
        p.finish()
        return m

    def _distribution(self, p: _Props) -> str:
        dist = p.string("distribution", "beckmann")  # Mitsuba 3's default
        if dist not in DISTRIBUTIONS:
            p.props["distribution"].fail(f"unknown distribution {dist!r}{_suggest(dist, DISTRIBUTIONS)}; "
                                         f"known: {', '.join(DISTRIBUTIONS)}")
        return dist

    def _alphas(self, p: _Props) -> tuple:
        """(alpha_u, alpha_v) of a microfacet BSDF: both given, or alpha for both (as Mitsuba 3)."""
        if p.has("alpha_u") or p.has("alpha_v"):
            if not (p.has("alpha_u") and p.has("alpha_v")):
                p.node.fail("alpha_u and alpha_v must be given together")
            if p.has("alpha"):
                p.node.fail("alpha and alpha_u/alpha_v must not be given together")
            au, av = p.float("alpha_u", 0.1, lo=0.0), p.float("alpha_v", 0.1, lo=0.0)
            return max(au, 1e-4), max(av, 1e-4)
        a = max(p.float("alpha", 0.1, lo=0.0), 1e-4)
        return a, a

    def _alpha(self, p: _Props) -> float:
        """A roughplastic's alpha (isotropic in Mitsuba: an anisotropic pair is averaged, with a warning)."""
        # Mitsuba 3 reads roughplastic's alpha as a plain float and refuses a
        # texture ("The property "alpha" has the wrong type (expected float,
        # got object)"): so does clpt, rather than render another roughness.
        given = p.props.get("alpha")
        if (given is not None and given.tag == "ref") or any(nm == "alpha" for nm, _ in p.objects):
            p.node.fail("'alpha' must be a float: roughplastic's roughness cannot be a texture (Mitsuba 3 refuses "
                        "it too)")
        if p.has("alpha_u") or p.has("alpha_v"):
            au, av = p.float("alpha_u", 0.1, lo=0.0), p.float("alpha_v", 0.1, lo=0.0)
            if au != av:
                self.warn(p.node, "roughplastic's roughness is isotropic: the mean of alpha_u and alpha_v is "
                                  "used", key=("aniso",))
            a = 0.5 * (au + av)
        else:
            a = p.float("alpha", 0.1, lo=0.0)
        return max(a, 1e-4)

    def _conductor_ior(self, p: _Props) -> tuple:
        """(eta, k) RGB of a conductor: `eta`/`k` given, else the named `material`."""
        if p.has("eta") or p.has("k"):
            eta = tuple(p.color("eta", 0.0, bounded=False))
            k = tuple(p.color("k", 1.0, bounded=False))
            p.string("material")
            if min(eta) < 0 or min(k) < 0:
                p.node.fail(f"eta and k must not be negative (got eta {eta}, k {k})")
            return eta, k
        name = p.string("material", "none")
        try:
            return conductor_ior(name)
        except SceneError as e:
            p.props["material"].fail(str(e))

    def _conductor_albedo(self, p: _Props) -> np.ndarray:
        if p.has("eta") or p.has("k"):
            eta = np.array(p.color("eta", 0.0, bounded=False))
            k = np.array(p.color("k", 1.0, bounded=False))
            p.string("material")
            return np.array(conductor_albedo(eta, k))
        name = p.string("material", "none")
        if name == "none":
            return np.ones(3)
        table = _ior_data()["conductor"]
        if name not in table:
            p.props["material"].fail(f"unknown conductor {name!r}{_suggest(name, table)}; known: none, "
                                     f"{', '.join(table)}")
        return np.array(conductor_albedo(table[name]["eta"], table[name]["k"]))

    # --- shapes ----------------------------------------------------------------------------

    def shape(self, node: _Node, out: list, to_world=None):
        p = self.props(node)
        t = p.type
        m = p.transform("to_world")
        if to_world is not None:
            m = to_world @ m
        bsdfs = p.nested("bsdf")
        if len(bsdfs) > 1:
            node.fail("has more than one BSDF")
        mat = self.bsdf(bsdfs[0]) if bsdfs else Material(kd=(0.5, 0.5, 0.5), one_sided=True)
        emission = radiance_tex = None
        for e in p.nested("emitter"):
            ep = self.props(e)
            if ep.type != "area":
                self.warn(e, f"emitter '{ep.type}' on a shape is not supported; ignored", key=("emitter", ep.type))
                continue
            # A bitmap or checkerboard radiance varies over the shape by its (u, v) (EMISSION_SLOT;
            # a checkerboard's colours are reflectances in Mitsuba 3 too: at most 1).
            radiance_tex = ep.texture("radiance")
            emission = radiance_tex.max() if radiance_tex is not None else ep.color("radiance", emitter=True)
            ep.finish()
        if emission is not None and not bsdfs:
            mat = Material(one_sided=True)  # Mitsuba 3 gives an emitter without a BSDF a black diffuse one
        if radiance_tex is not None:
            mat = replace(mat, textures=mat.bsdf_textures + ((EMISSION_SLOT, radiance_tex),))
        flip = p.boolean("flip_normals", False)
        name = node.attrs.get("id") or f"{t} at {node.where()}"
        kw = dict(material=mat, emission=emission, two_sided=False, name=name)
        for obj_tag in ("medium", "sensor"):
            for _ in p.nested(obj_tag):
                self.warn(node, f"a {obj_tag} inside a shape is not supported; ignored", key=("shape", obj_tag))
        if t == "rectangle":
            # Mitsuba's (u, v) = ((x + 1) / 2, (y + 1) / 2) of the local point.
            out.append(self._parallelogram(m, (-1, -1, 0), (2, 0, 0), (0, 2, 0), flip, kw,
                                           uv=((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))))
        elif t == "cube":
            for axis in range(3):
                a1, a2 = (axis + 1) % 3, (axis + 2) % 3
                for side in (-1.0, 1.0):
                    c, u, v = np.zeros(3), np.zeros(3), np.zeros(3)
                    c[axis], c[a1], c[a2] = side, -1.0, -1.0
                    u[a1], v[a2] = 2.0, 2.0
                    if side < 0:
                        u, v = v, u
                    out.append(self._parallelogram(m, c, u, v, flip, kw, uv=_cube_face_uv(axis, side, c, u, v)))
        elif t == "sphere":
            center = _apply(m, p.point("center", (0.0, 0.0, 0.0)))
            r = p.float("radius", 1.0, lo=0.0)
            sv = np.linalg.svd(m[:3, :3], compute_uv=False)
            if sv.max() - sv.min() > 1e-6 * sv.max():
                self.warn(node, "a sphere's to_world must scale uniformly (ellipsoids are not supported): "
                                "the mean scale is used", key=("ellipsoid",))
            if flip:
                self.warn(node, "flip_normals on a sphere is not supported: it is made two-sided (reflecting "
                                "and emitting on both sides)", key=("flip_sphere",))
                kw = dict(kw, material=replace(mat, one_sided=False), two_sided=True)
            # Mitsuba's (u, v) come from the direction in the sphere's own frame: to_world's rotation undone.
            frame = np.linalg.inv(m[:3, :3]) * float(np.mean(sv))
            out.append(Sphere(center=_floats3(center), radius=r * float(np.mean(sv)),
                              uv_frame=tuple(tuple(float(x) for x in row) for row in frame), **kw))
        elif t == "disk":
            # A fan of k triangles, each with vertices of its own so that it carries Mitsuba's
            # (u, v) = (r, phi / 2 pi) (exact at its vertices; its centre's phi its middle one's).
            k = DISK_SEGMENTS
            ang = 2 * math.pi * np.arange(k + 1) / k
            scale = math.sqrt(2 * math.pi / (k * math.sin(2 * math.pi / k)))  # fan area = disk area
            ring = np.stack([np.cos(ang) * scale, np.sin(ang) * scale, np.zeros(k + 1)], axis=1)
            i = np.arange(k)
            verts = np.stack([np.zeros((k, 3)), ring[i], ring[i + 1]], axis=1).reshape(-1, 3)
            uvs = np.stack([np.stack([np.zeros(k), (i + 0.5) / k], axis=1), np.stack([np.full(k, scale), i / k], axis=1),
                            np.stack([np.full(k, scale), (i + 1) / k], axis=1)], axis=1).reshape(-1, 2)
            out.append(self._mesh(node, verts, np.arange(3 * k).reshape(k, 3), None, m, flip, dict(kw, uvs=uvs)))
        elif t == "cylinder":
            p0, p1 = p.point("p0", (0.0, 0.0, 0.0)), p.point("p1", (0.0, 0.0, 1.0))
            r = p.float("radius", 1.0, lo=0.0)
            axis = p1 - p0
            if np.linalg.norm(axis) == 0 or r == 0:
                node.fail("a cylinder needs p0 != p1 and radius > 0")
            # A prism of k quads, each with vertices of its own carrying Mitsuba's (u, v) = (phi / 2 pi,
            # z / length), phi about the axis in Mitsuba's frame of it (coordinate_system).
            k = DISK_SEGMENTS
            ang = 2 * math.pi * np.arange(k + 1) / k
            scale = (math.pi / k) / math.sin(math.pi / k)  # the prism's side area = the cylinder's
            w = axis / np.linalg.norm(axis)
            a, b = coordinate_system(w)
            radial = np.outer(np.cos(ang), a) + np.outer(np.sin(ang), b)
            i = np.arange(k)
            verts = np.stack([p0 + r * scale * radial[i], p0 + r * scale * radial[i + 1],
                              p1 + r * scale * radial[i + 1], p1 + r * scale * radial[i]], axis=1).reshape(-1, 3)
            normals = np.stack([radial[i], radial[i + 1], radial[i + 1], radial[i]], axis=1).reshape(-1, 3)
            uvs = np.stack([np.stack([i / k, np.zeros(k)], axis=1), np.stack([(i + 1) / k, np.zeros(k)], axis=1),
                            np.stack([(i + 1) / k, np.ones(k)], axis=1), np.stack([i / k, np.ones(k)], axis=1)],
                           axis=1).reshape(-1, 2)
            q = 4 * i
            tris = np.vstack([np.stack([q, q + 1, q + 2], axis=1), np.stack([q, q + 2, q + 3], axis=1)])
            out.append(self._mesh(node, verts, tris, normals, m, flip, dict(kw, uvs=uvs)))
        elif t in ("obj", "ply", "serialized"):
            path = self.resolve(node, p.string("filename") or node.fail("missing property 'filename'"))
            index = p.integer("shape_index", 0) if t == "serialized" else 0
            if index < 0:
                p.props["shape_index"].fail(f"must be >= 0 (got {index})")
            try:
                verts, tris, normals, uvs = read_mesh_uv(path, shape_index=index)
            except (SceneError, ValueError, OSError) as e:
                node.fail(str(e))
            face_normals = p.boolean("face_normals", False)
            if t == "obj" and uvs is not None and p.boolean("flip_tex_coords", True):
                uvs = np.stack([uvs[:, 0], 1.0 - uvs[:, 1]], axis=1)  # Mitsuba's default for OBJ files
            kw = dict(kw, uvs=uvs)
            if t in ("obj", "ply") and p.has("max_smooth_angle"):  # Mitsuba 0.6's crease angle (maxSmoothAngle)
                p.float("max_smooth_angle")
                self.warn(node, "max_smooth_angle (Mitsuba 0.6) is not supported: normals are computed as "
                                "Mitsuba 3 does, smooth across every edge", key=("max_smooth_angle",))
            out.append(self._file_mesh(node, verts, tris, None if face_normals else normals, not face_normals,
                                       m, flip, kw))
        else:
            self.warn(node, f"shape '{t}' is not supported; left out", key=("shape", t))
            return
        p.finish()

    def _parallelogram(self, m, c, u, v, flip, kw, uv):
        c, u, v = (np.asarray(a, dtype=np.float64) for a in (c, u, v))
        corner = _apply(m, c)
        eu, ev = m[:3, :3] @ u, m[:3, :3] @ v
        # The normal transforms by the inverse transpose; the edges' cross product by the
        # cofactor, which differs by det(m): a mirroring transform keeps Mitsuba's normal.
        if (np.linalg.det(m[:3, :3]) < 0) != flip:
            eu, ev = ev, eu
            uv = (uv[0], uv[2], uv[1])
        return Quad(corner=_floats3(corner), edge_u=_floats3(eu), edge_v=_floats3(ev), uv=uv, **kw)

    def _file_mesh(self, node, verts, tris, normals, smooth, m, flip, kw):
        """A mesh read from a file, as Mitsuba 3 makes it. With the file's own
        normals: as _mesh. Without: the triangles face by their winding in
        world space (Mitsuba reverses nothing for a mirroring to_world), and
        unless `smooth` is off (face_normals), Mitsuba's smooth vertex normals
        are computed from the world-space positions (meshio.vertex_normals),
        so that a coarse mesh is shaded as Mitsuba shades it, not faceted."""
        if normals is not None:
            return self._mesh(node, verts, tris, normals, m, flip, kw)

        try:
            verts, _ = transform_mesh(np.asarray(verts, dtype=np.float64), None, m)
        except ValueError as e:  # a singular or non-finite to_world
            node.fail(f"to_world: {e}")
        tris = np.asarray(tris)
        normals = vertex_normals(verts, tris) if smooth else None
        if flip:
            tris = tris[:, ::-1]
            normals = None if normals is None else -normals
        return Mesh(vertices=verts, triangles=tris, normals=normals, **kw)

    def _mesh(self, node, verts, tris, normals, m, flip, kw):
        try:
            verts, normals = transform_mesh(np.asarray(verts, dtype=np.float64),
                                            None if normals is None else np.asarray(normals, dtype=np.float64), m)
        except ValueError as e:  # a singular or non-finite to_world
            node.fail(f"to_world: {e}")
        tris = np.asarray(tris)
        if (np.linalg.det(m[:3, :3]) < 0) != flip:
            tris = tris[:, ::-1]
        if flip and normals is not None:
            normals = -normals
        return Mesh(vertices=verts, triangles=tris, normals=normals, **kw)

    # --- sensor, integrator ------------------------------------------------------------------

    def sensor(self, node: _Node, settings: dict):
        p = self.props(node)
        if p.type not in ("perspective", "thinlens"):
            node.fail(f"sensor '{p.type}' is not supported (only perspective)")
        if p.type == "thinlens":
            self.warn(node, "thinlens: depth of field is not supported; rendered as a pinhole camera",
                      key=("thinlens",))
            p.float("aperture_radius")
            p.float("focus_distance")
        m = p.transform("to_world")
        origin = m[:3, 3]
        fwd, up, left = m[:3, 2], m[:3, 1], m[:3, 0]
        if np.linalg.norm(fwd) == 0 or np.linalg.norm(up) == 0:
            node.fail("to_world is singular")
        if np.linalg.det(m[:3, :3]) < 0:
            self.warn(node, "a mirroring camera transform is not supported: the image is not mirrored",
                      key=("mirror_cam",))
        sv = np.linalg.svd(m[:3, :3], compute_uv=False)
        if sv.max() - sv.min() > 1e-6 * sv.max() or abs(np.dot(fwd, up)) > 1e-6 * np.linalg.norm(fwd) * np.linalg.norm(up):
            self.warn(node, "scale or shear in the camera transform is not supported; only its position and "
                            "orientation are used", key=("cam_scale",))
        films = p.nested("film")
        width, height = 768, 576
        pixel_filter = PixelFilter("gaussian")  # Mitsuba's default film has its default filter
        for f in films:
            fp = self.props(f)
            if fp.type not in ("hdrfilm", "specfilm"):
                self.warn(f, f"film '{fp.type}' is read as an hdrfilm", key=("film", fp.type))
            width, height = fp.integer("width", 768), fp.integer("height", 576)
            for k in ("width", "height"):
                v = width if k == "width" else height
                if not 1 <= v <= 1 << 16:
                    fp.props[k].fail(f"must be from 1 to 65536 (got {v})")
            if any(fp.has(k) for k in ("crop_offset_x", "crop_offset_y", "crop_width", "crop_height")):
                self.warn(f, "crop windows are not supported: the whole image is rendered", key=("crop",))
                fp.used.update(("crop_offset_x", "crop_offset_y", "crop_width", "crop_height"))
            pixel_filter = PixelFilter("gaussian")  # Mitsuba's default
            for rf in fp.nested("rfilter"):
                pixel_filter = self.rfilter(rf)
            pixel_filter = replace(pixel_filter, sample_border=fp.boolean("sample_border", False))
            # Output settings, which do not change the radiance clpt renders (and for Mitsuba
            # 0.6's ldrfilm, its tone mapping, which the film warning above covers).
            fp.finish(quiet=("pixel_format", "component_format", "file_format", "banner", "high_quality_edges",
                             "compensate", "srgb_primaries", "attach_log")
                      + (("tonemap_method", "gamma", "exposure", "key", "burn") if fp.type == "ldrfilm" else ()))
        for s in p.nested("sampler"):
            sp = self.props(s)
            spp = sp.integer("sample_count", 4)
            if spp < 1:
                sp.props["sample_count"].fail(f"must be >= 1 (got {spp})")
            settings["spp"] = spp
            seed = sp.integer("seed", 0)
            if seed < 0:
                sp.props["seed"].fail(f"must be >= 0 (got {seed})")
            settings["seed"] = seed
            sp.finish(quiet=("jitter", "scramble_seed", "strategy"))  # sample patterns: clpt has its own
        fov_axis = p.string("fov_axis", "x")
        if fov_axis not in ("x", "y", "diagonal", "smaller", "larger"):
            p.props["fov_axis"].fail(f"must be x, y, diagonal, smaller or larger (got {fov_axis!r})")
        if p.has("fov"):
            fov = p.float("fov")
            if not 0 < fov < 180:
                p.props["fov"].fail(f"must be between 0 and 180 degrees (got {fov})")
            p.string("focal_length")
        else:
            fl = p.string("focal_length", "50mm").strip()
            try:
                f_mm = float(fl[:-2] if fl.endswith("mm") else fl)
            except ValueError:
                p.props["focal_length"].fail(f"bad focal length {fl!r} (e.g. \"50mm\")")
            if f_mm <= 0:
                p.props["focal_length"].fail(f"must be > 0 (got {fl})")
            fov = math.degrees(2 * math.atan(math.hypot(36, 24) / (2 * f_mm)))
            fov_axis = "diagonal"
        if fov_axis == "diagonal":
            # The x fov of the same image diagonal, for this film's shape.
            half_diag = math.tan(math.radians(fov) / 2)
            fov = math.degrees(2 * math.atan(half_diag * width / math.hypot(width, height)))
            fov_axis = "x"
        for k in ("principal_point_offset_x", "principal_point_offset_y"):
            if p.float(k, 0.0) != 0.0:
                self.warn(node, "principal point offsets are not supported", key=("ppo",))
        p.finish(quiet=("near_clip", "far_clip", "focus_distance", "shutter_open", "shutter_close", "srf"))
        return Camera(origin=_floats3(origin), target=_floats3(origin + fwd / np.linalg.norm(fwd)),
                      up=_floats3(up / np.linalg.norm(up)), fov=fov, fov_axis=fov_axis, width=width, height=height,
                      pixel_filter=pixel_filter)

    def rfilter(self, node: _Node) -> PixelFilter:
        """An <rfilter>: Mitsuba 3's box, tent (radius) and gaussian (stddev);
        the filters with negative lobes are rendered with the box."""
        p = self.props(node)
        if p.type == "box":
            pf = PixelFilter("box")
        elif p.type == "tent":
            radius = p.float("radius", 1.0)
            if not 1e-3 <= radius <= FILTER_MAX_RADIUS:
                p.props["radius"].fail(f"must be from 0.001 to {FILTER_MAX_RADIUS:g} pixels (got {radius:g})")
            pf = PixelFilter("tent", radius=radius)
        elif p.type == "gaussian":
            stddev = p.float("stddev", 0.5)
            if not 1e-3 <= stddev <= FILTER_MAX_RADIUS / 4:
                p.props["stddev"].fail(f"must be from 0.001 to {FILTER_MAX_RADIUS / 4:g} pixels (got {stddev:g})")
            pf = PixelFilter("gaussian", stddev=stddev)
        elif p.type in NEGATIVE_LOBED_FILTERS:
            self.warn(node, f"reconstruction filter '{p.type}' has negative lobes, which clpt does not sample: "
                            "rendered with a box filter (box, tent and gaussian are supported)", key=("rfilter",))
            p.used.update(p.props)
            pf = PixelFilter("box")
        else:
            node.fail(f"unknown reconstruction filter '{p.type}' (Mitsuba 3 has box, tent, gaussian, mitchell, "
                      "catmullrom, lanczos)")
        p.finish()
        return pf

    def integrator(self, node: _Node, settings: dict):
        p = self.props(node)
        t = p.type
        if t in ("path", "volpath", "volpathmis", "ptracer") + LEGACY_INTEGRATORS:
            if t in LEGACY_INTEGRATORS:
                self.warn(node, f"integrator '{t}' (Mitsuba 0.6) is rendered by clpt's path tracer and its photon "
                                "merging: max_depth and rr_depth are used, its other settings are not",
                          key=("integrator", t))
                p.used.update(k for k in p.props if k not in ("max_depth", "rr_depth", "hide_emitters"))
            elif t != "path":
                self.warn(node, f"integrator '{t}' is rendered by clpt's path tracer", key=("integrator", t))
            depth = p.integer("max_depth", -1)
            if depth < -1:
                p.props["max_depth"].fail(f"must be -1 (unlimited) or >= 0 (got {depth})")
            if depth == 0:
                p.props["max_depth"].fail("max_depth 0 renders nothing (clpt's depths start at Mitsuba's 1)")
            settings["max_depth"] = UNLIMITED_DEPTH if depth == -1 else depth - 1
            if p.has("rr_depth"):
                rr = p.integer("rr_depth")
                if rr < 1:
                    p.props["rr_depth"].fail(f"must be >= 1 (got {rr})")
                settings["rr_depth"] = rr - 1
            settings["hide_emitters"] = p.boolean("hide_emitters", False)
            p.finish(quiet=("samples_per_pass", "timeout"))
        elif t == "direct":
            self.warn(node, "integrator 'direct' is rendered as path tracing with one bounce", key=("direct",))
            settings["max_depth"] = 1
            p.used.update(p.props)
            p.finish()
        else:
            self.warn(node, f"integrator '{t}' is not supported: clpt's path tracer is used", key=("integrator", t))

    # --- the scene --------------------------------------------------------------------------

    def load(self) -> Scene:
        root = _read_xml(self.root_path, self.shown)
        if root.tag != "scene":
            root.fail("the root element must be <scene>")
        self.substitute(root)
        if "version" not in root.attrs:
            root.fail("missing attribute 'version' (e.g. version=\"3.0.0\")")
        major = _major_version(root)
        if major > 3:
            self.warn(root, f"version {root.attrs['version']} is newer than the Mitsuba 3 subset clpt reads",
                      key=("version",))
        nodes = self.expand(root, (self.root_path.resolve(),), legacy=major < 2)
        self.register(nodes)
        unused = self.given - self.used_params
        if unused:
            name = sorted(unused)[0]
            raise SceneError(f"{self.shown}: parameter {name!r} is not used by the scene"
                             f"{_suggest(name, self.used_params | self.declared)}")

        settings: dict = {}
        camera = None
        shapes: list = []
        materials: dict = {}
        for n in nodes:
            if n.tag == "sensor":
                if camera is not None:
                    self.warn(n, "more than one sensor: the first is used", key=("sensors",))
                    continue
                camera = self.sensor(n, settings)
            elif n.tag == "integrator":
                self.integrator(n, settings)
            elif n.tag == "shape":
                self.top_shape(n, shapes)
            elif n.tag == "bsdf":
                m = self.bsdf(n)
                if "id" in n.attrs:
                    materials[n.attrs["id"]] = m
            elif n.tag == "emitter":
                self.emitter(n, shapes)
            elif n.tag in ("texture", "alias", "ref"):
                pass  # used where referenced
            elif n.tag in ("medium", "phase", "volume"):
                self.warn(n, f"{n.tag}s are not supported; left out", key=(n.tag,))
            else:
                n.fail(f"is not allowed at the top level of <scene>")
        if camera is None:
            self.warn(root, "no sensor: Mitsuba's default camera is used (at the origin, looking along +z, "
                            "fov 39.3 along x)", key=("nosensor",))
            camera = Camera(origin=(0.0, 0.0, 0.0), target=(0.0, 0.0, 1.0), fov=39.3077, fov_axis="x",
                            width=768, height=576, pixel_filter=PixelFilter("gaussian"))
        if "max_depth" not in settings:
            settings["max_depth"] = UNLIMITED_DEPTH  # Mitsuba's default path integrator
        defaults = RenderSettings()
        render = RenderSettings(spp=settings.get("spp", 4), max_depth=settings["max_depth"],
                                seed=settings.get("seed", defaults.seed),
                                rr_depth=settings.get("rr_depth", defaults.rr_depth),
                                hide_emitters=settings.get("hide_emitters", defaults.hide_emitters),
                                shading_normals="mitsuba")
        self.emit_warnings()
        scene = Scene(camera=camera, shapes=shapes, materials=materials, render=render, source=self.shown)
        try:
            scene.check()
        except SceneError as e:
            if self.left_out_emitters and NO_LIGHT in str(e):
                # The scene's only lights were of kinds clpt lacks (a sun and sky, most often): say
                # which, in one line, rather than that the scene is dark.
                n = self.left_out_emitters[0]
                t = n.attrs.get("type", "?")
                what = " (Mitsuba's sun and sky models are not implemented)" if t in SKY_EMITTERS else ""
                n.fail(f"emitter '{t}' is not supported{what}, and the scene has no other light "
                       f"(clpt renders area, point, spot, directional, envmap and constant emitters)")
            raise SceneError(f"{e} (after import from Mitsuba XML)") from None
        return scene

    def emitter(self, node: _Node, shapes: list):
        """A top-level emitter: point, spot, directional, envmap and constant
        lights; other kinds are left out with a warning."""
        p = self.props(node)
        t = p.type
        if t not in ("point", "spot", "directional", "envmap", "constant"):
            self.left_out_emitters.append(node)
            self.warn(node, f"emitter '{t}' is not supported (only area emitters on shapes, point, spot, directional, "
                            "envmap and constant); left out", key=("emitter", t))
            return
        if t in ("envmap", "constant"):
            if any(isinstance(s, EnvironmentLight) for s in shapes):
                node.fail("only one environment emitter (envmap or constant) is allowed in a scene")
            shapes.append(self.environment(node, p))
            p.finish()
            return
        if t == "directional":
            m = p.transform("to_world")
            if p.has("direction"):
                if p.has("to_world"):
                    node.fail("give either direction or to_world, not both")
                d = p.point("direction", (0.0, 0.0, 1.0))
            else:
                d = m[:3, :3] @ np.array([0.0, 0.0, 1.0])
            if not np.linalg.norm(d) > 0:
                node.fail("the direction is zero (or to_world is singular)")
            e = p.color("irradiance", 1.0, emitter=True)
            shapes.append(DirectionalLight(direction=tuple(float(x) for x in d / np.linalg.norm(d)), irradiance=e))
            p.finish()
            return
        intensity = p.color("intensity", 1.0, emitter=True)
        if t == "point":
            if p.has("position") and p.has("to_world"):
                node.fail("give either position or to_world, not both")
            pos = p.point("position", (0.0, 0.0, 0.0)) if p.has("position") else p.transform("to_world")[:3, 3]
            shapes.append(PointLight(position=tuple(float(x) for x in pos), intensity=intensity))
        else:
            tex = p.texture("texture")
            if tex is None and (p.has("texture") or any(nm == "texture" for nm, _ in p.objects)):
                node.fail("a spot light's texture must be a bitmap or checkerboard")
            m = p.transform("to_world")
            d = m[:3, :3] @ np.array([0.0, 0.0, 1.0])
            if not np.linalg.norm(d) > 0 or (tex is not None and not abs(np.linalg.det(m[:3, :3])) > 0):
                node.fail("to_world is singular")
            cutoff = p.float("cutoff_angle", 20.0)
            beam = p.float("beam_width", 0.75 * cutoff)
            if not 0 < cutoff <= 90:
                node.fail(f"cutoff_angle must be in (0, 90] degrees (got {cutoff:g})")
            if not 0 <= beam <= cutoff:
                node.fail(f"beam_width must be in [0, cutoff_angle = {cutoff:g}] degrees (got {beam:g})")
            shapes.append(SpotLight(position=tuple(float(x) for x in m[:3, 3]), intensity=intensity,
                                    direction=tuple(float(x) for x in d / np.linalg.norm(d)),
                                    cutoff_angle=float(cutoff), beam_width=float(beam), texture=tex,
                                    texture_axes=None if tex is None else tuple(
                                        tuple(float(x) for x in m[:3, k] / np.linalg.norm(d)) for k in (0, 1))))
        p.finish()

    def environment(self, node: _Node, p: _Props) -> EnvironmentLight:
        """Mitsuba's envmap (filename, scale, to_world; an 8-bit image is
        sRGB-decoded as Mitsuba decodes it) or constant (radiance)."""
        if p.type == "constant":
            return EnvironmentLight(radiance=p.color("radiance", 1.0, emitter=True))
        name = p.string("filename") or node.fail("missing property 'filename'")
        path = self.resolve(node, name)
        try:
            img = np.asarray(load_image(path), dtype=np.float32)
        except (ImageError, OSError) as e:
            node.fail(f"cannot read {path}: {e}")
        if img.ndim == 2:
            img = img[:, :, None]
        img = img[:, :, :3] if img.shape[2] >= 3 else np.repeat(img[:, :, :1], 3, axis=2)
        if path.suffix.lower() not in (".exr", ".hdr", ".pfm"):
            img = np.where(img <= 0.04045, img / 12.92, ((img + 0.055) / 1.055) ** 2.4).astype(np.float32)
        h, w = img.shape[:2]
        if w < 2 or h < 3:
            node.fail(f"{name}: the environment map must be at least 2x3 pixels (got {w}x{h})")
        scale = p.float("scale", 1.0)
        if not scale > 0:
            node.fail(f"scale must be > 0 (got {scale:g})")
        m = p.transform("to_world")
        p.boolean("mis_compensation", False)  # changes Mitsuba's variance only, not its image
        return EnvironmentLight(image=img, scale=float(scale), to_world=tuple(map(tuple, m.tolist())),
                                filename=str(path))

    def top_shape(self, n: _Node, shapes: list, to_world=None):
        t = n.attrs.get("type", "")
        if t == "shapegroup":
            return  # instantiated by <shape type="instance">
        if t == "instance":
            p = self.props(n)
            m = p.transform("to_world")
            if to_world is not None:
                m = to_world @ m
            groups = [self.deref(o) for _, o in p.objects]
            p.used.update(("obj", id(o)) for _, o in p.objects)
            for g in groups:
                if g.tag != "shape" or g.attrs.get("type") != "shapegroup":
                    n.fail("an instance must refer to a shapegroup")
                for c in g.children:
                    if c.tag == "shape":
                        self.top_shape(c, shapes, m)
                    else:
                        c.fail("a shapegroup may hold only shapes")
            p.finish()
            return
        self.shape(n, shapes, to_world)


# --- Mitsuba 0.x files ------------------------------------------------------------------------
#
# Mitsuba 3 reads a file whose version is below 2.0 after an upgrade (parser.cpp's
# transform_upgrade; before 3.7, xml.cpp's upgrade_tree): every property name from
# camelCase to snake_case (toWorld -> to_world, intIOR -> int_ior, sampleCount ->
# sample_count), but never a <default>'s name, since the $references to it are not
# renamed either; a diffuse BSDF's diffuse_reflectance -> reflectance; a texture's
# uoffset/voffset/uscale/vscale -> a to_uv transform; and (up to 3.6) the tag
# <lookAt> -> <lookat>. Each file is upgraded by its own version.


def camel_to_snake(name: str) -> str:
    """Mitsuba 3's upgrade of a 0.x property name: an upper-case run after a
    lower-case letter becomes '_' and the run in lower case (intIOR -> int_ior,
    fovAxis -> fov_axis); ASCII letters only, as C's islower/isupper."""
    return re.sub(r"(?<=[a-z])([A-Z]+)", lambda m: "_" + m.group(1).lower(), name)


def _major_version(node: _Node) -> int:
    version = node.attrs["version"]
    try:
        return int(version.split(".")[0])
    except ValueError:
        node.fail(f"bad version {version!r}")


def _upgrade_node(node: _Node):
    """A 0.x element's own upgrade, before it is checked: the tag <lookAt>,
    and its property name (not a <default>'s: $references keep 0.x names)."""
    if node.tag == "lookAt":
        node.tag = "lookat"
    if "name" in node.attrs and node.tag != "default":
        node.attrs["name"] = camel_to_snake(node.attrs["name"])


# A 0.x texture's placement, as to_uv's operations (x: u, y: v). uvscale is Mitsuba
# 0.6's default for both uscale and vscale; Mitsuba 3's upgrade leaves it out.
_UV_OFFSETS = ("uoffset", "voffset")
_UV_SCALES = ("uscale", "vscale", "uvscale")


def _upgrade_object(node: _Node):
    """A 0.x object's upgrade once its children are read: a diffuse BSDF's
    diffuse_reflectance, and a texture's uv offsets and scales (as a to_uv
    transform: translate, then scale)."""
    named = {c.attrs.get("name"): c for c in node.children if c.tag in PROPERTY_TAGS + OBJECT_TAGS}
    if node.tag == "bsdf" and node.attrs.get("type") == "diffuse" and "diffuse_reflectance" in named \
            and "reflectance" not in named:
        named["diffuse_reflectance"].attrs["name"] = "reflectance"
    uv = {k: c for k, c in named.items() if k in _UV_OFFSETS + _UV_SCALES and c.tag in ("float", "integer")}
    if not uv or "to_uv" in named:
        return
    first = min(c.line for c in uv.values())

    def op(tag, keys, default):
        attrs = {}
        for axis, k in zip("xy", keys):
            c = uv.get(k) or (uv.get("uvscale") if tag == "scale" else None)
            attrs[axis] = c.attrs.get("value", default) if c is not None else default
        return _Node(tag, attrs, node.file, first, via=node.via)

    ops = [op("translate", _UV_OFFSETS, "0"), op("scale", _UV_SCALES[:2], "1")]
    node.children = [c for c in node.children if all(c is not u for u in uv.values())]
    node.children.append(_Node("transform", {"name": "to_uv"}, node.file, first, ops, node.via))


def load_mitsuba(path, params: dict | None = None, *, strict: bool = False) -> Scene:
    """Read a Mitsuba 3 XML scene. params override the file's <default>
    values (as Mitsuba's -D name=value); strict turns every SceneWarning into
    a SceneError."""
    p = Path(path)
    return _Loader(p, str(path), params, strict).load()
