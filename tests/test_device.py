"""Device selection by name: exact names and platform short names first, a
substring only when it picks out one device, else a refusal naming the matches."""

import sys
from types import SimpleNamespace

import pytest

from clpt.device import DeviceError, _match, platform_short_name


def _found():
    pocl = SimpleNamespace(name="Portable Computing Language")
    intel = SimpleNamespace(name="Intel(R) OpenCL")
    nv = SimpleNamespace(name="NVIDIA CUDA")
    devs = [(0, 0, intel, SimpleNamespace(name="Intel(R) Xeon(R) Processor @ 2.80GHz")),
            (1, 0, pocl, SimpleNamespace(name="pthread-Intel(R) Xeon(R) Processor @ 2.80GHz")),
            (2, 0, nv, SimpleNamespace(name="NVIDIA H200")),
            (2, 1, nv, SimpleNamespace(name="NVIDIA H200"))]
    return devs


def test_short_names():
    assert platform_short_name("Portable Computing Language") == "pocl"
    assert platform_short_name("Intel(R) OpenCL") == "intel"
    assert platform_short_name("NVIDIA CUDA") == "nvidia"
    assert platform_short_name("Frobnicator(TM) Runtime") == "frobnicator"


@pytest.mark.parametrize("spec,want", [("intel", (0, 0)), ("POCL", (1, 0)), ("nvidia", (2, 0)),
                                       ("Intel(R) OpenCL", (0, 0)), ("pthread", (1, 0)),
                                       ("NVIDIA H200", (2, 0)), ("1", (1, 0)), ("2:1", (2, 1))])
def test_exact_then_unique_matches(spec, want):
    found = _found()
    got = _match(spec, found)
    assert len(got) == 1 and any(d is got[0] and (pi, di) == want for pi, di, _, d in found)


def test_ambiguous_and_unknown_names_are_refused():
    with pytest.raises(DeviceError, match="matches 2 devices: 0:0 .*; 1:0 "):
        _match("xeon", _found())
    with pytest.raises(DeviceError, match="matches 2 devices"):
        _match("cuda", _found())  # a substring of one platform with two devices
    with pytest.raises(DeviceError, match="no OpenCL device matches 'amd'"):
        _match("amd", _found())


# --- the default device and checks (clpt/device.py, clpt/probe.py) -------------------------------

import warnings  # noqa: E402

import pyopencl as cl  # noqa: E402

import clpt.device as devmod  # noqa: E402
from clpt import probe  # noqa: E402


def _dev(platform, name, kind, driver="1.0"):
    p = SimpleNamespace(name=platform, version="OpenCL 3.0")
    return SimpleNamespace(name=name, platform=p, type=kind, driver_version=driver, vendor="v", version="OpenCL 3.0")


CPU, GPU = cl.device_type.CPU, cl.device_type.GPU


def _machine(monkeypatch, devices, broken=(), known=None, background=None):
    """Fake platforms (one device each) and checks: devices named in broken
    fail; known: names checked before (all, by default); background: gets
    the names whose checks were started in the background."""
    found = [(i, 0, d.platform, d) for i, d in enumerate(devices)]
    monkeypatch.setattr(devmod, "_all_devices", lambda: found)
    checked = []
    known = {d.name for d in devices} if known is None else set(known)
    background = [] if background is None else background

    def check(d, lanes=None, photons=False, found=None, wait=True, **kw):
        if not wait and d.name not in known:
            if kw.get("background", True):
                background.append(d.name)
            return None
        checked.append(d.name)
        known.add(d.name)
        bad = d.name in broken
        return probe.CheckResult(not bad, lanes or 16, "LLVM ERROR: boom" if bad else "", 0.1)

    monkeypatch.setattr(devmod, "check_device", check)
    monkeypatch.setattr(devmod, "_reported", set())
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    return checked


# A table where PoCL merges photons faster and Intel's runtime path traces
# faster, as measured once: the ranking by kernel kind and the background
# check of a runtime ranked ahead only for photons are checked against it.
SPLIT_RATES = {"plain": {"intel": 13.4, "pocl": 9.55}, "photons": {"intel": 1.89, "pocl": 4.81}}


def _three():
    return [_dev("Portable Computing Language", "pthread-old", CPU, "3.0"),
            _dev("Intel(R) OpenCL", "EPYC", CPU),
            _dev("Oclgrind", "Oclgrind Simulator", GPU)]


def test_default_ranks_cpu_runtimes_by_kernel_kind_and_never_takes_a_simulator(monkeypatch):
    monkeypatch.setattr(devmod, "CPU_RUNTIME_RATES", SPLIT_RATES)
    _machine(monkeypatch, _three())
    assert devmod.default_device(photons=False).device.name == "EPYC"  # Intel is faster path tracing
    assert devmod.default_device(photons=True).device.name == "pthread-old"  # PoCL is faster merging
    nv = _dev("NVIDIA CUDA", "H200", GPU)
    _machine(monkeypatch, _three() + [nv])
    c = devmod.default_device(photons=True)
    assert c.device.name == "H200" and c.why == "the first GPU"


def test_a_default_that_cannot_render_is_skipped_in_one_line(monkeypatch):
    monkeypatch.setattr(devmod, "CPU_RUNTIME_RATES", SPLIT_RATES)
    checked = _machine(monkeypatch, _three(), broken={"pthread-old"})
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        sel = devmod.choose_devices(None, photons=True)
        devmod.choose_devices(None, photons=True)  # said once a process
    assert [d.name for d in sel.devices] == ["EPYC"] and checked[:2] == ["EPYC", "pthread-old"]
    lines = [str(x.message) for x in w if issubclass(x.category, devmod.DeviceWarning)]
    assert len(lines) == 1 and "pthread-old" in lines[0] and "LLVM ERROR: boom" in lines[0] and "\n" not in lines[0]
    assert "skipped pthread-old" in sel.why


def test_a_first_render_never_waits_for_a_check_ranked_ahead_only_for_photons(monkeypatch):
    """Nothing checked yet: the runtime that path traces fastest is checked
    (the render waits), the one ahead of it for photon merging is checked in
    the background and taken once it has passed."""
    monkeypatch.setattr(devmod, "CPU_RUNTIME_RATES", SPLIT_RATES)
    bg = []
    checked = _machine(monkeypatch, _three(), known=(), background=bg)
    c = devmod.default_device(photons=True)
    assert c.device.name == "EPYC" and checked == ["EPYC"] and bg == ["pthread-old"]
    assert "checking pthread-old" in c.skipped[0] and "in the background" in c.skipped[0]
    _machine(monkeypatch, _three())  # the background check has passed
    assert devmod.default_device(photons=True).device.name == "pthread-old"
    _machine(monkeypatch, _three(), broken={"pthread-old"})  # or failed
    c = devmod.default_device(photons=True)
    assert c.device.name == "EPYC" and c.skipped == ("skipped pthread-old (Portable Computing Language, driver 3.0): "
                                                     "cannot render at 16 lanes: LLVM ERROR: boom",)


def test_one_background_check_at_a_time(monkeypatch):
    monkeypatch.setattr(devmod, "CPU_RUNTIME_RATES", SPLIT_RATES)
    bg = []
    two = [_dev("Portable Computing Language", "pthread-a", CPU), _dev("Portable Computing Language", "pthread-b", CPU)]
    _machine(monkeypatch, two + [_dev("Intel(R) OpenCL", "EPYC", CPU)], known={"EPYC"}, background=bg)
    c = devmod.default_device(photons=True)
    assert c.device.name == "EPYC" and bg == ["pthread-a"] and len(c.skipped) == 1
    # A candidate checked before still counts while another is checked in the background.
    _machine(monkeypatch, two + [_dev("Intel(R) OpenCL", "EPYC", CPU)], known={"EPYC", "pthread-b"}, background=bg)
    assert devmod.default_device(photons=True).device.name == "pthread-b"


def test_no_device_that_renders_is_an_error_with_the_fix(monkeypatch):
    _machine(monkeypatch, _three(), broken={"pthread-old", "EPYC"})
    with pytest.raises(devmod.DeviceError, match="no OpenCL device can render here.*intel-opencl-rt"):
        devmod.default_device()
    _machine(monkeypatch, [_three()[2]])  # only a simulator
    with pytest.raises(devmod.DeviceError, match="only simulators"):
        devmod.default_device()


def test_a_named_device_that_fails_is_an_error_never_a_switch(monkeypatch):
    _machine(monkeypatch, _three(), broken={"pthread-old"})
    with pytest.raises(devmod.DeviceError, match="pthread-old .*cannot render at 16 lanes: LLVM ERROR: boom"):
        devmod.select_devices("pthread-old")
    assert [d.name for d in devmod.select_devices("oclgrind")] == ["Oclgrind Simulator"]  # by name it is fine


def test_one_name_for_two_platforms_takes_the_one_that_renders(monkeypatch):
    new = _dev("Portable Computing Language", "pthread-new", CPU, "3.1")
    _machine(monkeypatch, _three() + [new], broken={"pthread-old"})
    assert [d.name for d in devmod.select_devices("pocl")] == ["pthread-new"]


def test_all_and_lists_leave_out_failing_devices_and_simulators(monkeypatch):
    _machine(monkeypatch, _three(), broken={"pthread-old"})
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        assert [d.name for d in devmod.select_devices("all")] == ["EPYC"]
        assert [d.name for d in devmod.select_devices("0,1")] == ["EPYC"]
    assert sum("left out pthread-old" in str(x.message) for x in w) == 1
    _machine(monkeypatch, _three(), broken={"pthread-old", "EPYC"})
    with pytest.raises(devmod.DeviceError, match="no device of '0,1' can render"):
        devmod.select_devices("0,1")


def test_the_check_renders_on_the_test_device_and_is_cached(device_spec, monkeypatch):
    """The real check (a child process) passes on the device the suite runs on, and the second time it is read back."""
    dev = devmod.select_devices(device_spec)[0]
    first = devmod.check_device(dev)
    assert first.ok, first.reason
    probe._memo.clear()
    again = devmod.check_device(dev)
    assert again.ok and again.cached and again.lanes == first.lanes


def test_a_crashing_check_fails_with_the_compilers_last_line(monkeypatch, tmp_path):
    """A compiler that aborts takes only the check's child process with it."""
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path))
    probe._memo.clear()
    crash = "import os, sys; sys.stdin.read(); print('LLVM ERROR: Cannot emit physreg copy instruction', " \
            "file=sys.stderr, flush=True); os.abort()"
    monkeypatch.setattr(probe, "_command", lambda: [sys.executable, "-c", crash])
    r = probe.check(None, "fake|identity", "fake device", 16, (0, 0))
    assert not r.ok and r.reason == "the kernel build crashed (SIGABRT): LLVM ERROR: Cannot emit physreg copy instruction"
    wrong = "import sys, json; sys.stdin.read(); print(json.dumps({'finite': True, 'mean': 0.9}))"
    monkeypatch.setattr(probe, "_command", lambda: [sys.executable, "-c", wrong])
    r = probe.check(None, "fake|identity", "fake device", 8, (0, 0))
    assert not r.ok and "wrong results" in r.reason
    probe._memo.clear()
    assert not probe.cached("fake|identity", 16).ok  # saved: the next process does not crash again


def test_a_background_check_caches_its_result(device_spec, monkeypatch, tmp_path):
    import time

    dev = devmod.select_devices(device_spec)[0]
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path))
    probe._memo.clear()
    assert devmod.check_device(dev, wait=False) is None  # unknown: started
    deadline = time.time() + 2 * probe.CHECK_SECONDS
    while time.time() < deadline and devmod.check_device(dev, wait=False) is None:
        probe._memo.clear()
        time.sleep(0.5)
    r = devmod.check_device(dev, wait=False)
    assert r is not None and r.ok and r.cached
    assert not list(tmp_path.glob("devices/*.checking"))
