"""`clpt devices`: the OpenCL devices, and with -v their vector widths,
checks, tuned defaults and the default device for each kind of render;
with --tune, lanes and work-group sizes measured for scenes' kernels and
cached (what CLPT_TUNE=measure does on a render), so that no render pays
for the measurement."""

from __future__ import annotations

import sys

from . import common


def add_parser(sub):
    p = sub.add_parser("devices", help="list the OpenCL devices")
    p.add_argument("-v", "--verbose", action="store_true", help="also the vector widths and the tuned defaults")
    p.add_argument("--tune", nargs="*", metavar="SCENE", default=None,
                   help="measure lanes and work-group size for these scenes' kernels (default: cornell_box and "
                        "cornell_box_caustics, one with photons and one without) and cache the choice, which "
                        "later renders of scenes with the same kinds of shapes, lobes and lights take")
    common.device(p, help="with --tune: the devices to tune (default: each CPU device that is not a simulator)")
    p.set_defaults(func=run)
    return p


def run_tune(a) -> int:
    """Measure (CLPT_TUNE=measure) for each scene on each device, and say what was chosen."""
    import os

    from .. import device as devmod

    before = os.environ.get("CLPT_TUNE")
    os.environ["CLPT_TUNE"] = "measure"  # (for this command only: put back below)
    try:
        return _tune_each(a, _targets(a, devmod))
    finally:
        if before is None:
            os.environ.pop("CLPT_TUNE", None)
        else:
            os.environ["CLPT_TUNE"] = before


def _targets(a, devmod) -> list:
    """The devices `--tune` measures: --device's, or each CPU device that is not a simulator."""
    if a.device is not None:
        return [a.device]
    return [str(d.index) for d in devmod.list_devices()
            if d.kind == "CPU" and not devmod.is_simulator(devmod._all_devices()[d.index][3])]


def _tune_each(a, targets) -> int:
    import time

    from ..errors import DeviceError
    from ..render import Renderer

    if not targets:
        print("clpt: no CPU device to tune (GPUs take their defaults from device queries)", file=sys.stderr)
        return 1
    tuned = 0
    for spec in targets:
        for scene in a.tune or ("cornell_box", "cornell_box_caustics"):
            t0 = time.perf_counter()
            try:
                r = Renderer(scene, device=spec, use_cache=True)
            except DeviceError as e:  # a device that fails its check is left out, as in a device list
                common.warn(f"device {spec} not tuned: {e}")
                break
            st = r.states[0]
            tuned += 1
            print(f"{st.dctx.label}: {scene}: {st.tuning.describe()} ({time.perf_counter() - t0:.1f} s with the "
                  f"builds)")
    return 0 if tuned else 1


def run(a) -> int:
    if a.tune is not None:
        return run_tune(a)
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
