"""OpenCL device discovery and selection; one context and queue per device.

Nothing here is global: each selected device gets its own ``DeviceContext``,
so one image can be rendered on several devices at once.

Selection (``--device``, ``clpt.render(device=...)``): an index into
``list_devices()`` ("1"), a platform:device pair as in PYOPENCL_CTX ("0:1"),
a name, "all", or several of these separated by commas. A name is matched
case-insensitively: first exactly, against the device name, the platform
name and the platform's short name (``pocl``, ``intel``, ``nvidia``, ``amd``:
the first device of that platform); else as a substring of the device or
platform name, which must then pick out one device (an ambiguous name is
refused with the list of its matches). Where platforms share a name (the
PoCL in pyopencl's wheel beside a system PoCL), the first that renders.

Every device is checked before its first render (clpt/probe.py: a child
process builds and renders a tiny Cornell box; cached per device and
driver). Without a selection, PYOPENCL_CTX is honoured; else the default is
the first candidate that passes: a GPU, then the CPU runtimes in the order
of their measured speed for the kernel's kind (CPU_RUNTIME_RATES: path
tracing alone, or with photon merging), then anything else; each candidate
skipped is named in one DeviceWarning line, and if none passes the error
says what to install. A device named alone that fails is an error, never a
silent switch; in a list or "all" it is left out with a warning.
Simulators (Oclgrind, which reports itself as a GPU) are chosen only by
name.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass

import pyopencl as cl

from . import probe, tune
from .errors import DeviceError, DeviceWarning
from .runtimes import SIMULATORS, platform_short_name


@dataclass(frozen=True)
class DeviceInfo:
    index: int
    platform_index: int
    device_index: int
    name: str
    platform: str
    kind: str
    compute_units: int
    global_mem: int
    max_alloc: int
    fp64: bool
    driver: str
    short: str = ""

    def line(self) -> str:
        return (f"[{self.index}] {self.platform_index}:{self.device_index}  {self.name}  ({self.platform} = {self.short}; "
                f"{self.kind}, {self.compute_units} units, {self.global_mem / 2**30:.1f} GiB, "
                f"fp64 {'yes' if self.fp64 else 'no'}, driver {self.driver})")


def _kind(dev) -> str:
    t = dev.type
    if t & cl.device_type.GPU:
        return "GPU"
    if t & cl.device_type.CPU:
        return "CPU"
    if t & cl.device_type.ACCELERATOR:
        return "accelerator"
    return "other"


def _all_devices():
    try:
        platforms = cl.get_platforms()
    except cl.Error as e:
        raise DeviceError(f"no OpenCL platform found ({e}). {_FIX}") from None
    out = []
    for pi, p in enumerate(platforms):
        try:
            devs = p.get_devices()
        except cl.Error:
            continue
        for di, d in enumerate(devs):
            out.append((pi, di, p, d))
    return out


def device_has_fp64(dev) -> bool:
    return bool(dev.double_fp_config) or "cl_khr_fp64" in dev.extensions


def list_devices() -> list[DeviceInfo]:
    infos = []
    for i, (pi, di, p, d) in enumerate(_all_devices()):
        infos.append(DeviceInfo(index=i, platform_index=pi, device_index=di, name=d.name.strip(),
                                platform=p.name.strip(), kind="simulator" if is_simulator(d) else _kind(d), compute_units=d.max_compute_units,
                                global_mem=d.global_mem_size, max_alloc=d.max_mem_alloc_size,
                                fp64=device_has_fp64(d), driver=d.driver_version,
                                short=platform_short_name(p.name.strip())))
    return infos


def _match(spec: str, found) -> list:
    spec = spec.strip()
    if spec.lower() == "all":
        return [d for _, _, _, d in found]
    if ":" in spec:
        a, b = spec.split(":", 1)
        if a.isdigit() and (b.isdigit() or b == ""):
            pis = sorted({pi for pi, _, _, _ in found})
            if int(a) >= len(pis):
                raise DeviceError(f"no OpenCL platform {a} (there are {len(pis)})")
            devs = [(di, d) for pi, di, _, d in found if pi == pis[int(a)]]
            if b == "":
                return [devs[0][1]]
            for di, d in devs:
                if di == int(b):
                    return [d]
            raise DeviceError(f"platform {a} has no device {b} (it has {len(devs)})")
    if spec.isdigit():
        i = int(spec)
        if i >= len(found):
            raise DeviceError(f"no device {i}: there are {len(found)} (see `clpt devices`)")
        return [found[i][3]]
    low = spec.lower()
    exact, platforms = [], set()
    for pi, _, p, d in found:
        if low in (d.name.strip().lower(), p.name.strip().lower(), platform_short_name(p.name.strip())) \
                and pi not in platforms:
            platforms.add(pi)
            exact.append(d)
    if exact:
        return exact  # the first device of each platform: several where platforms share a name (two PoCLs)
    hits = [(pi, di, p, d) for pi, di, p, d in found if low in d.name.lower() or low in p.name.lower()]
    if len(hits) == 1:
        return [hits[0][3]]

    def listing(entries):
        return "; ".join(f"{pi}:{di} {d.name.strip()} ({p.name.strip()} = {platform_short_name(p.name.strip())})"
                         for pi, di, p, d in entries)

    if not hits:
        raise DeviceError(f"no OpenCL device matches {spec!r}; available: {listing(found)}")
    raise DeviceError(f"{spec!r} matches {len(hits)} devices: {listing(hits)}; "
                      f"name one exactly, by platform:device, or by a platform's short name")


# Simulators and debuggers (runtimes.SIMULATORS): never chosen by default or
# by "all", whatever device type they report (Oclgrind reports a GPU); only by name.

# Samples/s of CPU runtimes that rank the default CPU device, per kind of
# kernel: path tracing alone, and with the caustic photon gather. Measured on
# the 2-core AVX-512 machine (AMD EPYC, Zen 4) with Intel's runtime 2026.2 and
# Debian's PoCL 3.1, each at its default lanes. "plain": `clpt bench
# cornell_box --device intel,pocl --width 128 --height 128 --max-depth 64
# --rounds 5 --no-cold`, medians, Msamples/s. "photons": cornell_box_caustics
# with its default photon merging, 128x128, depth 64, medians of 3 renders,
# in Msamples per CPU second of the process (the machine was shared; each
# runtime's workers use both cores, so the ranking is that of wall time).
# A runtime not listed ranks after these; a GPU before every CPU.
CPU_RUNTIME_RATES = {
    "plain": {"intel": 13.4, "pocl": 9.55},
    "photons": {"intel": 2.22, "pocl": 2.02},
}


def is_simulator(device) -> bool:
    p = device.platform.name.lower()
    return any(s in p or s in device.name.lower() for s in SIMULATORS)


def device_label(device) -> str:
    return f"{device.name.strip()} ({device.platform.name.strip()}, driver {device.driver_version.strip()})"


def _where(device, found) -> tuple[int, int] | None:
    for pi, di, _, d in found:
        if d == device:
            return pi, di
    return None


def check_device(device, lanes: int | None = None, photons: bool = False, found=None, *, wait: bool = True,
                 background: bool = True):
    """The device's check (clpt/probe.py) at the lanes it would render with;
    an ok result without running anything for simulators, sub-devices and
    when CLPT_DEVICE_CHECK=0. wait=False: the cached result, else None (after
    starting the check in the background, unless background=False)."""
    n = lanes or tune.predict(device).lanes  # the width of the Cornell box's kernel on this device
    where = _where(device, found if found is not None else _all_devices())
    if not probe.enabled() or is_simulator(device) or where is None:
        return probe.CheckResult(True, n, "", 0.0)
    identity, label = DeviceContext.identity_of(device), device_label(device)
    if not wait:
        hit = probe.cached(identity, n)
        if hit is None and background:
            probe.check_in_background(identity, label, n, where)
        return hit
    return probe.check(device, identity, label, n, where)


@dataclass(frozen=True)
class DefaultChoice:
    """The device chosen when none was asked for, why, and those skipped."""
    device: object
    why: str
    skipped: tuple[str, ...] = ()


def _rank(found, photons: bool):
    """Candidates for the default, best first: GPUs in listed order, then
    CPUs by CPU_RUNTIME_RATES for the kernel's kind (unlisted runtimes after,
    in listed order), then other devices; simulators never."""
    rates = CPU_RUNTIME_RATES["photons" if photons else "plain"]
    gpus, cpus, other = [], [], []
    for i, (pi, di, p, d) in enumerate(found):
        if is_simulator(d):
            continue
        if d.type & cl.device_type.GPU:
            gpus.append(d)
        elif d.type & cl.device_type.CPU:
            cpus.append((-rates.get(platform_short_name(p.name.strip()), -1.0), i, d))
        else:
            other.append(d)
    return gpus + [d for _, _, d in sorted(cpus, key=lambda t: t[:2])] + other


def _why(device, photons: bool) -> str:
    if device.type & cl.device_type.GPU:
        return "the first GPU"
    kind = "photons" if photons else "plain"
    rates = CPU_RUNTIME_RATES[kind]
    short = platform_short_name(device.platform.name.strip())
    if device.type & cl.device_type.CPU and short in rates:
        table = ", ".join(f"{k} {v:g}" for k, v in sorted(rates.items(), key=lambda kv: -kv[1]))
        what = "with caustic photon merging" if photons else "path tracing"
        return (f"the CPU runtime measured fastest {what} of those that render here (Msamples/s: {table}; "
                f"clpt/device.py CPU_RUNTIME_RATES)")
    return "the first device that renders here (no GPU, no measured CPU runtime)"


def default_device(photons: bool = False, found=None) -> DefaultChoice:
    """The device to render on when none is named: the best candidate (see
    _rank) that passes its check; raises DeviceError naming the fix if none
    does. Checks that make the render wait run in the order of path-tracing
    speed (the surest first: a GPU, then the CPU runtime that path traces
    fastest); a candidate ranked ahead of that one only for photon merging
    and not checked yet is checked in the background, and taken by later
    renders if it passes: a first render never waits for a runtime that may
    crash (the PoCL in pyopencl's wheel can spend 30 s failing its check)."""
    found = _all_devices() if found is None else found
    if not found:
        raise DeviceError(_NO_DEVICE)
    # Each device is checked at its own width, whatever lanes a render asks for: the default
    # must not change with lanes (a crashing compiler may pass at 4 lanes and fail at 16).
    lanes = None
    skipped, base = [], None
    for d in _rank(found, False):
        r = check_device(d, lanes, False, found)
        if r.ok:
            base = d
            break
        skipped.append(f"skipped {device_label(d)}: {r.line()}")
    if base is None:
        listed = "; ".join(skipped) or "only simulators are listed (name one with --device)"
        raise DeviceError(f"no OpenCL device can render here ({listed}). {_FIX}")
    for d in _rank(found, photons):
        if d == base:
            break
        # One background check at a time: on a few cores each one slows the render down.
        started = any("in the background" in line for line in skipped)
        r = check_device(d, lanes, photons, found, wait=False, background=not started)
        if r is None and started:
            continue
        if r is None:
            skipped.append(f"checking {device_label(d)} in the background (faster with photon merging where "
                           f"measured); later renders take it if it renders here")
        elif r.ok:
            return DefaultChoice(d, _why(d, photons), tuple(skipped))
        elif not any(device_label(d) in line for line in skipped):
            skipped.append(f"skipped {device_label(d)}: {r.line()}")
    return DefaultChoice(base, _why(base, photons), tuple(skipped))


_FIX = ("Reinstall clpt on Linux x86-64 to get Intel's CPU runtime (pip install --force-reinstall "
        "intel-opencl-rt intel-cmplr-lib-rt), install another OpenCL driver (e.g. apt install pocl-opencl-icd, "
        "or a GPU's), or name a device with --device (clpt devices lists them)")
_NO_DEVICE = f"no OpenCL device found. {_FIX}"


def _checked(devices, lanes, found, explicit_one: bool, spec: str) -> list:
    """The devices that pass their checks; one named alone that fails is an
    error, others that fail are left out with a DeviceWarning each."""
    out, failed = [], []
    for d in devices:
        r = check_device(d, lanes, False, found)
        if r.ok:
            out.append(d)
        else:
            failed.append(f"{device_label(d)} {r.line()}")
    if explicit_one and failed:
        raise DeviceError(f"{failed[0]}; choose another device (clpt devices lists them), or fewer --lanes")
    if not out:
        raise DeviceError(f"no device of {spec!r} can render here: {'; '.join(failed)}")
    for f in failed:
        if f"left out {f}" not in _reported:
            _reported.add(f"left out {f}")
            warnings.warn(DeviceWarning(f"left out {f}"), stacklevel=3)
    return out


_reported: set[str] = set()


@dataclass(frozen=True)
class Selection:
    """The devices selected and why (`render -v`)."""
    devices: list
    why: str


def select_devices(spec=None, *, photons: bool = False, lanes: int | None = None) -> list:
    """pyopencl Device objects for a selection string, an index, a Device or a
    list of these (choose_devices(...).devices)."""
    return choose_devices(spec, photons=photons, lanes=lanes).devices


def choose_devices(spec=None, *, photons: bool = False, lanes: int | None = None) -> Selection:
    """The devices for a selection, and why. Without one: PYOPENCL_CTX, else
    default_device() for the kernel's kind (photons). Named devices are
    checked at `lanes` (clpt/probe.py): one named alone that cannot render
    is an error, never a silent switch; in a list or "all", those that cannot
    are left out with a warning, and simulators are left out of "all"."""
    found = _all_devices()
    if not found:
        raise DeviceError(_NO_DEVICE)
    if isinstance(spec, cl.Device):
        return Selection([spec], "given as a pyopencl Device")
    if isinstance(spec, (list, tuple)):
        out = []  # one device twice is two contexts on it (tests, several queues)
        for s in spec:
            out += select_devices(s, photons=photons, lanes=lanes)
        return Selection(out, f"named: {', '.join(map(str, spec))}")
    if isinstance(spec, int):
        spec = str(spec)
    why = f"named: {spec}"
    if spec is None:
        env = os.environ.get("PYOPENCL_CTX", "").strip()
        if env:
            spec, why = env, f"PYOPENCL_CTX={env}"
    if spec is None:
        choice = default_device(photons, found)
        for line in choice.skipped:
            if line not in _reported:  # once a process: every Renderer would say it again
                _reported.add(line)
                warnings.warn(DeviceWarning(line), stacklevel=3)
        return Selection([choice.device], "default: " + choice.why + "".join(f"; {s}" for s in choice.skipped))
    parts = [p.strip() for p in str(spec).split(",")]
    named = []  # (device, sub-device count or "")
    for part in parts:
        part, slash, n = part.partition("/")
        matched = _match(part, found)
        if part.lower() == "all":
            matched = [d for d in matched if not is_simulator(d)]
        elif len(matched) > 1:  # one name for several platforms (two PoCLs): the first that renders
            ok = [d for d in matched if check_device(d, lanes, photons, found).ok]
            matched = ok[:1] or matched[:1]
        named += [(d, n if slash else "") for d in matched if (d, n if slash else "") not in named]
    alone = len(parts) == 1 and parts[0].lower() != "all"
    distinct = []
    for d, _ in named:
        if d not in distinct:
            distinct.append(d)
    usable = _checked(distinct, lanes, found, alone, spec)
    out = []
    for d, n in named:
        if d in usable:
            out += [sub for sub in (split_device(d, n) if n else [d]) if sub not in out]
    return Selection(out, why)


def split_device(device, n) -> list:
    """A device split into n sub-devices of equal compute units (OpenCL
    device fission, CL_DEVICE_PARTITION_EQUALLY): the selector "SPEC/N"."""
    if not str(n).isdigit() or int(n) < 1:
        raise DeviceError(f"a device split needs a number of parts >= 1 (got {n!r})")
    n = int(n)
    cu = device.max_compute_units
    if n > cu or cu % n:
        raise DeviceError(f"{device.name.strip()} has {cu} compute units: it splits into parts that divide them "
                          f"(got {n})")
    if n == 1:
        return [device]
    props = getattr(device, "partition_properties", []) or []
    if cl.device_partition_property.EQUALLY not in props:
        raise DeviceError(f"{device.name.strip()} ({device.platform.name.strip()}) cannot be split into sub-devices")
    return device.create_sub_devices([cl.device_partition_property.EQUALLY, cu // n])[:n]


class DeviceContext:
    """A device with its own context and profiling-enabled in-order queue."""

    def __init__(self, device):
        self.device = device
        self.context = cl.Context([device])
        self.queue = cl.CommandQueue(self.context, device,
                                     properties=cl.command_queue_properties.PROFILING_ENABLE)
        self.name = device.name.strip()
        self.platform = device.platform.name.strip()
        self.fp64 = device_has_fp64(device)
        self.is_cpu = bool(device.type & cl.device_type.CPU)
        self.is_pocl = "portable computing language" in self.platform.lower() or "pocl" in self.platform.lower()
        self.part = ""  # " #k" where one render has this device more than once (sub-devices)

    @property
    def label(self) -> str:
        return f"{self.name} ({self.platform}){self.part}"

    def identity(self) -> str:
        return self.identity_of(self.device)

    @staticmethod
    def identity_of(d) -> str:
        """The device and driver, as build caches and checks key them."""
        return "|".join([d.platform.name.strip(), d.platform.version, d.name.strip(), d.vendor, d.version,
                         d.driver_version])
