"""Device selection by name: exact names and platform short names first, a
substring only when it picks out one device, else a refusal naming the matches."""

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
