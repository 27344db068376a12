"""Mitsuba's `roughplastic` and `plastic` (kernels/bsdf.h plastic_*,
clpt/coating.py): eval and pdf against Mitsuba 3's values, sampling against
bsdf_pdf (chi-square), sample weights against eval / pdf, energy."""

import json
import math
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

import clpt
from clpt import coating
from clpt.pack import _material_records

from stats import ALPHA, chi2_test, sidak

pytestmark = pytest.mark.portability

DATA = Path(__file__).parent / "data" / "roughplastic_mitsuba.json"


def material_of(case):
    """clpt's Material for a Mitsuba case (tests/mitsuba_roughplastic.py)."""
    kw = {k: tuple(v) if isinstance(v, list) else v for k, v in case.items() if k != "type"}
    if case["type"] == "plastic":
        return clpt.Material.smooth_plastic(**kw)
    return clpt.Material.rough_plastic(**kw)


def lobe(probe, m, d, u1, u2, uf, w):
    """probe_plastic for material m over incoming directions d (N, 3),
    uniforms u1, u2, uf and evaluation directions w (N, 3); normal +z."""
    rec = _material_records([m])[0]
    r4 = cl.cltypes.make_double4 if probe.real is np.float64 else cl.cltypes.make_float4
    tab = np.zeros((16, 4), dtype=probe.real)
    if m.alpha > 0:
        tab[:] = np.reshape(coating.rough_tables(m.alpha, m.distribution, m.plastic_eta)[0], (16, 4))
    buf = cl.Buffer(probe.dctx.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=tab)
    c = rec["coat"]
    cols = [d[:, 0], d[:, 1], d[:, 2], u1, u2, uf, w[:, 0], w[:, 1], w[:, 2]]
    o = probe.run("probe_plastic", cols, 13, prefix=(buf,),
                  scalars=(r4(*c), r4(*m.kp, float(m.nonlinear)), r4(*m.kps, rec["kps_w"][3])))
    return {"wi": np.stack(o[0:3], 1), "weight": np.stack(o[3:6], 1), "spdf": o[6], "chosen": o[7] > 0,
            "delta": o[8] > 0, "f": np.stack(o[9:12], 1), "pdf": o[12]}


def incoming(theta_deg, n):
    t = math.radians(theta_deg)
    return np.tile([-math.sin(t), 0.0, -math.cos(t)], (n, 1))


def mitsuba_cases():
    return json.loads(DATA.read_text())["cases"]


# --- the host's tables against Mitsuba's ------------------------------------------------------------

def test_fdr_fit_is_mitsubas():
    """Mitsuba's fitted diffuse Fresnel reflectance against the exact
    cosine-weighted average of Fresnel (its papers' stated accuracy)."""
    from clpt.mitsuba import fresnel_diffuse_reflectance as exact
    for eta in (1.2, 1.49, 1.7):
        assert coating.fresnel_diffuse_reflectance(eta) == pytest.approx(exact(eta), rel=2e-3, abs=1e-3)
        assert coating.fresnel_diffuse_reflectance(1 / eta) == pytest.approx(exact(1 / eta), rel=6e-3)


def test_transmittance_table_limits():
    """t(mu) of a nearly smooth coating is 1 - F(mu) (away from grazing), and
    every table lies in [0, 1]."""
    from clpt.mitsuba import fresnel_dielectric
    t, r = coating.rough_tables(0.001, "ggx", 1.5)
    mu = np.linspace(0, 1, coating.TABLE_RES)
    for i in range(20, coating.TABLE_RES):
        assert t[i] == pytest.approx(1 - fresnel_dielectric(mu[i], 1.5), abs=2e-3)
    for alpha in (0.05, 0.5, 1.0):
        t, r = coating.rough_tables(alpha, "beckmann", 1.49)
        assert 0 <= min(t) and max(t) <= 1 and 0 < r < 1


# --- values against Mitsuba 3 ---------------------------------------------------------------------

@pytest.mark.parametrize("double", [False, True])
@pytest.mark.parametrize("case", range(6))
def test_eval_and_pdf_match_mitsuba(probes, case, double):
    """f cos and pdf of each direction pair against Mitsuba 3's (the rough
    coating's tables integrated as Mitsuba integrates them, clpt/coating.py)."""
    c = mitsuba_cases()[case]
    m = material_of(c["bsdf"])
    wi = np.array([r["wi"] for r in c["rows"]])
    wo = np.array([r["wo"] for r in c["rows"]])
    ev = np.array([r["eval"] for r in c["rows"]])
    pdf = np.array([r["pdf"] for r in c["rows"]])
    n = len(wi)
    half = np.full(n, 0.5)
    out = lobe(probes(1, double=double), m, -wi, half, half, half, wo)
    f_cos = out["f"] * wo[:, 2:3]
    assert (ev > 0).all()
    rtol = 1e-3 if m.alpha > 0 or not double else 2e-4
    np.testing.assert_allclose(f_cos, ev, rtol=rtol, atol=1e-6 * ev.max())
    np.testing.assert_allclose(out["pdf"], pdf, rtol=rtol, atol=1e-6 * pdf.max())
