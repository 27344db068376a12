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
refused with the list of its matches). Without a selection, PYOPENCL_CTX is
honoured, then a GPU is preferred, then PoCL's CPU device, then any CPU, so
registering another CPU runtime does not change the default.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import pyopencl as cl


class DeviceError(RuntimeError):
    """No usable OpenCL device matches what was asked for."""


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
        raise DeviceError(f"no OpenCL platform found ({e}); install an OpenCL runtime "
                          f"(pip install pocl-binary-distribution gives a CPU one)") from None
    out = []
    for pi, p in enumerate(platforms):
        try:
            devs = p.get_devices()
        except cl.Error:
            continue
        for di, d in enumerate(devs):
            out.append((pi, di, p, d))
    return out


def platform_short_name(platform_name: str) -> str:
    """A platform's short name for --device: pocl, intel, nvidia, amd, or the
    first word of its name, lowercased, without (R)/(TM)."""
    low = platform_name.lower()
    if "portable computing language" in low or "pocl" in low:
        return "pocl"
    for known in ("intel", "nvidia", "amd", "apple", "rusticl", "clover"):
        if known in low:
            return known
    words = low.replace("(r)", "").replace("(tm)", "").split()
    return words[0] if words else low


def device_has_fp64(dev) -> bool:
    return bool(dev.double_fp_config) or "cl_khr_fp64" in dev.extensions


def list_devices() -> list[DeviceInfo]:
    infos = []
    for i, (pi, di, p, d) in enumerate(_all_devices()):
        infos.append(DeviceInfo(index=i, platform_index=pi, device_index=di, name=d.name.strip(),
                                platform=p.name.strip(), kind=_kind(d), compute_units=d.max_compute_units,
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
    exact = [d for _, _, p, d in found
             if low in (d.name.strip().lower(), p.name.strip().lower(), platform_short_name(p.name.strip()))]
    if exact:
        return exact[:1]
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


def select_devices(spec=None) -> list:
    """pyopencl Device objects for a selection string, an index, a Device or a list of these."""
    found = _all_devices()
    if not found:
        raise DeviceError("no OpenCL device found; install an OpenCL runtime "
                          "(pip install pocl-binary-distribution gives a CPU one)")
    if isinstance(spec, cl.Device):
        return [spec]
    if isinstance(spec, (list, tuple)):
        out = []
        for s in spec:
            out += select_devices(s)
        return out
    if isinstance(spec, int):
        spec = str(spec)
    if spec is None:
        env = os.environ.get("PYOPENCL_CTX", "").strip()
        if env:
            spec = env
    if spec is None:
        gpus = [d for _, _, _, d in found if d.type & cl.device_type.GPU]
        cpus = [d for _, _, p, d in found if d.type & cl.device_type.CPU]
        cpus.sort(key=lambda d: platform_short_name(d.platform.name.strip()) != "pocl")  # stable: PoCL first
        return [(gpus or cpus or [found[0][3]])[0]]
    out = []
    for part in str(spec).split(","):
        part, slash, n = part.partition("/")
        for d in _match(part, found):
            for sub in (split_device(d, n) if slash else [d]):
                if sub not in out:
                    out.append(sub)
    return out


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
        d = self.device
        return "|".join([self.platform, d.platform.version, self.name, d.vendor, d.version, d.driver_version])
