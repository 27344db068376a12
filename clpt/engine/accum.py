"""Raw per-pixel sums of a render, kept in float64 on the host.

Planes (n = pixels):
  sum    n x 4   r, g, b, sample count
  sq     n       squared luminance (times lum_scale squared, as the kernels sum it)
  comp   n x 5   Kahan compensations of sum and sq (devices without fp64); value = sum - comp
  aux    n x 16  feature sums: normal xyz + count, albedo rgb + distance, emission rgb + emitter count,
                 online caustic rgb + its squared scaled luminance
  c_sum, c_sq, c_comp   the offline caustic buffer, as sum, sq and comp

Sums add plane by plane, so accumulators of disjoint work merge into the
accumulator of all of it; what a device holds goes in and out unchanged
(to_device / from_device), which keeps a resumed render bit-identical.
"""

from __future__ import annotations

import io
import json
import warnings

import numpy as np

from ..constants import dot_rows
from ..result import RenderResult

LUMA = np.array([0.2126, 0.7152, 0.0722])
WIDTHS = {"sum": 4, "sq": 0, "comp": 5, "aux": 16, "c_sum": 4, "c_sq": 0, "c_comp": 5}


class Accumulator:
    def __init__(self, n_pix: int, *, kahan: bool = False, aux: bool = False, caustic: bool = False):
        self.n_pix = int(n_pix)
        names = ["sum", "sq"] + (["comp"] if kahan else []) + (["aux"] if aux else [])
        if caustic:
            names += ["c_sum", "c_sq"] + (["c_comp"] if kahan else [])
        self.planes = {k: np.zeros((self.n_pix, WIDTHS[k]) if WIDTHS[k] else self.n_pix) for k in names}

    # --- arithmetic ----------------------------------------------------------------
    def add(self, other: "Accumulator") -> "Accumulator":
        """Add other's sums (its planes must be among ours) in place."""
        if other.n_pix != self.n_pix:
            raise ValueError(f"cannot add sums of {other.n_pix} pixels to sums of {self.n_pix}")
        for k, v in other.planes.items():
            if k not in self.planes:
                raise ValueError(f"cannot add plane {k!r} to an accumulator without it")
            self.planes[k] += v
        return self

    def copy(self) -> "Accumulator":
        out = Accumulator.__new__(Accumulator)
        out.n_pix = self.n_pix
        out.planes = {k: v.copy() for k, v in self.planes.items()}
        return out

    def zeros_like(self) -> "Accumulator":
        out = self.copy()
        for v in out.planes.values():
            v[...] = 0.0
        return out

    @staticmethod
    def merge(parts) -> "Accumulator":
        parts = list(parts)
        out = parts[0].copy()
        for p in parts[1:]:
            out.add(p)
        return out

    def with_layout(self, like: "Accumulator") -> "Accumulator":
        """These sums in like's layout: Kahan compensations folded in or added
        as zeros (the feature and caustic planes must agree)."""
        out = self.copy()
        for p in ("", "c_"):
            if p + "comp" in out.planes and p + "comp" not in like.planes:
                comp = out.planes.pop(p + "comp")
                out.planes[p + "sum"] = out.planes[p + "sum"] - comp[:, :4]
                out.planes[p + "sq"] = out.planes[p + "sq"] - comp[:, 4]
            elif p + "comp" in like.planes and p + "comp" not in out.planes and p + "sum" in out.planes:
                out.planes[p + "comp"] = np.zeros((self.n_pix, 5))
        if not out.same_layout(like):
            raise ValueError(f"sums with planes {sorted(self.planes)} do not fit planes {sorted(like.planes)}")
        return out

    def same_layout(self, other: "Accumulator") -> bool:
        return other.n_pix == self.n_pix and set(other.planes) == set(self.planes)

    # --- values --------------------------------------------------------------------
    def _value(self, prefix: str = ""):
        s, sq = self.planes[prefix + "sum"], self.planes[prefix + "sq"]
        comp = self.planes.get(prefix + "comp")
        if comp is not None:
            return s - comp[:, :4], sq - comp[:, 4]
        return s, sq

    @property
    def count(self) -> np.ndarray:
        return self._value()[0][:, 3]

    @property
    def samples(self) -> int:
        return int(round(float(self.count.sum())))

    def stats(self, lum_scale: float = 1.0, prefix: str = ""):
        """Per pixel: mean rgb, variance of one sample's luminance, count."""
        total, total_sq = self._value(prefix)
        total = np.zeros((self.n_pix, 4)) + total  # as the kernels' sums were always read: from zero
        total_sq = np.zeros(self.n_pix) + total_sq
        count = total[:, 3]
        safe = np.maximum(count, 1.0)
        mean = total[:, :3] / safe[:, None]
        lum_mean = dot_rows(mean, LUMA) * lum_scale  # the kernels square scaled luminance
        var = np.maximum(total_sq / safe - lum_mean ** 2, 0.0) * (safe / np.maximum(safe - 1.0, 1.0)) / lum_scale ** 2
        return mean, var, count

    def images(self, width: int, height: int, lum_scale: float = 1.0, length_scale: float = 1.0):
        """(image, lum_var, count, caustic image, aux dict) as a RenderResult
        holds them; length_scale: the packed scene's (depths are given back in
        the scene's own lengths)."""
        mean, var, count = self.stats(lum_scale)
        caustic = caustic_var = None
        if "c_sum" in self.planes:
            c_mean, c_var, c_count = self.stats(lum_scale, "c_")
            caustic = c_mean.astype(np.float32).reshape(height, width, 3)
            mean = mean + c_mean
            # As the variance of one sample: the caustic mean's variance scaled to count samples.
            caustic_var = c_var * np.maximum(count, 1.0) / np.maximum(c_count, 1.0)
            var = var + caustic_var
        image = mean.astype(np.float32).reshape(height, width, 3)
        bad = ~np.isfinite(image)
        if bad.any():  # the kernels drop non-finite samples; this is the last guard
            warnings.warn(f"{int(bad.sum())} non-finite pixel values set to 0")
            image[bad] = 0.0
        aux = None
        if "aux" in self.planes:
            a = np.zeros((self.n_pix, 16)) + self.planes["aux"]
            nsum, asum, esum, csum = a[:, 0:4], a[:, 4:8], a[:, 8:12], a[:, 12:16]
            k = np.maximum(nsum[:, 3:4], 1.0)
            normal = nsum[:, :3]
            normal = normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)

            def img(x):
                return x.reshape(height, width, -1).astype(np.float32)

            aux = {"normal": img(normal), "albedo": img(asum[:, :3] / k),
                   "depth": (asum[:, 3] / k[:, 0] / length_scale).reshape(height, width).astype(np.float32),
                   "emission": img(esum[:, :3] / k),
                   "emitter": (esum[:, 3] / k[:, 0]).reshape(height, width).astype(np.float32)}
            if caustic is not None:  # offline: the caustic buffer
                aux["caustic"], aux["caustic_var"] = caustic, caustic_var.reshape(height, width)
            else:  # online: the photon part the kernels summed
                n = np.maximum(count, 1.0)
                c_mean = csum[:, :3] / n[:, None]
                c_lum = dot_rows(c_mean, LUMA) * lum_scale
                c_var = np.maximum(csum[:, 3] / n - c_lum ** 2, 0.0) * (n / np.maximum(n - 1.0, 1.0)) / lum_scale ** 2
                aux["caustic"], aux["caustic_var"] = img(c_mean), c_var.reshape(height, width)
                # The plane's w per sample, as it is: in the pilot's trial (RenderJob.moments), path
                # tracing's second moment for the merged paths (kernels/photon_grid.h).
                aux["caustic_sq"] = (csum[:, 3] / n / lum_scale ** 2).reshape(height, width).astype(np.float32)
        return image, var.reshape(height, width), count.reshape(height, width), caustic, aux

    def finish(self, width: int, height: int, lum_scale: float = 1.0, length_scale: float = 1.0, **result):
        """A RenderResult of these sums; `result` gives its other fields
        (seed, max_depth, rr_depth, devices, features, stats, ...)."""
        image, var, count, caustic, aux = self.images(width, height, lum_scale, length_scale)
        spp = int(count.max()) if count.size else 0
        return RenderResult(image=image, sample_count=count.astype(np.uint32), lum_var=var, spp=spp,
                            caustic_image=caustic, aux=aux, **result)

    # --- device layout --------------------------------------------------------------
    @classmethod
    def from_device(cls, main, caustic=None, aux=None) -> "Accumulator":
        """From what a device holds: main and caustic are (pix_sum, pix_sq) as
        read (n x 4 and n float64, or Kahan pairs n x 8 and n x 2 float32); aux
        four n x 4 float32 arrays."""
        kahan = main[0].shape[1] == 8
        n = len(main[0])
        acc = cls(n, kahan=kahan, aux=aux is not None, caustic=caustic is not None)
        for prefix, sums in (("", main), ("c_", caustic)):
            if sums is None:
                continue
            s, sq = sums
            acc.planes[prefix + "sum"][...] = s[:, :4]
            acc.planes[prefix + "sq"][...] = sq[:, 0] if kahan else sq
            if kahan:
                acc.planes[prefix + "comp"][:, :4] = s[:, 4:]
                acc.planes[prefix + "comp"][:, 4] = sq[:, 1]
        if aux is not None:
            acc.planes["aux"][...] = np.concatenate(aux, axis=1)
        return acc

    def to_device(self, prefix: str = "", kahan: bool = False):
        """(pix_sum, pix_sq) in a device's layout (inverse of from_device)."""
        s, sq = self.planes[prefix + "sum"], self.planes[prefix + "sq"]
        if not kahan:
            comp = self.planes.get(prefix + "comp")
            if comp is not None:  # Kahan sums onto a device with fp64 sums
                return np.ascontiguousarray(s - comp[:, :4]), np.ascontiguousarray(sq - comp[:, 4])
            return np.ascontiguousarray(s), np.ascontiguousarray(sq)
        comp = self.planes.get(prefix + "comp")
        if comp is None:
            comp = np.zeros((self.n_pix, 5))
        ds = np.concatenate([s, comp[:, :4]], axis=1).astype(np.float32)
        dq = np.stack([sq, comp[:, 4]], axis=1).astype(np.float32)
        return ds, dq

    def aux_to_device(self):
        a = self.planes["aux"].astype(np.float32)
        return [np.ascontiguousarray(a[:, 4 * i:4 * i + 4]) for i in range(4)]

    # --- bytes -----------------------------------------------------------------------
    def to_bytes(self) -> bytes:
        buf = io.BytesIO()
        np.savez(buf, _n_pix=np.array(self.n_pix), **self.planes)
        return buf.getvalue()

    @classmethod
    def from_bytes(cls, data: bytes) -> "Accumulator":
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            acc = cls.__new__(cls)
            acc.n_pix = int(z["_n_pix"])
            acc.planes = {}
            for k in z.files:
                if k == "_n_pix":
                    continue
                if k not in WIDTHS:
                    raise ValueError(f"unknown plane {k!r} in saved sums")
                v = z[k].astype(np.float64)
                want = (acc.n_pix, WIDTHS[k]) if WIDTHS[k] else (acc.n_pix,)
                if v.shape != want:
                    raise ValueError(f"plane {k!r} has shape {v.shape}, expected {want}")
                acc.planes[k] = v
        if "sum" not in acc.planes or "sq" not in acc.planes:
            raise ValueError("saved sums lack the sum or sq plane")
        return acc

    def describe(self) -> str:
        return json.dumps({"n_pix": self.n_pix, "planes": sorted(self.planes), "samples": self.samples})
