"""`clpt scenes`: the shipped scenes, each with its first comment line."""

from __future__ import annotations


def add_parser(sub):
    p = sub.add_parser("scenes", help="list the shipped scenes")
    p.set_defaults(func=run)
    return p


def run(a) -> int:
    from ..resources import scene_dir, shipped_scenes

    for name in shipped_scenes():
        first = (scene_dir() / f"{name}.toml").read_text().splitlines()[0].lstrip("# ").strip()
        print(f"{name:28s} {first}")
    return 0
