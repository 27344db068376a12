"""Shared fixtures: one OpenCL device per test session (the path-tracing
default, pinned; set CLPT_TEST_DEVICE to a `--device` selection to test another), an isolated
kernel build cache, and probe programs that expose kernel library functions."""

import atexit
import faulthandler
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

# An isolated build cache: tests must not depend on (or fill) the user's.
# One made here is removed when the session's process ends (a session's
# builds take about 120 MB; left behind, every run of the suite kept them).
if "CLPT_CACHE_DIR" not in os.environ:
    os.environ["CLPT_CACHE_DIR"] = tempfile.mkdtemp(prefix="clpt-test-cache-")
    atexit.register(shutil.rmtree, os.environ["CLPT_CACHE_DIR"], ignore_errors=True)
# Defaults from device queries only: a runtime whose best lane width is
# measured (clpt/tune.py) would otherwise measure for every new kind of scene.
# tests/test_tune.py measures on purpose.
os.environ.setdefault("CLPT_TUNE", "query")

import pyopencl as cl  # noqa: E402

from clpt.device import DeviceContext, select_devices  # noqa: E402
from clpt.features import Features  # noqa: E402
from clpt import program  # noqa: E402

TESTS = Path(__file__).resolve().parent
sys.path.insert(0, str(TESTS))

# A test that hangs (a render whose samples ran away, say) ends the run with
# every thread's traceback on the real stderr, instead of using up CI's time
# in silence: no test here takes more than a minute or two.
HANG_SECONDS = float(os.environ.get("CLPT_TEST_HANG_SECONDS", "900"))
_stderr_copy = None


def pytest_configure(config):
    global _stderr_copy
    if HANG_SECONDS > 0 and _stderr_copy is None:
        _stderr_copy = os.dup(sys.stderr.fileno())  # (output capture is suspended here)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if _stderr_copy is not None:
        os.write(_stderr_copy, b"")  # (fails now, not at the deadline, if the copy is gone)
        faulthandler.dump_traceback_later(HANG_SECONDS, exit=True, file=_stderr_copy)
    try:
        yield
    finally:
        if _stderr_copy is not None:
            faulthandler.cancel_dump_traceback_later()


@pytest.fixture(scope="session")
def device_spec():
    """CLPT_TEST_DEVICE, else the default device for path tracing, pinned by
    its index. Left unnamed, renders with photons could move to another
    runtime once its background check passed (clpt/device.py default_device),
    and tests that compare two renders would compare two devices."""
    spec = os.environ.get("CLPT_TEST_DEVICE")
    if spec:
        return spec
    from clpt.device import _all_devices, default_device
    found = _all_devices()
    chosen = default_device(photons=False, found=found).device
    return str(next(i for i, (_, _, _, d) in enumerate(found) if d == chosen))


@pytest.fixture(scope="session")
def dctx(device_spec):
    return DeviceContext(select_devices(device_spec)[0])


class Probe:
    """The probe program for one lane width and precision."""

    def __init__(self, dctx, lanes, double, accum_double=True, bvh_walk="hybrid"):
        self.dctx = dctx
        self.lanes = lanes
        self.real = np.float64 if double else np.float32
        feats = Features(lanes=lanes, double=double, accum_double=accum_double, mode="generic", bvh_walk=bvh_walk)
        from clpt.layout import launch_records
        fields = " ".join(f"PROBE_SIZE({r.name})" + "".join(f" PROBE_FIELD({r.name}, {f})" for f, _ in r.fields)
                          for r in launch_records())
        src = program.stitch(["photons.cl", "grid.cl", "filter.cl", str(TESTS / "kernels" / "lane_io.cl"),
                              str(TESTS / "kernels" / "probes.cl")],
                             {"<probe record fields>": f"#define PROBE_RECORD_FIELDS {fields}\n"},
                             after=program.LIBRARY_FILES[-1])
        self.program, _ = program.build(dctx, src, feats.options())
        self.kernels = {}

    def run(self, name, inputs, n_out, scalars=(), scalars_after=(), out_dtype=None, prefix=()):
        """Launch probe `name` over len(inputs[0]) elements (padded to the lane
        width); returns n_out output arrays."""
        ctx, q = self.dctx.context, self.dctx.queue
        n = len(inputs[0]) if inputs else self.lanes
        pad = -(-n // self.lanes) * self.lanes
        mf = cl.mem_flags
        bufs = []
        for a in inputs:
            a = np.asarray(a)
            dt = np.uint32 if a.dtype.kind in "ui" else self.real
            h = np.zeros(pad, dtype=dt)
            h[:n] = a
            bufs.append(cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=h))
        outs = [np.zeros(pad, dtype=out_dtype or self.real) for _ in range(n_out)]
        obufs = [cl.Buffer(ctx, mf.WRITE_ONLY, o.nbytes) for o in outs]
        k = self.kernels.get(name) or self.kernels.setdefault(name, cl.Kernel(self.program, name))
        k.set_args(*prefix, *scalars, *bufs, *scalars_after, *obufs)
        # A fixed work-group size: PoCL compiles a kernel once per local size,
        # and lets it choose by the global size otherwise (a compile per probe size).
        cl.enqueue_nd_range_kernel(q, k, (pad // self.lanes,), (1,))
        for o, b in zip(outs, obufs):
            cl.enqueue_copy(q, o, b)
        q.finish()
        return [o[:n] for o in outs]

    def scene_args(self, packed):
        """The records and the SceneInfo (no offset floor) the probes take."""
        from clpt.engine.launch import scene_info
        recs = np.ascontiguousarray(packed.records, dtype=self.real)
        mf = cl.mem_flags
        buf = cl.Buffer(self.dctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=recs)
        info = np.ascontiguousarray(scene_info(packed.counts, 0.0, self.real == np.float64))
        return (buf, cl.Buffer(self.dctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=info))


@pytest.fixture(scope="session")
def probes(dctx):
    cache = {}

    def get(lanes=1, double=False, accum_double=True, bvh_walk="hybrid"):
        key = (lanes, double, accum_double, bvh_walk)
        if key not in cache:
            cache[key] = Probe(dctx, lanes, double, accum_double, bvh_walk)
        return cache[key]

    return get
