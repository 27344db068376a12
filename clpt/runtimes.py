"""OpenCL runtimes installed with clpt, registered for this process.

An OpenCL program finds runtimes through the ICD loader, which reads the
``.icd`` files of one vendor folder: ``/etc/OpenCL/vendors``, or the folder
(or file) that ``OCL_ICD_VENDORS`` names instead. pyopencl's wheels also load
the PoCL they bundle. A runtime installed by pip has no file in either place,
so nothing would find it.

On Linux x86-64, ``pip install clpt`` installs Intel's CPU OpenCL runtime
(the ``intel-opencl-rt`` and ``intel-cmplr-lib-rt`` wheels): the PoCL in
pyopencl's wheels (3.0, LLVM 14) cannot compile clpt's kernels on CPUs newer
than its LLVM (Zen 4 and Zen 5 among them), while Intel's runtime runs on
AMD and Intel CPUs alike. ``register()`` runs when clpt is imported, before
any OpenCL call: if that runtime is installed and not already visible, it
writes a vendor folder holding the ``.icd`` files the loader would have read
(those of ``OCL_ICD_VENDORS`` if the user set it, else of
``OPENCL_VENDOR_PATH`` or ``/etc/OpenCL/vendors``) plus one naming the
installed ``libintelocl.so``, and points ``OCL_ICD_VENDORS`` at it. Every
device the user had stays visible (system GPU and CPU drivers, pyopencl's
PoCL, their own folder), and child processes inherit the setting.

The folder lies in clpt's cache (``<cache>/opencl-vendors/<hash>``, named by
its contents, so concurrent processes agree on it), else in the temporary
folder. ``CLPT_REGISTER_RUNTIMES=0`` leaves the environment alone. A program
that made OpenCL calls before importing clpt has already read the vendor
folder: it sees the runtime only if it sets ``OCL_ICD_VENDORS`` itself.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

from .resources import cache_dir

SYSTEM_VENDORS = "/etc/OpenCL/vendors"
# Simulators and debuggers, by platform or device name (clpt.device never
# chooses them unasked; clpt.program builds them what they can run).
SIMULATORS = ("oclgrind",)


@dataclass(frozen=True)
class Registration:
    """What register() did: the runtime libraries it added (empty if none),
    the vendor folder OCL_ICD_VENDORS now names (None if unchanged), and why."""
    added: tuple[str, ...]
    folder: str | None
    note: str


_done: Registration | None = None


def bundled_runtime_libraries() -> list[Path]:
    """The OpenCL runtime libraries that pip installed beside clpt (Intel's
    CPU runtime), found through the installed distributions' file lists."""
    out = []
    try:
        dist = metadata.distribution("intel-opencl-rt")
    except metadata.PackageNotFoundError:
        return out
    for f in dist.files or ():
        if f.name == "libintelocl.so":
            p = Path(dist.locate_file(f)).resolve()
            if p.is_file():
                out.append(p)
    return out


def _icd_lines_in(path: Path) -> dict[str, str]:
    """{file name: library} of the .icd files a vendor folder (or one .icd
    file, or a library named directly) gives the loader."""
    out = {}
    try:
        if path.is_dir():
            for f in sorted(path.glob("*.icd")):
                try:
                    out[f.name] = f.read_text().strip()
                except OSError:
                    continue
        elif path.suffix == ".icd" and path.is_file():
            out[path.name] = path.read_text().strip()
        elif path.is_file():  # OCL_ICD_VENDORS naming a runtime library
            out[path.name + ".icd"] = str(path)
    except OSError:
        pass
    return {k: v for k, v in out.items() if v}


def current_vendors(environ=None) -> tuple[Path, dict[str, str]]:
    """The vendor folder the ICD loader will read, and its .icd entries."""
    env = os.environ if environ is None else environ
    where = env.get("OCL_ICD_VENDORS") or env.get("OPENCL_VENDOR_PATH") or SYSTEM_VENDORS
    return Path(where), _icd_lines_in(Path(where))


def _same_library(a: str, b: Path) -> bool:
    return Path(a).name == b.name  # an Intel runtime registered anywhere counts: no second platform


def _folder_for(entries: dict[str, str]) -> Path:
    text = "\n".join(f"{k}\t{v}" for k, v in sorted(entries.items()))
    name = hashlib.sha256(text.encode()).hexdigest()[:16]
    for base in (cache_dir() / "opencl-vendors", Path(tempfile.gettempdir()) / f"clpt-opencl-vendors-{os.getuid()}"):
        folder = base / name
        try:
            folder.mkdir(parents=True, exist_ok=True)
            for fname, lib in entries.items():
                p = folder / fname
                if not p.is_file() or p.read_text().strip() != lib:
                    tmp = folder / f".{fname}.{os.getpid()}.tmp"
                    tmp.write_text(lib + "\n")
                    os.replace(tmp, p)  # atomic: a concurrent process never reads half a file
            stale = {p.name for p in folder.glob("*.icd")} - set(entries)
            for s in stale:
                (folder / s).unlink(missing_ok=True)
            return folder
        except OSError:
            continue
    raise OSError("no writable folder for the OpenCL vendor list")


def register(environ=None, libraries=None) -> Registration:
    """Make the runtimes installed with clpt visible to the ICD loader (see
    the module's docstring). Idempotent; environ and libraries are for tests."""
    global _done
    env = os.environ if environ is None else environ
    if environ is None and libraries is None and _done is not None:
        return _done
    if env.get("CLPT_REGISTER_RUNTIMES", "1") == "0":
        result = Registration((), None, "CLPT_REGISTER_RUNTIMES=0: the OpenCL vendor list is left alone")
    else:
        libs = bundled_runtime_libraries() if libraries is None else [Path(p) for p in libraries]
        where, entries = current_vendors(env)
        missing = [lib for lib in libs if not any(_same_library(v, lib) for v in entries.values())]
        if not libs:
            result = Registration((), None, "no OpenCL runtime was installed with clpt")
        elif not missing:
            result = Registration((), None, f"Intel's CPU runtime is already listed in {where}")
        else:
            for lib in missing:
                entries[f"clpt-{lib.stem}.icd"] = str(lib)
            try:
                folder = _folder_for(entries)
            except OSError as e:
                result = Registration((), None, f"could not write an OpenCL vendor folder ({e})")
            else:
                env["OCL_ICD_VENDORS"] = str(folder)
                result = Registration(tuple(map(str, missing)), str(folder),
                                      f"OCL_ICD_VENDORS={folder}: {where}'s {len(entries) - len(missing)} "
                                      f"runtime(s) plus {', '.join(map(str, missing))}")
    if environ is None and libraries is None:
        _done = result
    return result


def registration() -> Registration | None:
    """What register() did in this process (None before it ran)."""
    return _done


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
