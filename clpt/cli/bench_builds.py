"""`clpt bench-builds`: cold and warm kernel builds per scene and device,
as a first render meets them (clpt/tools/bench.py)."""

from __future__ import annotations

from . import common


def add_parser(sub):
    p = sub.add_parser("bench-builds", help="cold and warm kernel builds of scenes per device, as a first "
                                            "render meets them")
    p.add_argument("scene", nargs="*", default=["all"], help="scenes ('all': every shipped scene, the default)")
    common.device(p, default="default",
                  help="comma list of devices to measure ('default': the device clpt render picks)")
    common.json(p)
    p.set_defaults(func=run)
    return p


def run(a) -> int:
    from ..tools.bench import run_bench_builds

    return run_bench_builds(a)
