"""Where the kernel sources and shipped scenes are, in a source checkout or an
installed package (the wheel carries kernels/ and scenes/ as clpt/kernels and
clpt/scenes), and where clpt's cache is."""

from __future__ import annotations

import contextlib
import importlib.resources
import os
from pathlib import Path


def _data_dir(name: str) -> Path:
    here = Path(__file__).resolve().parent
    for d in (here / name, here.parent / name):  # installed, then source checkout
        if d.is_dir():
            return d
    # An editable install maps clpt.<name> onto the checkout's folder (or has no such package).
    with contextlib.suppress(ModuleNotFoundError, TypeError):
        d = Path(str(importlib.resources.files(f"clpt.{name}")))
        if d.is_dir():
            return d
    raise FileNotFoundError(f"clpt cannot find its {name}/ folder next to {here}; reinstall clpt")


def kernel_dir() -> Path:
    return _data_dir("kernels")


def scene_dir() -> Path:
    return _data_dir("scenes")


def scene_path(name: str) -> Path | None:
    """A shipped scene by name ("cornell_box" or "cornell_box.toml"), or None."""
    p = scene_dir() / (name if name.endswith(".toml") else name + ".toml")
    return p if p.is_file() else None


def shipped_scenes() -> list[str]:
    return sorted(p.stem for p in scene_dir().glob("*.toml"))


def cache_dir() -> Path:
    """Where clpt caches kernel builds, device checks and tunings (CLPT_CACHE_DIR, else the user's cache folder)."""
    env = os.environ.get("CLPT_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "clpt"
