"""Constants shared by the host and the kernels, each defined once here.

The kernels receive them as a generated block of ``#define``s at the top of
every stitched program (``kernel_defines()``), so host and device never
disagree and a change reaches the build cache key.
"""

from __future__ import annotations

import math

import numpy as np

# Rec. 709 luminance weights of linear RGB.
LUMA_WEIGHTS = (0.2126, 0.7152, 0.0722)
LUMA = np.array(LUMA_WEIGHTS)

# Work-group sizes when no tuned or explicit choice applies (every kernel
# checks its range, so any size is correct; these are the sizes measured best).
LOCAL_SIZE_CPU = 16
LOCAL_SIZE_GPU = 64

# Pixels (or adaptive entries) a trace_paths work-item takes per lane, when it
# has more than one lane: a lane that has finished its pixel takes the
# work-item's next one (kernels/film.h), so only the last pixels leave lanes
# idle. One pixel per lane, a launch of 8 samples per pixel (a progressive
# photon map's) kept 70% of the lanes busy on the caustics box. At most
# LANE_PIXELS: a launch too small to give every compute unit GROUPS_PER_UNIT
# work-groups so takes fewer, down to one per lane (work_item_entries).
LANE_PIXELS = 4
GROUPS_PER_UNIT = 4


def work_item_entries(lanes: int, n: int | None = None, units: int = 1, local: int = 1) -> int:
    """Pixels or list entries one trace_paths work-item takes (the launch
    record's wi_entries): lanes x LANE_PIXELS, or, for a launch over n of them
    on `units` compute units in work-groups of `local`, the most (a multiple
    of the lanes, at least one per lane) that still leaves GROUPS_PER_UNIT
    work-groups per unit. A work-group runs on one CPU thread, so with four
    pixels per lane a 32x32 image was one work-group of 16 lanes' items: one
    core busy. Images are the same bits whatever a work-item takes."""
    if lanes <= 1:
        return 1
    most = lanes * LANE_PIXELS
    if n is None:
        return most
    fit = n // max(1, GROUPS_PER_UNIT * units * local)
    return max(lanes, min(most, fit // lanes * lanes))

# Ray-origin offsets (kernels/scene.h offset_distance): OFFSET_REL times the
# magnitudes the hit point's rounding error follows (the point's, the ray
# origin's, the primitive's position and size), never the scene's extent,
# plus an absolute floor OFFSET_FLOOR (2^20 of the smallest normal numbers)
# for points at the origin; per precision.
OFFSET_REL = {"float": 2e-6, "double": 1e-12}
OFFSET_FLOOR = {"float": float(np.finfo(np.float32).tiny) * 2.0 ** 20,
                "double": float(np.finfo(np.float64).tiny) * 2.0 ** 20}


# Mitsuba's gaussian pixel filter, exp(-x^2 / (2 stddev^2)) minus its value
# at its radius r = 4 stddev, has one shape in units of r: g(s) = exp(-8 s^2)
# - exp(-8) on [-1, 1]. The kernels sample it (kernels/camera.h) through its
# inverse CDF tabulated at GAUSSIAN_TABLE_BINS + 1 equally likely nodes of
# its half [0, 1] (node k: the s where the half's CDF is k / BINS), the
# density within a bin linear between g at its nodes, scaled to the bin's
# 1 / BINS of the mass: within 2e-5 of g's peak everywhere (tests/test_camera.py).
GAUSSIAN_TABLE_BINS = 256
GAUSSIAN_HALF_MASS = float(np.sqrt(np.pi / 32) * math.erf(np.sqrt(8.0)) - np.exp(-8.0))  # g over [0, 1]


def gaussian_half_cdf(s):
    """The CDF of g over [0, 1] (exact, double)."""
    s = np.asarray(s, dtype=np.float64)
    erf = np.vectorize(math.erf)
    return (math.sqrt(math.pi / 32) * erf(math.sqrt(8.0) * s) - math.exp(-8.0) * s) / GAUSSIAN_HALF_MASS


def gaussian_table_cdf(k):
    """The half CDF at node k (of 0..GAUSSIAN_TABLE_BINS)."""
    return 1.0 - (1.0 - np.asarray(k, dtype=np.float64) / GAUSSIAN_TABLE_BINS) ** 2


def gaussian_filter_table() -> np.ndarray:
    """The nodes s_k (k = 0..GAUSSIAN_TABLE_BINS) where g's half CDF is gaussian_table_cdf(k), float64."""
    q = gaussian_table_cdf(np.arange(GAUSSIAN_TABLE_BINS + 1))
    lo, hi = np.zeros_like(q), np.ones_like(q)
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        below = gaussian_half_cdf(mid) < q
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    s = 0.5 * (lo + hi)
    s[0], s[-1] = 0.0, 1.0
    return s


DOT_ROWS = 4096  # rows a product takes at a time (dot_rows)


def dot_rows(a, w) -> np.ndarray:
    """a @ w (w a vector over a's last axis), DOT_ROWS rows at a time: the
    same numbers as one product of a's rows, but each is small enough that the BLAS
    library runs it on the calling thread. One large product wakes its
    worker threads, which then spin for about 0.1 s of CPU after every
    render (as measured with OpenBLAS), competing with the OpenCL runtime
    for the cores."""
    a = np.asarray(a)
    # Always as rows: numpy's batched product of a 3-d array rounds some rows otherwise (numpy 2.4).
    flat = a.reshape(-1, a.shape[-1])
    out = flat @ w if len(flat) <= DOT_ROWS else \
        np.concatenate([flat[i:i + DOT_ROWS] @ w for i in range(0, len(flat), DOT_ROWS)])
    return out.reshape(a.shape[:-1])


def luminance(rgb) -> np.ndarray:
    """Luminance of an array of linear RGB triples (last axis)."""
    return dot_rows(np.asarray(rgb, dtype=np.float64), LUMA)


def kernel_defines() -> str:
    """The constants the kernels use, as OpenCL C #defines (double literals:
    the kernels convert them to their real type)."""
    r, g, b = LUMA_WEIGHTS
    lines = [
        f"#define CLPT_LUMA_R {r!r}",
        f"#define CLPT_LUMA_G {g!r}",
        f"#define CLPT_LUMA_B {b!r}",
        f"#define CLPT_OFFSET_REL_FLOAT {OFFSET_REL['float']!r}",
        f"#define CLPT_OFFSET_REL_DOUBLE {OFFSET_REL['double']!r}",
        f"#define CLPT_GAUSSIAN_TABLE_BINS {GAUSSIAN_TABLE_BINS}",
        f"#define CLPT_GAUSSIAN_HALF_MASS {GAUSSIAN_HALF_MASS!r}",
    ]
    lines.append("#define CLPT_GAUSSIAN_TABLE_S {" + ", ".join(repr(float(x)) for x in gaussian_filter_table())
                 + "}")
    return "\n".join(lines) + "\n"
