"""Tabulate Mitsuba 3's `roughplastic` and `plastic` (eval and pdf) once, for
tests/test_plastic.py. Mitsuba is never a dependency of clpt; this is how
tests/data/roughplastic_mitsuba.json was made:

    python tests/mitsuba_roughplastic.py tests/data/roughplastic_mitsuba.json

Each case is a BSDF (type and parameters) and pairs of local directions
(Mitsuba's wi towards the viewer, wo the scattered one, +z the normal) with
Mitsuba's eval (f cos_o, RGB) and pdf (the smooth plastic's: its diffuse part).
"""

import json
import sys
from pathlib import Path

import numpy as np

import mitsuba as mi

sys.path.insert(0, str(Path(__file__).parent))
from mitsuba_roughconductor import rows_of  # noqa: E402  (sets the scalar_rgb variant)

CASES = [
    {"type": "roughplastic", "diffuse_reflectance": [0.8, 0.4, 0.2]},
    {"type": "roughplastic", "distribution": "ggx", "alpha": 0.3, "int_ior": 1.5, "ext_ior": 1.0,
     "specular_reflectance": [0.9, 0.9, 0.7], "diffuse_reflectance": [0.5, 0.5, 0.5]},
    {"type": "roughplastic", "distribution": "beckmann", "alpha": 0.6, "nonlinear": True,
     "diffuse_reflectance": [0.9, 0.6, 0.3]},
    {"type": "roughplastic", "distribution": "ggx", "alpha": 0.05, "int_ior": 1.33,
     "diffuse_reflectance": [0.2, 0.7, 0.4]},
    {"type": "plastic", "diffuse_reflectance": [0.3, 0.6, 0.9]},
    {"type": "plastic", "int_ior": 1.7, "nonlinear": True, "specular_reflectance": [0.8, 0.8, 0.8],
     "diffuse_reflectance": [0.9, 0.5, 0.1]},
]


def directions(rng, n):
    """n unit directions in the upper hemisphere, cos theta from 0.05 to 1."""
    z = rng.uniform(0.05, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def bsdf_of(case):
    d = {}
    for k, v in case.items():
        d[k] = {"type": "rgb", "value": v} if isinstance(v, list) else v
    return mi.load_dict(d)


def main(out_path):
    rng = np.random.default_rng(17)
    out = []
    for case in CASES:
        bsdf = bsdf_of(case)
        alpha = case.get("alpha", 0.1) if case["type"] == "roughplastic" else 0.05
        wi = directions(rng, 64)
        wo = directions(rng, 64)
        mirror = wi * np.array([-1, -1, 1])
        near = mirror[:32] + rng.normal(0, 1.5 * alpha, (32, 3))
        near[:, 2] = np.abs(near[:, 2]) + 0.02
        wo[:32] = near / np.linalg.norm(near, axis=1, keepdims=True)
        out.append({"bsdf": case, "rows": rows_of(bsdf, wi, wo)})
    with open(out_path, "w") as fh:
        json.dump({"mitsuba": mi.__version__, "cases": out}, fh, separators=(",", ":"))


if __name__ == "__main__":
    main(sys.argv[1])
