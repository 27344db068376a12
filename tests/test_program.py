"""Kernel builds (clpt/program.py): PoCL's one compile per kernel, and
overlapping PoCL builds that go to child processes."""

import os
import threading

import numpy as np
import pyopencl as cl
import pytest

from clpt import program
from clpt.device import DeviceContext, select_devices

SRC = """
__kernel void scale(__global float *a, float k) { size_t i = get_global_id(0); a[i] = sqrt(a[i]) * k + 0.1f; }
"""


@pytest.fixture
def dctx(device_spec):
    return DeviceContext(select_devices(device_spec)[0])


def _run(dctx, prg):
    a = np.linspace(0, 3, 64, dtype=np.float32)
    buf = cl.Buffer(dctx.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=a)
    prg.scale(dctx.queue, (64,), (16,), buf, np.float32(1.7))
    cl.enqueue_copy(dctx.queue, a, buf)
    return a


def test_pocl_compiles_each_kernel_once_unless_told_otherwise(monkeypatch):
    pocl = type("D", (), {"is_pocl": True})()
    other = type("D", (), {"is_pocl": False})()
    monkeypatch.delenv("POCL_WORK_GROUP_SPECIALIZATION", raising=False)
    program.pocl_defaults(other)
    assert "POCL_WORK_GROUP_SPECIALIZATION" not in program.os.environ
    program.pocl_defaults(pocl)
    assert program.os.environ["POCL_WORK_GROUP_SPECIALIZATION"] == "0"
    monkeypatch.setenv("POCL_WORK_GROUP_SPECIALIZATION", "1")  # the user's choice wins
    program.pocl_defaults(pocl)
    assert program.os.environ["POCL_WORK_GROUP_SPECIALIZATION"] == "1"


def test_of_overlapping_builds_the_largest_stays(monkeypatch):
    monkeypatch.setattr(program, "OVERLAP_WINDOW", 0)
    big, small, twin = [100, 1], [50, 2], [100, 3]
    monkeypatch.setattr(program, "_overlapping", [big, small, twin])
    assert program._elsewhere(small) and program._elsewhere(twin) and not program._elsewhere(big)
    monkeypatch.setattr(program, "_overlapping", [small])
    assert not program._elsewhere(small)  # alone: built here


def test_a_child_build_gives_the_same_program(dctx, tmp_path):
    if not dctx.is_pocl:
        pytest.skip("child builds are for PoCL")
    here = cl.Program(dctx.context, SRC).build(options=["-w"], cache_dir=False)
    there = program._built_elsewhere(dctx, SRC, ["-w"], tmp_path / "p.bin")
    assert there is not None and (tmp_path / "p.bin").is_file()
    assert np.array_equal(_run(dctx, here), _run(dctx, there))
    assert not program._child_build(dctx, SRC + "syntax error", ["-w"], tmp_path / "bad.bin")


def test_concurrent_builds_split_and_agree(dctx, tmp_path, monkeypatch):
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CLPT_BUILD_PROCESSES", "1")
    big = SRC + "\n// " + "x" * 1000 + "\n"
    small = SRC + "\n// small\n"
    out, children = {}, []
    real_child = program._child_build

    def child(d, source, options, path):
        children.append(len(source))
        return real_child(d, source, options, path)

    monkeypatch.setattr(program, "_child_build", child)

    def one(name, src):
        out[name] = program.build(dctx, src, [])

    threads = [threading.Thread(target=one, args=(n, s)) for n, s in (("big", big), ("small", small))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(list(tmp_path.glob("kernels/*.bin"))) == 2  # each cached, wherever it was built
    if dctx.is_pocl:
        assert children == [len(small)]  # the smaller went to a child, the larger stayed
    else:
        assert children == []
    assert np.array_equal(_run(dctx, out["big"][0]), _run(dctx, out["small"][0]))
    again = program.build(dctx, small, [])
    assert again[1].cache_hit
    with pytest.raises(program.KernelBuildError):  # a child's failure ends in the usual error
        threads = [threading.Thread(target=one, args=("big", big + " ")),]
        threads[0].start()
        program.build(dctx, small + "syntax error", [])
    threads[0].join()


def _fake(platform, device_type):
    dev = type("Dev", (), {"type": device_type})()
    return type("D", (), {"platform": platform, "device": dev,
                          "is_pocl": "portable computing language" in platform.lower()})()


def test_builds_overlap_only_where_the_runtime_takes_it():
    T = cl.device_type
    assert program.builds_at_once(_fake("Portable Computing Language", T.CPU))
    assert program.builds_at_once(_fake("Intel(R) OpenCL", T.CPU))
    # Oclgrind reports every device type at once; it segfaults on overlapping builds.
    assert not program.builds_at_once(_fake("Oclgrind", T.CPU | T.GPU | T.ACCELERATOR | T.DEFAULT))
    assert not program.builds_at_once(_fake("Intel(R) OpenCL Graphics", T.GPU))
    assert not program.builds_at_once(_fake("Intel(R) FPGA Emulation Platform for OpenCL(TM)", T.ACCELERATOR))
    assert not program.builds_at_once(_fake("NVIDIA CUDA", T.GPU))


class _Overlap:
    """Wraps cl.Program.build: counts the builds running at once (each held
    a moment, so that builds started together surely overlap if allowed to)
    and the threads they ran on."""

    def __init__(self, monkeypatch):
        self.lock, self.now, self.most, self.threads = threading.Lock(), 0, 0, set()
        real = cl.Program.build

        def build(prg, *args, **kwargs):
            with self.lock:
                self.now += 1
                self.most = max(self.most, self.now)
                self.threads.add(threading.get_ident())
            try:
                threading.Event().wait(0.3)
                return real(prg, *args, **kwargs)
            finally:
                with self.lock:
                    self.now -= 1

        monkeypatch.setattr(cl.Program, "build", build)


@pytest.mark.parametrize("at_once", [False, True])
def test_builds_from_threads_overlap_only_where_allowed(dctx, monkeypatch, at_once):
    monkeypatch.setenv("CLPT_BUILD_PROCESSES", "0")  # PoCL too builds in this process
    monkeypatch.setattr(program, "builds_at_once", lambda d: at_once)
    seen = _Overlap(monkeypatch)
    out = {}
    threads = [threading.Thread(target=lambda n=n: out.setdefault(n, program.build(dctx, SRC + f"// {n}\n", [],
                                                                                    use_cache=False)))
               for n in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(out) == 3 and seen.most == (3 if at_once else 1)
    assert np.array_equal(_run(dctx, out[0][0]), _run(dctx, out[2][0]))


def test_a_caustic_scene_builds_its_programs_in_turn_where_builds_cannot_overlap(device_spec, monkeypatch):
    import clpt
    monkeypatch.setattr(program, "builds_at_once", lambda d: False)
    seen = _Overlap(monkeypatch)
    r = clpt.Renderer("cornell_box_caustics", device=device_spec, use_cache=False, lanes=4)
    assert r.states[0].pmap is not None  # two programs: the path pass and the photon pass
    assert seen.most == 1 and seen.threads == {threading.get_ident()}


def test_the_cache_keeps_the_recently_used_binaries_within_its_bound(dctx, tmp_path, monkeypatch):
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path))
    srcs = [SRC + f"\n// variant {i}\n" for i in range(3)]
    program.build(dctx, srcs[0], [])
    bins = sorted(tmp_path.glob("kernels/*.bin"))
    assert len(bins) == 1
    size = bins[0].stat().st_size
    # Room for two binaries: the third build removes the least recently used.
    monkeypatch.setenv("CLPT_CACHE_MB", str(2.5 * size / 2 ** 20))
    program.build(dctx, srcs[1], [])
    first, second = bins[0], (set(tmp_path.glob("kernels/*.bin")) - {bins[0]}).pop()
    os.utime(first, (1e9, 1e9))
    os.utime(second, (1e9 + 1, 1e9 + 1))  # (used after the first)
    assert program.build(dctx, srcs[0], [])[1].cache_hit  # a hit renews the first: now the second is oldest
    assert first.stat().st_mtime > 1e9 + 1
    program.build(dctx, srcs[2], [])
    left = set(tmp_path.glob("kernels/*.bin"))
    assert first in left and second not in left and len(left) == 2
    assert program.build(dctx, srcs[0], [])[1].cache_hit
    assert not program.build(dctx, srcs[1], [])[1].cache_hit  # removed, so built again
    # The binary just written always stays, even with no room at all.
    monkeypatch.setenv("CLPT_CACHE_MB", "0")
    program.build(dctx, srcs[2] + " ", [])
    assert len(list(tmp_path.glob("kernels/*.bin"))) == 1


@pytest.mark.parametrize("bad", ["lots", "-1", "nan", "inf"])
def test_a_bad_cache_bound_is_one_line_before_any_build(dctx, tmp_path, monkeypatch, bad):
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CLPT_CACHE_MB", bad)
    with pytest.raises(program.SettingsError, match="CLPT_CACHE_MB") as e:
        program.build(dctx, SRC, [])
    assert "\n" not in str(e.value)
    assert not list(tmp_path.glob("kernels/*"))
    assert program.build(dctx, SRC, [], use_cache=False)[0] is not None  # no cache: no bound to read
