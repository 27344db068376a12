"""Per-device defaults (clpt/tune.py): what device queries predict, the
measurement where they do not, its cache, and explicit choices winning; none
of them changes a bit of the image."""

import json

import numpy as np
import pytest

import clpt
from clpt import program, tune


def test_queried_defaults_and_explicit_choices(device_spec):
    r = clpt.Renderer("cornell_box", device=device_spec)
    st = r.states[0]
    assert st.tuning.lanes in tune.LANE_WIDTHS and st.features.lanes == st.tuning.lanes
    assert st.local == st.tuning.local_size and st.tuning.how in ("query", "cached", "measured")
    if st.dctx.is_pocl:
        assert st.tuning.lanes == tune.register_width(st.dctx.device)
    e = clpt.Renderer("cornell_box", device=device_spec, lanes=2, local_size=3).states[0]
    assert (e.features.lanes, e.local, e.tuning.how) == (2, 3, "explicit")
    with pytest.raises(ValueError):
        clpt.Renderer("cornell_box", device=device_spec, lanes=3)
    with pytest.raises(ValueError):
        clpt.Renderer("cornell_box", device=device_spec, local_size=0)


@pytest.mark.portability
def test_measured_choice_is_cached_and_changes_no_bit(device_spec, monkeypatch):
    monkeypatch.setenv("CLPT_TUNE", "measure")
    scene = clpt.load_scene("cornell_box")  # nothing measured before: CLPT_TUNE=query for the other tests
    first = clpt.Renderer(scene, device=device_spec)
    t = first.states[0].tuning
    if not first.states[0].dctx.is_cpu:
        pytest.skip("measurement is for CPU runtimes")
    assert t.how == "measured" and t.lanes in (1, tune.register_width(first.states[0].dctx.device))
    entries = list((program.cache_dir() / "tune").glob("*.json"))
    assert entries and any(json.loads(p.read_text())["lanes"] == t.lanes for p in entries)
    again = clpt.Renderer(scene, device=device_spec).states[0].tuning
    assert again.how == "cached" and again.lanes == t.lanes
    a = first.render(3, width=20, height=12, seed=5).image
    for lanes in {1, tune.register_width(first.states[0].dctx.device)} - {t.lanes}:
        b = clpt.Renderer(scene, device=device_spec, lanes=lanes).render(3, width=20, height=12, seed=5).image
        assert np.array_equal(a, b)
