"""The host's files and memory, as clpt's readers and preflight checks see them."""

from __future__ import annotations

import os
import resource
import stat
from pathlib import Path

from .errors import SceneError


def open_regular_file(p: Path, name, what: str, limit: int | None = None):
    """The file open for reading in binary, checked first: it exists, is a
    regular file (a FIFO or a device would block or never end) and has at
    most `limit` bytes. Every failure is a one-line SceneError naming the
    file as `name`."""
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise SceneError(f"{name}: no such {what}") from None
    except OSError as e:
        raise SceneError(f"{name}: cannot read the {what}: {e.strerror or e}") from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise SceneError(f"{name}: is a folder, not a {what}")
        if not stat.S_ISREG(st.st_mode):
            raise SceneError(f"{name}: not a regular file (a pipe or device); save the {what} to a file")
        if limit is not None and st.st_size > limit:
            raise SceneError(f"{name}: {st.st_size} bytes is too large for a {what} (at most {limit >> 20} MiB)")
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def available_host_bytes() -> int | None:
    """What this process may still allocate: the least of the memory the
    system has available, the cgroup's limit and the address-space limit."""
    limits = []
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    limits.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError):
        pass
    try:
        mx = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if mx != "max":
            cur = int(Path("/sys/fs/cgroup/memory.current").read_text())
            limits.append(int(mx) - cur)
    except (OSError, ValueError):
        pass
    try:
        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY:
            vm = 0
            with open("/proc/self/status") as f:
                for line in f:
                    if line.startswith("VmSize:"):
                        vm = int(line.split()[1]) * 1024
            limits.append(soft - vm)
    except (OSError, ValueError):
        pass
    return max(0, min(limits)) if limits else None

