"""Packing time and peak host memory of a large environment map (the README's 8192x4096 figures).

    python tests/bench_envmap_memory.py [W H] [DEVICE]

A generated sky (a vertical gradient with noise and an 8x8-texel sun) over
a sphere on a plane; 32x32 pixels, 16 spp.
"""
import resource
import sys
import time

import numpy as np

import clpt
from clpt.scene import Scene, Camera, Quad, Sphere, Material, EnvironmentLight
W, H = (int(sys.argv[1]), int(sys.argv[2])) if len(sys.argv) > 2 else (8192, 4096)
DEVICE = sys.argv[3] if len(sys.argv) > 3 else None
rng = np.random.default_rng(1)
y = np.linspace(0, 1, H, dtype=np.float32)[:, None, None]
img = (0.3 + 0.7 * y + 0.05 * rng.random((H, W, 3), dtype=np.float32)).astype(np.float32)
img[H // 5:H // 5 + 8, W // 3:W // 3 + 8] = 5e3  # a sun
cam = Camera(origin=(0, 2.2, 2.2), target=(0, 0, 0), up=(0, 1, 0), fov=45, width=32, height=32)
floor = Quad(corner=(-2, 0, 2), edge_u=(4, 0, 0), edge_v=(0, 0, -4), material=Material(kd=(0.6, 0.6, 0.6)))
ball = Sphere(center=(0, 0.5, 0), radius=0.45, material=Material(kd=(0.5, 0.5, 0.5)))
t = time.perf_counter()
scene = Scene(camera=cam, shapes=[floor, ball, EnvironmentLight(image=img)])
del img
r = clpt.Renderer(scene, device=DEVICE)
t1 = time.perf_counter()
res = r.render(16, seed=1)
t2 = time.perf_counter()
print(f"{W}x{H} on {DEVICE}: scene and Renderer (packing, build) {t1 - t:.1f} s, render (16 spp) {t2 - t1:.1f} s, "
      f"peak host RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} GiB, mean {float(res.image.mean()):.4g}, "
      f"finite {bool(np.isfinite(res.image).all())}")
