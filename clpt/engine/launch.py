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

import collections

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

    KEEP = 4  # copies whose host side is kept alive (their transfers long done when dropped)

    def __init__(self, dctx, record: np.ndarray):
        self.dctx = dctx
        self.buffer = cl.Buffer(dctx.context, cl.mem_flags.READ_ONLY, max(record.nbytes, 16))
        self._copies = collections.deque(maxlen=self.KEEP)

    def write(self, record: np.ndarray):
        """Queue a copy of record into the buffer, without waiting for it: in
        an in-order queue it lands after every launch queued before and before
        every launch queued after, so a launch queued behind work still
        running (a photon map's build) follows it with no return to the host
        in between. The record is copied first, so the caller's array may
        change at once; pyopencl's event keeps that copy alive until the
        transfer is done (dropping the event waits for it: the last KEEP
        are kept, and by the time one is dropped later launches have
        followed it)."""
        host = np.array(record, copy=True, order="C")
        self._copies.append(cl.enqueue_copy(self.dctx.queue, self.buffer, host, is_blocking=False))
        return self.buffer

