"""The kernels' arguments: launch records and buffers, put together in one place.

Everything a launch passes by value is one record of clpt/layout.py
(TraceLaunch, PhotonLaunch: numpy structured arrays filled by field name),
uploaded into a small constant buffer the kernel reads through a
``__constant`` pointer; the rest of a kernel's arguments are buffers, in the
order TRACE_ARGS (+ AUX_ARGS, + PHOTON_ARGS) and PHOTON_PASS_ARGS give them
(kernels/trace.cl, kernels/photons.cl; a test checks them against the
source), which the passes' argument records (passes.py TraceArgs,
PhotonPassArgs) follow.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from .. import layout

TRACE_ARGS = ("scene", "launch", "pix_sum", "pix_sq", "stats", "pix_jobs")
AUX_ARGS = ("aux",)
PHOTON_ARGS = ("ph_pos", "ph_dir", "ph_pow", "bucket_start", "ph_occ")  # the photon map's (PhotonPass.fill)
PHOTON_PASS_ARGS = ("scene", "launch", "ph_pos", "ph_dir", "ph_pow", "n_stored")


def fill_scene_info(rec, counts, eps_abs: float):
    """Fill rec, a SceneInfo record (or a launch record's "scene" field), by
    field name from a packed scene's counts (clpt.pack.PackedScene.counts)."""
    for name, n in zip(layout.COUNT_NAMES, counts):
        rec[name] = n
    rec["eps_abs"] = eps_abs
    return rec


def fill_pixel_filter(rec, pf):
    """Fill rec, a FilterRec (a launch record's "pixel_filter" field), from a
    clpt.scene.PixelFilter; its kind is the build's (CLPT_PIXEL_FILTER)."""
    rec["radius"] = pf.extent
    rec["sample_border"] = int(pf.sample_border)
    return rec


def scene_info(counts, eps_abs: float, double: bool) -> np.ndarray:
    """A SceneInfo record of its own (the probes' scene argument)."""
    return fill_scene_info(layout.SCENE_INFO.zeros(double), counts, eps_abs)


def trace_record(double: bool) -> np.ndarray:
    """A zeroed TraceLaunch record."""
    return layout.TRACE_LAUNCH.zeros(double)


def photon_record(double: bool) -> np.ndarray:
    """A zeroed PhotonLaunch record."""
    return layout.PHOTON_LAUNCH.zeros(double)


class RecordBuffer:
    """A device buffer holding one launch record, rewritten before each launch."""

    def __init__(self, dctx, record: np.ndarray):
        self.dctx = dctx
        self.buffer = cl.Buffer(dctx.context, cl.mem_flags.READ_ONLY, max(record.nbytes, 16))

    def write(self, record: np.ndarray):
        """Copy record in (blocking: the host array may change right after; in
        an in-order queue the copy also lands after every launch queued before)."""
        cl.enqueue_copy(self.dctx.queue, self.buffer, np.ascontiguousarray(record), is_blocking=True)
        return self.buffer

