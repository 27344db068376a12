"""Environment maps the tests generate, and the one they store.

``sky_map`` is a small equirectangular HDR sky (Mitsuba's orientation: row 0
at the zenith, +y up): a blue gradient above the horizon, a brown ground
below, and a sun of a few texels; ``sun_map`` a map with one bright spot on a
dim random background, for sampling tests. ``python tests/envmaps.py`` writes
tests/data/env_sky.exr, which tests/data/env_spheres.xml (and its stored
Mitsuba 3 reference, tests/mitsuba_measure.py --reference) reads.
"""

from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parent / "data"


def sky_map(w: int = 64, h: int = 32) -> np.ndarray:
    theta = np.pi * np.arange(h) / (h - 1)
    up = np.cos(theta)[:, None, None] * np.ones((1, w, 1))
    sky = np.array([0.35, 0.55, 1.0]) * (0.4 + 0.6 * np.clip(up, 0, 1))
    ground = np.array([0.25, 0.18, 0.12]) * np.ones_like(up)
    img = np.where(up > 0, sky, ground)
    # A sun 45 degrees up, towards phi = 2 pi (x + 1/2) / w at x = w / 8.
    y, x = int(round((h - 1) / 4)), w // 8
    img[y:y + 2, x:x + 2] = (60.0, 55.0, 45.0)
    return img.astype(np.float32)


def sun_map(w: int = 48, h: int = 25, seed: int = 5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = 0.05 + 0.1 * rng.random((h, w, 3))
    img[6, 30] = (400.0, 380.0, 300.0)
    img[7, 30:32] = 80.0
    return img.astype(np.float32)


if __name__ == "__main__":
    import clpt

    clpt.save_image(DATA / "env_sky.exr", sky_map())
    print(DATA / "env_sky.exr")
