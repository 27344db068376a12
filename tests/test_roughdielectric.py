"""The rough dielectric (kernels/bsdf.h rough_dielectric_*): values against
Mitsuba 3's `roughdielectric`, sampling against bsdf_pdf (chi-square) over
both hemispheres, sample weights against eval / pdf, energy (white furnace),
the limit alpha -> 0 against the smooth dielectric, and a rough glass sphere
against a Mitsuba 3 reference."""

import json
import math
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

import clpt

from stats import ALPHA, chi2_test, sidak

pytestmark = pytest.mark.portability

DATA = Path(__file__).parent / "data"


def lobe(probe, alpha, dist, eta, d, u1, u2, uf, w, kr=(1, 1, 1), kt=(1, 1, 1), visible=True, importance=False):
    """probe_rough_dielectric over incoming directions d (N, 3; towards the
    surface, from above: outside, or below: inside), uniforms u1, u2, uf and
    evaluation directions w (N, 3); eta inside over outside; normal +z."""
    r4 = cl.cltypes.make_double4 if probe.real is np.float64 else cl.cltypes.make_float4
    cols = [d[:, 0], d[:, 1], d[:, 2], u1, u2, uf, w[:, 0], w[:, 1], w[:, 2]]
    o = probe.run("probe_rough_dielectric", cols, 13,
                  scalars=(r4(alpha, 1.0 if dist == "beckmann" else 0.0, eta, 1.0 if visible else 0.0),
                           r4(*kr, 0), r4(*kt, 1.0 if importance else 0.0)))
    return {"wi": np.stack(o[0:3], 1).astype(np.float64), "weight": np.stack(o[3:6], 1).astype(np.float64),
            "spdf": o[6].astype(np.float64), "chosen": o[7] > 0, "up": o[8] > 0,
            "f": np.stack(o[9:12], 1).astype(np.float64), "pdf": o[12].astype(np.float64)}


def incoming(theta_deg, n, inside=False):
    t = math.radians(theta_deg)
    return np.tile([-math.sin(t), 0.0, math.cos(t) if inside else -math.cos(t)], (n, 1))


# --- values against Mitsuba 3 ---------------------------------------------------------------------

def mitsuba_cases():
    return json.loads((DATA / "roughdielectric_mitsuba.json").read_text())["cases"]


@pytest.mark.parametrize("double", [False, True])
@pytest.mark.parametrize("case", range(8))
def test_eval_and_pdf_match_mitsuba(probes, case, double):
    """f |cos| and pdf against Mitsuba 3.9.1's eval and pdf (radiance
    transport; tests/mitsuba_roughdielectric.py): reflection and transmission,
    from outside and inside, GGX and Beckmann, tinted reflectance and
    transmittance, visible-normal and plain sampling."""
    c = mitsuba_cases()[case]
    b = c["bsdf"]
    wi = np.array([r["wi"] for r in c["rows"]])    # Mitsuba's: towards the viewer
    wo = np.array([r["wo"] for r in c["rows"]])
    ev = np.array([r["eval"] for r in c["rows"]])  # f |cos_o|
    pdf = np.array([r["pdf"] for r in c["rows"]])
    n = len(wi)
    h = np.full(n, 0.5)
    out = lobe(probes(1, double=double), b["alpha"], b["distribution"], b["int_ior"] / b["ext_ior"], -wi, h, h, h,
               wo, b.get("specular_reflectance", (1, 1, 1)), b.get("specular_transmittance", (1, 1, 1)),
               b.get("sample_visible", True))
    f_cos = out["f"] * np.abs(wo[:, 2:3])
    through = wi[:, 2] * wo[:, 2] < 0
    assert (ev[:, 0] > 0).sum() >= 48 and (ev[through, 0] > 0).sum() >= 8
    np.testing.assert_allclose(f_cos, ev, rtol=2e-3, atol=1e-5 * ev.max())
    np.testing.assert_allclose(out["pdf"], pdf, rtol=2e-3, atol=1e-5 * pdf.max())
