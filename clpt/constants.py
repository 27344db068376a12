"""Constants shared by the host and the kernels, each defined once here.

The kernels receive them as a generated block of ``#define``s at the top of
every stitched program (``kernel_defines()``), so host and device never
disagree and a change reaches the build cache key.
"""

from __future__ import annotations

import numpy as np

# Rec. 709 luminance weights of linear RGB.
LUMA_WEIGHTS = (0.2126, 0.7152, 0.0722)
LUMA = np.array(LUMA_WEIGHTS)

# Work-group sizes when no tuned or explicit choice applies (every kernel
# checks its range, so any size is correct; these are the sizes measured best).
LOCAL_SIZE_CPU = 16
LOCAL_SIZE_GPU = 64

# Ray-origin offsets (kernels/scene.h offset_distance): OFFSET_REL times the
# magnitudes the hit point's rounding error follows (the point's, the ray
# origin's, the primitive's position and size), never the scene's extent,
# plus an absolute floor OFFSET_FLOOR (2^20 of the smallest normal numbers)
# for points at the origin; per precision.
OFFSET_REL = {"float": 2e-6, "double": 1e-12}
OFFSET_FLOOR = {"float": float(np.finfo(np.float32).tiny) * 2.0 ** 20,
                "double": float(np.finfo(np.float64).tiny) * 2.0 ** 20}


def luminance(rgb) -> np.ndarray:
    """Luminance of an array of linear RGB triples (last axis)."""
    return np.asarray(rgb, dtype=np.float64) @ LUMA


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
    ]
    return "\n".join(lines) + "\n"
