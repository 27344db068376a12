"""Tabulate Mitsuba 3's `roughconductor` (eval and pdf) once, for
tests/test_microfacet.py. Mitsuba is never a dependency of clpt; this is how
tests/data/roughconductor_mitsuba.json was made:

    python tests/mitsuba_roughconductor.py tests/data/roughconductor_mitsuba.json

Each case is a BSDF (distribution, alpha or alpha_u/alpha_v, material or eta/k,
specular_reflectance) and pairs of local directions (Mitsuba's wi towards the
viewer, wo the scattered one, +z the normal) with Mitsuba's eval (f cos_o, RGB)
and pdf.
"""

import json
import sys

import numpy as np

import mitsuba as mi

mi.set_variant("scalar_rgb")

CASES = [
    {"distribution": "ggx", "alpha": 0.05, "material": "none"},
    {"distribution": "ggx", "alpha": 0.2, "material": "Au"},
    {"distribution": "ggx", "alpha": 0.7, "material": "Cu", "specular_reflectance": [0.9, 0.6, 0.3]},
    {"distribution": "beckmann", "alpha": 0.1, "material": "Al"},
    {"distribution": "beckmann", "alpha": 0.5, "eta": [0.2, 0.9, 1.1], "k": [3.9, 2.4, 1.9]},
    # Anisotropic: alpha_u along the shading frame's x (Mitsuba's sh_frame.s), alpha_v along y.
    {"distribution": "ggx", "alpha_u": 0.05, "alpha_v": 0.4, "material": "Al"},
    {"distribution": "ggx", "alpha_u": 0.6, "alpha_v": 0.15, "material": "Cu"},
    {"distribution": "beckmann", "alpha_u": 0.3, "alpha_v": 0.08, "material": "Au"},
    {"distribution": "beckmann", "alpha_u": 0.1, "alpha_v": 0.5, "eta": [0.2, 0.9, 1.1], "k": [3.9, 2.4, 1.9]},
]


def roughness(case):
    """(alpha_u, alpha_v) of a case."""
    return (case["alpha_u"], case["alpha_v"]) if "alpha_u" in case else (case["alpha"], case["alpha"])


def directions(rng, n):
    """n unit directions in the upper hemisphere, cos theta from 0.05 to 1."""
    z = rng.uniform(0.05, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def bsdf_of(case):
    d = {"type": "roughconductor", "distribution": case["distribution"]}
    if "alpha_u" in case:
        d["alpha_u"], d["alpha_v"] = case["alpha_u"], case["alpha_v"]
    else:
        d["alpha"] = case["alpha"]
    if "eta" in case:
        d["eta"] = {"type": "rgb", "value": case["eta"]}
        d["k"] = {"type": "rgb", "value": case["k"]}
    else:
        d["material"] = case["material"]
    if "specular_reflectance" in case:
        d["specular_reflectance"] = {"type": "rgb", "value": case["specular_reflectance"]}
    return mi.load_dict(d)


def rows_of(bsdf, wi, wo):
    """Mitsuba's eval (RGB) and pdf of each pair of local directions, +z the normal."""
    rows = []
    for a, b in zip(wi, wo):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*a)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        ctx = mi.BSDFContext()
        f = bsdf.eval(ctx, si, mi.Vector3f(*b))
        p = bsdf.pdf(ctx, si, mi.Vector3f(*b))
        rows.append({"wi": [float(x) for x in a], "wo": [float(x) for x in b],
                     "eval": [float(f[0]), float(f[1]), float(f[2])], "pdf": float(p)})
    return rows


def main(out_path):
    rng = np.random.default_rng(7)
    out = []
    for case in CASES:
        bsdf = bsdf_of(case)
        wi = directions(rng, 64)
        # Half the outgoing directions near the mirror direction (where the lobe is), half anywhere.
        wo = directions(rng, 64)
        mirror = wi * np.array([-1, -1, 1])
        near = mirror[:32] + rng.normal(0, 1.5 * max(roughness(case)), (32, 3))
        near[:, 2] = np.abs(near[:, 2]) + 0.02
        wo[:32] = near / np.linalg.norm(near, axis=1, keepdims=True)
        out.append({"bsdf": case, "rows": rows_of(bsdf, wi, wo)})
    with open(out_path, "w") as fh:
        json.dump({"mitsuba": mi.__version__, "cases": out}, fh, separators=(",", ":"))


if __name__ == "__main__":
    main(sys.argv[1])
