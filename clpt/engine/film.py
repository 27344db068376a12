"""A job's per-pixel sums on one device (kernels/film.h's layout): the
image's sums, the offline caustic buffer's, and the feature sums.

They go in and out unchanged (Accumulator.to_device / from_device), so a
render continued from them is bit-identical.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..errors import DeviceError
from .accum import Accumulator


class PixelSums:
    """One image's sums of colour, count and squared luminance: float64, or Kahan pairs of float32."""

    def __init__(self, dctx, n_pix: int, accum_double: bool):
        self.dctx, self.n_pix, self.accum_double = dctx, n_pix, accum_double
        ctx = dctx.context
        self.pix_sum = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, n_pix * 32)
        self.pix_sq = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, n_pix * 8)
        self.zero()

    def zero(self):
        q = self.dctx.queue
        cl.enqueue_fill_buffer(q, self.pix_sum, np.float32(0), 0, self.n_pix * 32)
        cl.enqueue_fill_buffer(q, self.pix_sq, np.float32(0), 0, self.n_pix * 8)

    def read_async(self):
        """Queue copies of the sums into fresh host arrays: ((pix_sum, pix_sq), events)."""
        q = self.dctx.queue
        if self.accum_double:
            s, sq = np.empty((self.n_pix, 4), np.float64), np.empty(self.n_pix, np.float64)
        else:
            s, sq = np.empty((self.n_pix, 8), np.float32), np.empty((self.n_pix, 2), np.float32)
        return (s, sq), [cl.enqueue_copy(q, s, self.pix_sum, is_blocking=False),
                         cl.enqueue_copy(q, sq, self.pix_sq, is_blocking=False)]

    def write(self, s, sq):
        q = self.dctx.queue
        cl.enqueue_copy(q, self.pix_sum, s)
        cl.enqueue_copy(q, self.pix_sq, sq)
        q.finish()

    @property
    def nbytes(self) -> int:
        return self.pix_sum.size + self.pix_sq.size


class Film:
    """A job's sums on a device: `main`, the offline caustic buffer
    `caustic` (or None) and the feature sums `aux` (four planes of n_pix
    float4, kernels/film.h VisibleSurface; or None)."""

    def __init__(self, dctx, n_pix: int, *, accum_double: bool, caustic: bool, aux: bool, extra_bytes: int = 0,
                 label: str = ""):
        """Allocate and zero them; extra_bytes: what the passes allocate with
        them, counted against the device's memory. DeviceError if they do not fit."""
        self.dctx, self.n_pix, self.accum_double = dctx, n_pix, accum_double
        need = n_pix * 40 * (2 if caustic else 1) + extra_bytes + n_pix * 64 * aux
        dev = dctx.device
        label = label or dctx.label
        if n_pix * 32 > dev.max_mem_alloc_size or need > dev.global_mem_size:
            raise DeviceError(f"{n_pix} pixels need {need / 2**20:.0f} MiB of accumulation buffers, more than "
                              f"{label} offers ({dev.global_mem_size / 2**20:.0f} MiB, at most "
                              f"{dev.max_mem_alloc_size / 2**20:.0f} MiB per buffer); render a smaller image")
        self.need = need
        try:
            self.main = PixelSums(dctx, n_pix, accum_double)
            self.caustic = PixelSums(dctx, n_pix, accum_double) if caustic else None
            self.aux = cl.Buffer(dctx.context, cl.mem_flags.READ_WRITE, 4 * n_pix * 16) if aux else None
            self._zero_aux()
            dctx.queue.finish()
        except cl.Error as e:
            raise DeviceError(f"cannot allocate {need / 2**20:.0f} MiB on {label} for "
                              f"{n_pix} pixels ({e}); render a smaller image") from None

    def _zero_aux(self):
        if self.aux is not None:
            cl.enqueue_fill_buffer(self.dctx.queue, self.aux, np.float32(0), 0, self.aux.size)

    def zero(self):
        self.main.zero()
        if self.caustic is not None:
            self.caustic.zero()
        self._zero_aux()
        self.dctx.queue.finish()

    def snapshot(self):
        """Queue copies of the sums without waiting for them: ((main, caustic,
        aux) raw arrays for Accumulator.from_device, events). The queue is in
        order, so queued from any thread they see the sums between two items."""
        main, events = self.main.read_async()
        caustic = None
        if self.caustic is not None:
            caustic, ev = self.caustic.read_async()
            events += ev
        aux = None
        if self.aux is not None:
            aux = [np.empty((self.n_pix, 4), np.float32) for _ in range(4)]
            events += [cl.enqueue_copy(self.dctx.queue, h, self.aux, src_offset=k * h.nbytes, is_blocking=False)
                       for k, h in enumerate(aux)]
        self.dctx.queue.flush()
        return (main, caustic, aux), events

    def read(self) -> Accumulator:
        raw, _ = self.snapshot()
        self.dctx.queue.finish()
        return Accumulator.from_device(*raw)

    def load(self, acc: Accumulator):
        """Replace the sums by acc's (in this device's layout)."""
        kahan = not self.accum_double
        self.main.write(*acc.to_device("", kahan))
        if self.caustic is not None:
            if "c_sum" in acc.planes:
                self.caustic.write(*acc.to_device("c_", kahan))
            else:
                self.caustic.zero()
        if self.aux is not None:
            if "aux" in acc.planes:
                for k, h in enumerate(acc.aux_to_device()):
                    h = np.ascontiguousarray(h, dtype=np.float32)
                    cl.enqueue_copy(self.dctx.queue, self.aux, h, dst_offset=k * h.nbytes)
            else:
                self._zero_aux()
        self.dctx.queue.finish()

    def buffer_bytes(self) -> dict[str, int]:
        out = {"pixel sums": self.main.nbytes}
        if self.caustic is not None:
            out["caustic sums"] = self.caustic.nbytes
        if self.aux is not None:
            out["feature buffers"] = self.aux.size
        return out
