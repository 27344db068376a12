"""What a render has so far: the update handed to Renderer.render(on_update=...).

Renderer.render(on_update=f, update_interval=s) calls f(update) between
passes, at most every s seconds, and once more at the end with
update.final True. Viewers (clpt.tev, clpt.notebook) are built on it.

Reading the image costs the render only a copy of the device's sums, queued
between two passes: the per-pixel means, counts and variances are worked out
from that copy the first time a field is read, in whichever thread reads it.
A viewer that does its work in a thread of its own therefore leaves the
passes alone.
"""

from __future__ import annotations

import threading

import numpy as np

from .adaptive import relative_error
from .constants import LUMA, dot_rows


class RenderUpdate:
    """The render so far.

    image: H x W x 3 float32, the mean of the samples so far (linear RGB);
    sample_count: H x W samples per pixel; lum_var: H x W variance of one
    sample's luminance; aux: the feature images (normal, albedo, depth,
    emission) when the Renderer has them, else None; filtered: the filtered
    image, only in the final update of a render with a filter; spp_done:
    the average samples per pixel so far; spp_total: what was asked for;
    elapsed: seconds since the render started; stats: a copy of the
    RenderStats so far; final: True for the last update of a render.
    """

    def __init__(self, *, spp_done: float, spp_total: int, elapsed: float, stats, final: bool = False,
                 filtered: np.ndarray | None = None, load=None, load_aux=None, image=None, sample_count=None,
                 lum_var=None, aux=None):
        if load is None and image is None:
            raise TypeError("RenderUpdate needs the image or a load() that reads it")
        self.spp_done, self.spp_total, self.elapsed = spp_done, spp_total, elapsed
        self.stats, self.final, self.filtered = stats, final, filtered
        self._load, self._load_aux = load, load_aux
        self._fields = None if load is not None else (image, sample_count, lum_var)
        self._aux, self._aux_read = aux, load_aux is None
        self._lock = threading.Lock()

    def _get(self, i):
        with self._lock:
            if self._fields is None:
                self._fields = self._load()
                self._load = None
            return self._fields[i]

    @property
    def image(self) -> np.ndarray:
        return self._get(0)

    @property
    def sample_count(self) -> np.ndarray:
        return self._get(1)

    @property
    def lum_var(self) -> np.ndarray:
        return self._get(2)

    @property
    def aux(self) -> dict | None:
        with self._lock:
            if not self._aux_read:
                self._aux, self._aux_read, self._load_aux = self._load_aux(), True, None
            return self._aux

    @property
    def shape(self) -> tuple:
        """(height, width)."""
        return self.image.shape[:2]

    def relative_error(self) -> np.ndarray:
        """H x W standard error of each pixel's mean luminance over the mean (as adaptive sampling measures it)."""
        return relative_error(dot_rows(self.image, LUMA.astype(np.float32)), self.lum_var, self.sample_count).astype(np.float32)

    def display_image(self) -> np.ndarray:
        """The image a viewer should show: the filtered one when there is one."""
        return self.filtered if self.filtered is not None else self.image

    def __repr__(self):
        return (f"RenderUpdate({self.spp_done:g}/{self.spp_total} spp, {self.elapsed:.2f} s"
                f"{', final' if self.final else ''})")
