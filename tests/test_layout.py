"""The record layout is defined once (clpt/layout.py): the numpy dtypes the
host packs with and the C structs the kernels get agree, on the device."""

import numpy as np
import pyopencl as cl
import pytest

from clpt import layout, program
from clpt.layout import SCENE_RECORDS, Record


@pytest.mark.parametrize("double", [False, True])
def test_records_match_the_device(probes, double):
    probe = probes(lanes=1, double=double)
    n = sum(1 + len(r.fields) for r in SCENE_RECORDS)
    out = np.zeros(n + 1, dtype=np.uint32)
    ctx, q = probe.dctx.context, probe.dctx.queue
    buf = cl.Buffer(ctx, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=out)
    cl.Kernel(probe.program, "probe_record_layout")(q, (1,), None, buf)
    cl.enqueue_copy(q, out, buf)
    q.finish()
    assert out[n] == 0  # exactly n values written
    expect = []
    for r in SCENE_RECORDS:
        dt = r.dtype(double)
        expect.append(dt.itemsize)
        expect += [dt.fields[f][1] for f, _ in r.fields]
    np.testing.assert_array_equal(out[:n], expect)


def test_dtype_follows_opencl_alignment():
    r = Record("Mixed", "MIXED", (("a", "uint"), ("b", "float4"), ("c", "real"), ("d", "real3"), ("e", "int")))
    dt = r.dtype(double=True)
    assert r.offsets(double=True) == {"a": 0, "b": 16, "c": 32, "d": 64, "e": 96}
    assert dt.itemsize == 128  # aligned to its widest member (double3: 32 bytes)
    assert r.offsets(double=False) == {"a": 0, "b": 16, "c": 32, "d": 48, "e": 64}
    assert r.size(double=False) == 80
    with pytest.raises(ValueError, match="unsupported field type"):
        Record("Bad", "BAD", (("x", "real5"),)).dtype()


def test_generated_c_is_in_every_build():
    src = program.stitch(["trace.cl"])
    assert "typedef struct {\n    real4 lo_x_a;" in src and "#define PLANAR_STRIDE 4" in src
    assert src.index("<clpt/layout.py>") < src.index('"kernels/scene.h"')
    assert layout.PLANAR.stride == 4 and layout.BVH_NODE.stride == 16 and layout.BVH_LEAF.stride == 16
    assert f"#define BVHL_WIDTH {layout.BVH_LEAF_WIDTH}" in src
