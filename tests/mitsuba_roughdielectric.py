"""Tabulate Mitsuba 3's `roughdielectric` (eval and pdf) once, for
tests/test_roughdielectric.py. Mitsuba is never a dependency of clpt; this is
how tests/data/roughdielectric_mitsuba.json was made:

    python tests/mitsuba_roughdielectric.py tests/data/roughdielectric_mitsuba.json

Each case is a BSDF (distribution, alpha, int_ior/ext_ior, sample_visible,
specular_reflectance/transmittance) and pairs of local directions (Mitsuba's
wi towards the viewer, from outside (+z) or inside (-z); wo the scattered
one, reflected or transmitted) with Mitsuba's eval (f |cos_o|, RGB, radiance
transport) and pdf.
"""

import json
import sys
from pathlib import Path

import numpy as np

import mitsuba as mi

sys.path.insert(0, str(Path(__file__).parent))
from mitsuba_roughconductor import roughness, rows_of  # noqa: E402  (sets the scalar_rgb variant)

CASES = [
    {"distribution": "ggx", "alpha": 0.05, "int_ior": 1.5, "ext_ior": 1.0},
    {"distribution": "ggx", "alpha": 0.3, "int_ior": 1.5046, "ext_ior": 1.000277},
    {"distribution": "ggx", "alpha": 0.8, "int_ior": 1.33, "ext_ior": 1.0,
     "specular_reflectance": [0.9, 0.6, 0.3], "specular_transmittance": [0.2, 0.7, 0.95]},
    {"distribution": "beckmann", "alpha": 0.1, "int_ior": 1.5046, "ext_ior": 1.000277},
    {"distribution": "beckmann", "alpha": 0.5, "int_ior": 2.4, "ext_ior": 1.0},
    {"distribution": "beckmann", "alpha": 0.3, "int_ior": 1.0, "ext_ior": 1.5},
    {"distribution": "ggx", "alpha": 0.3, "int_ior": 1.5, "ext_ior": 1.0, "sample_visible": False},
    {"distribution": "beckmann", "alpha": 0.2, "int_ior": 1.5, "ext_ior": 1.0, "sample_visible": False},
    # Anisotropic: alpha_u along the shading frame's x, alpha_v along y.
    {"distribution": "ggx", "alpha_u": 0.05, "alpha_v": 0.35, "int_ior": 1.5, "ext_ior": 1.0},
    {"distribution": "beckmann", "alpha_u": 0.6, "alpha_v": 0.25, "int_ior": 1.5, "ext_ior": 1.0},
]


def directions(rng, n, zmin=0.05):
    """n unit directions in the upper hemisphere, cos theta from zmin to 1."""
    z = rng.uniform(zmin, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def refract(w, eta):
    """w (towards the viewer, +z side) refracted into a medium of relative index eta; None at TIR."""
    c = w[2]
    s2 = (1 - c * c) / (eta * eta)
    if s2 >= 1:
        return None
    return np.array([-w[0] / eta, -w[1] / eta, -np.sqrt(1 - s2)])


def bsdf_of(case):
    au, av = roughness(case)
    d = {"type": "roughdielectric", "distribution": case["distribution"],
         **({"alpha_u": au, "alpha_v": av} if "alpha_u" in case else {"alpha": au}),
         "int_ior": case["int_ior"], "ext_ior": case["ext_ior"],
         "sample_visible": case.get("sample_visible", True)}
    for key in ("specular_reflectance", "specular_transmittance"):
        if key in case:
            d[key] = {"type": "rgb", "value": case[key]}
    return mi.load_dict(d)


def main(out_path):
    rng = np.random.default_rng(17)
    out = []
    for case in CASES:
        bsdf = bsdf_of(case)
        eta = case["int_ior"] / case["ext_ior"]
        rows = []
        for side in (1.0, -1.0):  # the viewer outside, then inside
            e = eta if side > 0 else 1 / eta
            wi = directions(rng, 48)
            wo = directions(rng, 48)
            s = 1.5 * max(roughness(case))
            for j in range(48):
                kind = j % 3
                if kind == 0:    # near the mirror direction
                    v = wi[j] * np.array([-1, -1, 1]) + rng.normal(0, s, 3)
                    v[2] = abs(v[2]) + 0.02
                elif kind == 1:  # near the refracted direction (else anywhere below)
                    t = refract(wi[j], e)
                    v = (t if t is not None else -wo[j]) + rng.normal(0, s, 3)
                    v[2] = -abs(v[2]) - 0.02
                else:            # anywhere, either side
                    v = wo[j] * (1 if rng.random() < 0.5 else np.array([1, 1, -1]))
                wo[j] = v / np.linalg.norm(v)
            wi = wi * np.array([1, 1, side])
            wo = wo * np.array([1, 1, side])
            rows += rows_of(bsdf, wi, wo)
        out.append({"bsdf": case, "rows": rows})
    with open(out_path, "w") as fh:
        json.dump({"mitsuba": mi.__version__, "cases": out}, fh, separators=(",", ":"))


if __name__ == "__main__":
    main(sys.argv[1])
