"""Writes fluted.ply (tests/data/smooth_bumpy.xml's mesh): a flat 2 x 2 grid
in the plane y = 0, facing +y, 4 x 12 cells, whose vertex normals tilt
along z as flutes would, up to 60 degrees from the geometric normal
(n = normalize(0, 1, tan(60) sin(2 pi z / 0.5 + 0.5))): the shading normals
deviate strongly, so scattered rays often cross the geometric plane and
grazing views see the shading normal from behind.

    python tests/data/smooth_bumpy/make_fluted.py
"""

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent))
from meshgen import write_ply  # noqa: E402


def fluted(nx=4, nz=12, size=2.0, period=0.5, tilt_deg=60.0):
    x = np.linspace(-size / 2, size / 2, nx + 1)
    z = np.linspace(-size / 2, size / 2, nz + 1)
    gx, gz = np.meshgrid(x, z, indexing="ij")
    v = np.stack([gx.ravel(), np.zeros(gx.size), gz.ravel()], axis=1)
    n = np.stack([np.zeros(gx.size), np.ones(gx.size),
                  np.tan(np.radians(tilt_deg)) * np.sin(2 * np.pi * gz.ravel() / period + 0.5)], axis=1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    idx = lambda i, j: i * (nz + 1) + j  # noqa: E731
    tris = []
    for i in range(nx):
        for j in range(nz):  # counter-clockwise seen from +y
            tris += [(idx(i, j), idx(i, j + 1), idx(i + 1, j + 1)), (idx(i, j), idx(i + 1, j + 1), idx(i + 1, j))]
    return v, np.array(tris, dtype=np.int64), n


if __name__ == "__main__":
    v, t, n = fluted()
    write_ply(HERE / "fluted.ply", v, t, n)
