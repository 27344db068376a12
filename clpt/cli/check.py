"""`clpt check`: a scene file validated and packed, without rendering."""

from __future__ import annotations

from . import common
from .common import load as _load


def add_parser(sub):
    p = sub.add_parser("check", help="validate a scene file")
    p.add_argument("scene")
    common.scene_params(p)
    p.set_defaults(func=run)
    return p


def run(a) -> int:
    from ..features import scene_features
    from ..pack import pack_scene

    scene = _load(a)
    packed = pack_scene(scene)
    names = ("materials", "spheres", "quads", "triangles", "planes", "lights")
    line = ", ".join(f"{n} {c}" for n, c in zip(names, packed.counts))
    if packed.bvh is not None:
        line = (f"materials {packed.count('materials')}, {packed.primitives} spheres, quads and triangles in a BVH "
                f"of {packed.count('nodes')} nodes, planes {packed.count('planes')}, lights {packed.count('lights')}")
    print(f"{a.scene}: ok; {line}")
    print(f"features: {scene_features(packed).describe()}")
    return 0
