"""`clpt devices`: the OpenCL devices, and with -v their vector widths,
checks, tuned defaults and the default device for each kind of render."""

from __future__ import annotations

import sys


def add_parser(sub):
    p = sub.add_parser("devices", help="list the OpenCL devices")
    p.add_argument("-v", "--verbose", action="store_true", help="also the vector widths and the tuned defaults")
    p.set_defaults(func=run)
    return p


def run(a) -> int:
    from .. import device as devmod, runtimes
    from ..device import DeviceContext, list_devices

    devs = list_devices()
    for d in devs:
        print(d.line())
        if a.verbose:
            from .. import tune

            dev = devmod._all_devices()[d.index][3]
            dctx = DeviceContext(dev)
            print(f"    float vector width: native {dev.native_vector_width_float}, preferred "
                  f"{dev.preferred_vector_width_float}; max work-group {dev.max_work_group_size}; "
                  f"max allocation {d.max_alloc / 2**30:.1f} GiB")
            if devmod.is_simulator(dev):
                print("    check: a simulator (never a default; name it with --device to debug kernels)")
            else:
                print(f"    check: {devmod.check_device(dev).line()}")
            for photons in (False, True):
                print(f"    defaults{' with photons' if photons else ''}: "
                      f"{tune.query_tuning(dctx, photons).describe()}")
            for e in tune.cached_choices(dctx):
                print(f"    measured: lanes {e['lanes']}, local size {e['local_size']}, pass {e['pass_seconds']:g} s "
                      f"({e['why']})")
    if not devs:
        print("no OpenCL devices found", file=sys.stderr)
        return 1
    if a.verbose:
        reg = runtimes.registration()
        if reg is not None:
            print(f"runtimes: {reg.note}")
        for photons, kind in ((False, "for path tracing"), (True, "with photon merging")):
            try:
                c = devmod.default_device(photons)
                print(f"default {kind}: {devmod.device_label(c.device)}: {c.why}"
                      + "".join(f"; {s}" for s in c.skipped))
            except devmod.DeviceError as e:
                print(f"default {kind}: none ({e})")
    return 0
