"""The named dimensions (kernels/sampler.h) are the numbers the integrator
has always drawn: each decision reads the rng.h group and component the
table in sampler.h gives it, so images rendered before the table existed
are rendered again to the bit."""

import numpy as np
import pyopencl as cl
import pytest

from test_rng import draw

pytestmark = pytest.mark.portability

PHOTON_SEED_SALT = 0x5BD1E995


@pytest.mark.parametrize("lanes", [1, 8])
def test_named_dimensions_are_the_groups_of_the_table(probes, lanes):
    probe = probes(lanes)
    rng = np.random.default_rng(3)
    n = 64
    pixel = rng.integers(0, 1 << 20, n).astype(np.uint32)
    sample = rng.integers(0, 1 << 16, n).astype(np.uint32)
    depth = rng.integers(0, 40, n).astype(np.uint32)
    seed, bounce = 77, 5
    ctx, q, mf = probe.dctx.context, probe.dctx.queue, cl.mem_flags
    ins = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a) for a in (pixel, sample, depth)]
    out = np.zeros(18 * n, dtype=probe.real)
    ob = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    cl.Kernel(probe.program, "probe_sampler")(q, (n // lanes,), (1,), np.uint32(seed), np.uint32(bounce), *ins, ob)
    cl.enqueue_copy(q, out, ob)
    q.finish()
    got = out.reshape(n // lanes, 18, lanes).transpose(0, 2, 1).reshape(n, 18).T
    z = np.zeros(n, dtype=np.uint32)
    cam = draw(probe, seed, pixel, sample, z)
    vertex = draw(probe, seed, pixel, sample, depth * 2 + 1)
    bsdf = draw(probe, seed, pixel, sample, depth * 2 + 2)
    pseed = seed ^ PHOTON_SEED_SALT
    emit0, emit1 = draw(probe, pseed, pixel, z, z), draw(probe, pseed, pixel, z, z + 1)
    bounce_g = draw(probe, pseed, pixel, z, z + 2 + bounce)
    want = [cam[0], cam[1], vertex[0], vertex[1], vertex[2], vertex[3], bsdf[0], bsdf[1], bsdf[2], bsdf[3],
            emit0[0], emit0[1], emit0[2], emit0[3], emit1[0], emit1[1], bounce_g[0], bounce_g[1]]
    for k, w in enumerate(want):
        assert np.array_equal(got[k], w), k
