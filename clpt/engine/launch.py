"""trace_paths' arguments: one launch record whose numpy dtype is the truth.

TRACE_ARGS lists the kernel's parameters in order (kernels/trace.cl; a test
checks them against the source). A name in the record's dtype is passed by
value from the record, any other is a buffer looked up by name; the photon
map's arguments follow as PhotonMap.kernel_args gives them. `trace_args` is
the only place the argument list is put together.
"""

from __future__ import annotations

import numpy as np
import pyopencl.cltypes as clt

TRACE_ARGS = ("scene", "counts", "eps_abs", "lum_scale", "cam_o", "corner", "dx", "dy", "width", "height",
              "group_offset", "sample_begin", "n_samples", "max_depth", "rr_depth", "seed",
              "pix_sum", "pix_sq", "stats", "pix_list", "pix_jobs", "n_list")
AUX_ARGS = ("aux_normal", "aux_albedo", "aux_emit", "aux_caustic", "aux_specular")
PHOTON_ARGS = ("ph_pos", "ph_dir", "ph_pow", "bucket_start", "pm_mask", "pm_max", "pm_budget", "pm_radius",
               "pm_cone_k", "pm_mode", "pm_mis_k", "pm_merge_vertices", "pm_aim", "pm_merge_p", "pm_occ",
               "pm_occ_mask", "pm_inv_cell")  # as PhotonMap.kernel_args gives them


def launch_dtype(double: bool) -> np.dtype:
    """The by-value arguments of one trace_paths launch."""
    real = np.float64 if double else np.float32
    u = np.uint32
    return np.dtype([("counts", u, 8), ("eps_abs", real), ("lum_scale", real), ("cam_o", real, 4),
                     ("corner", real, 4), ("dx", real, 4), ("dy", real, 4), ("width", u), ("height", u),
                     ("group_offset", u), ("sample_begin", u), ("n_samples", u), ("max_depth", u),
                     ("rr_depth", u), ("seed", u), ("n_list", u), ("aux_specular", u)])


def _by_value(rec, name):
    dt = rec.dtype.fields[name][0]
    v = rec[name]
    if dt.shape == (8,):
        return clt.make_uint8(*(int(x) for x in v))
    if dt.shape == (4,):
        make = clt.make_double4 if dt.base == np.float64 else clt.make_float4
        return make(*(float(x) for x in v))
    return dt.type(v)


def trace_args(rec, buffers: dict, aux: bool, photon_tail=None) -> list:
    """The positional arguments of trace_paths: rec (a launch_dtype record)
    for values, buffers by name, photon_tail (PhotonMap.kernel_args) last."""
    names = TRACE_ARGS + (AUX_ARGS if aux else ())
    out = [_by_value(rec, n) if n in rec.dtype.names else buffers[n] for n in names]
    if photon_tail is not None:
        out += list(photon_tail)
    return out
