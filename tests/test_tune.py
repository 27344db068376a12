"""Per-device defaults (clpt/tune.py): what device queries predict, the
measurement where they do not, its cache, and explicit choices winning; none
of them changes a bit of the image."""

import json
import threading
import time

import numpy as np
import pyopencl as cl
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


class _FakePlatform:
    name = "Fake(R) OpenCL"


class _FakeDevice:
    native_vector_width_float = 16
    preferred_vector_width_float = 1
    max_work_group_size = 64
    type = cl.device_type.CPU
    platform = _FakePlatform()


class _FakeContext:
    """A CPU runtime that is not PoCL: its lanes and local size are measured."""
    is_cpu, is_pocl, label, platform = True, False, "fake CPU (fake runtime)", "Fake Runtime"
    device = _FakeDevice()

    def identity(self):
        return "fake|1|cpu"


class _FakeState:
    def __init__(self, lanes):
        self.features = type("F", (), {"lanes": lanes})()
        self.local = 16
        self.seen_locals = []

    def launch_seconds(self):  # as DeviceWorker: the host time of an empty launch
        return 1e-4


def _fake_trial(speed):
    """A trial whose samples/s are speed(lanes, local) (and 1 ms per spp)."""
    def trial(st, spp, seed):
        st.seen_locals.append(st.local)
        return speed(st.features.lanes, st.local) * 1e6, 1e-3
    return trial


def test_a_measured_device_gets_the_fastest_lanes_and_local_size(monkeypatch, tmp_path):
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CLPT_TUNE", "measure")
    states = {}

    def make(lanes):
        states[lanes] = _FakeState(lanes)
        return states[lanes]

    # 1 lane beats 16; with 1 lane, groups of 32 beat the others (128 is above the device's maximum).
    speed = _fake_trial(lambda lanes, local: (2.0 if lanes == 1 else 1.0) * (1.5 if local == 32 else 1.0))
    t, st = tune.choose(_FakeContext(), "src", ["-DX=1"], make, speed)
    assert (t.lanes, t.local_size, t.how) == (1, 32, "measured") and st is states[1]
    assert set(states[1].seen_locals) == {16, 32, 64} and states[1].local == 16  # tried, then left alone
    assert "local size 16" in t.why and "32 3.00" in t.why
    cached = tune.choose(_FakeContext(), "src", ["-DX=1"], make, speed)[0]
    assert (cached.lanes, cached.local_size, cached.how) == (1, 32, "cached")
    # An explicit local size is not measured, and wins.
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path / "other"))
    t2, _ = tune.choose(_FakeContext(), "src", ["-DX=1"], make, speed, local_size=8)
    assert (t2.lanes, t2.local_size, t2.how) == (1, 8, "explicit")
    assert not list((tmp_path / "other").glob("tune/*.json"))  # a partial measurement is not cached
    # The default policy takes the measurement made before, and measures nothing itself.
    monkeypatch.setenv("CLPT_TUNE", "auto")
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path))
    states.clear()
    cached = tune.choose(_FakeContext(), "src", ["-DX=1"], make, speed)[0]
    assert (cached.lanes, cached.local_size, cached.how) == (1, 32, "cached") and not states


def test_a_local_size_within_noise_of_the_default_leaves_it(monkeypatch, tmp_path):
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CLPT_TUNE", "measure")
    speed = _fake_trial(lambda lanes, local: 1.05 if local == 64 else 1.0)
    t, _ = tune.choose(_FakeContext(), "src", [], _FakeState, speed)
    assert t.local_size == 16 and "64 1.05" in t.why


def test_measure_local_sizes_restores_the_state():
    st = _FakeState(16)
    st.local = 7
    rates = tune.measure_local_sizes(st, _fake_trial(lambda lanes, local: local / 16), [16, 64])
    assert rates == {16: 1.0, 64: 4.0} and st.local == 7


def test_the_default_policy_predicts_without_trial_renders(monkeypatch, tmp_path):
    """Nothing measured before: CLPT_TUNE=auto predicts from the queries and
    the kernel's kind, and neither builds a candidate nor renders a trial."""
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CLPT_TUNE", "auto")

    def make(lanes):
        raise AssertionError("a candidate was built")

    def trial(st, spp, seed):
        raise AssertionError("a trial was rendered")

    t, st = tune.choose(_FakeContext(), "src", ["-DCLPT_PHOTONS=1"], make, trial)
    assert t.how == "query" and st is None and t.lanes == 16  # an unknown runtime: its register width
    assert not list(tmp_path.glob("tune/*.json"))


@pytest.mark.parametrize("platform,photons,lanes", [("Intel(R) OpenCL", False, 16), ("Intel(R) OpenCL", True, 16),
                                                    ("Portable Computing Language", True, 16)])
def test_predictions_by_runtime_and_kernel(platform, photons, lanes):
    dev = _FakeDevice()
    dev.platform = type("P", (), {"name": platform})()
    assert tune.predict(dev, photons).lanes == lanes
    gpu = _FakeDevice()
    gpu.type = cl.device_type.GPU
    assert tune.predict(gpu, photons).lanes == 1


@pytest.mark.parametrize("at_once", [False, True])
def test_lane_candidates_build_at_once_only_where_the_runtime_takes_it(monkeypatch, tmp_path, at_once):
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CLPT_TUNE", "measure")
    monkeypatch.setattr(program, "builds_at_once", lambda dctx: at_once)
    lock, running, most, threads = threading.Lock(), [0], [0], set()

    def make(lanes):  # a build that takes a moment, so that builds started together overlap
        with lock:
            running[0] += 1
            most[0] = max(most[0], running[0])
            threads.add(threading.get_ident())
        time.sleep(0.2)
        with lock:
            running[0] -= 1
        return _FakeState(lanes)

    tune.choose(_FakeContext(), "src", [], make, _fake_trial(lambda lanes, local: 1.0))
    assert most[0] == (2 if at_once else 1)
    assert (threads == {threading.get_ident()}) == (not at_once)
