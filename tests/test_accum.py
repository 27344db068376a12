"""Per-pixel sums (kernels/film.h) stay accurate over 10^6 samples: in
double, and in Kahan-compensated float on devices without fp64."""

import numpy as np
import pyopencl as cl
import pytest

from clpt.constants import DOT_ROWS, LUMA, dot_rows


@pytest.mark.parametrize("accum_double", [True, False])
def test_a_million_samples_sum_exactly_enough(probes, accum_double):
    n = 1_000_000
    probe = probes(8, False, accum_double)
    x = np.array([0.1, 1 / 3, 1e-6, 7.25, 123.456, 1e4, 0.0, 2.0 ** -20], dtype=np.float32)
    ctx, q = probe.dctx.context, probe.dctx.queue
    xb = cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=x)
    ps, pq = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 8 * 32), cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 8 * 8)
    k = cl.Kernel(probe.program, "probe_accumulate")
    k(q, (1,), None, xb, np.uint32(n), ps, pq)
    if accum_double:
        s, sq = np.empty((8, 4)), np.empty(8)
    else:
        s, sq = np.empty((8, 8), np.float32), np.empty((8, 2), np.float32)
    cl.enqueue_copy(q, s, ps)
    cl.enqueue_copy(q, sq, pq)
    q.finish()
    if not accum_double:  # sum minus compensation, as the host reads them
        s = s[:, :4].astype(np.float64) - s[:, 4:].astype(np.float64)
        sq = sq[:, 0].astype(np.float64) - sq[:, 1].astype(np.float64)
    exact = x.astype(np.float64) * n
    exact_sq = (x.astype(np.float64) ** 2).astype(np.float32).astype(np.float64) * n
    tol = 1e-12 if accum_double else 2e-7  # a naive float sum is off by ~1e-3 here
    assert np.allclose(s[:, 0], exact, rtol=tol, atol=0)
    assert (s[:, 3] == n).all()
    assert np.allclose(sq, exact_sq, rtol=tol, atol=0)
    naive = np.float32(0)
    for _ in range(20000):  # the problem being solved, at 1/50 of the count
        naive += np.float32(0.1)
    assert abs(naive - 2000.0) / 2000.0 > 10 * 2e-7


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("rows", [1, 4095, 4096, 4097, 3 * 4096 + 5])
def test_dot_rows_gives_one_products_numbers(dtype, rows):
    """Luminance products go 4096 rows at a time (so the BLAS library keeps
    to the calling thread); each row's number must be what one product
    of the rows gives, bit for bit, whatever the shape (numpy's batched
    product of a 3-d array rounds some rows otherwise)."""
    assert DOT_ROWS == 4096
    rng = np.random.default_rng(rows)
    a = (rng.random((rows, 3)) * np.exp(rng.normal(0.0, 5.0, (rows, 1)))).astype(dtype)
    w = LUMA.astype(dtype)
    assert np.array_equal(dot_rows(a, w), a @ w)
    img = a[: rows - rows % 7].reshape(7, -1, 3) if rows >= 7 else a.reshape(1, rows, 3)
    got = dot_rows(img, w)
    assert got.shape == img.shape[:-1]
    assert np.array_equal(got, (img.reshape(-1, 3) @ w).reshape(img.shape[:-1]))
