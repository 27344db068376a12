"""Reading a scene file of either format: clpt's TOML (clpt.scene) or Mitsuba 3 XML (clpt.mitsuba)."""

from __future__ import annotations

from pathlib import Path

from .errors import SceneError
from .mitsuba import load_mitsuba
from .resources import scene_path
from .scene import Scene, _read_scene_text, parse_scene


def load_scene(path, params: dict | None = None, *, strict: bool = False) -> Scene:
    """Read a TOML scene file (or a shipped scene's name, e.g. "cornell_box"),
    or a Mitsuba 3 XML file (.xml, clpt.mitsuba): params then override its
    <default> values, and strict makes every SceneWarning an error."""
    p = Path(path)
    if p.suffix.lower() == ".xml":
        return load_mitsuba(p, params, strict=strict)
    if params:
        raise SceneError(f"{path}: parameters (-D NAME=VALUE) apply to Mitsuba XML scenes only")
    if not p.exists() and p.suffix == "" and len(p.parts) == 1:
        shipped = scene_path(str(path))
        if shipped is not None:
            p = shipped
    text = _read_scene_text(p, path)
    return parse_scene(text, source=str(path), base_dir=p.parent)
