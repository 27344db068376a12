"""`clpt bench-denoise`: the cone filter and OIDN against a path-traced
reference: error, caustic energy, halos around lights, time
(clpt/tools/bench_denoise.py)."""

from __future__ import annotations

from . import common


def add_parser(sub):
    p = sub.add_parser("bench-denoise", help="the cone filter and OIDN against a path-traced reference: error, "
                                             "caustic energy, halos around lights, time")
    p.add_argument("scene", nargs="*", default=["cornell_box", "cornell_box_caustics"])
    common.size(p, 128, 128)
    p.add_argument("--spp", default="16,64", help="comma list")
    p.add_argument("--seeds", type=int, default=2)
    common.max_depth(p, default=64)
    common.ref_spp(p, default=4096)
    common.ref_dir(p)
    p.add_argument("--time-size", type=int, default=512, help="image size of the timing (0: no timing)")
    p.add_argument("--image", default=None, help="write raw | cone | OIDN | reference of the caustics box here")
    p.add_argument("--crops", default=None, help="write crops (raw | cone | OIDN | reference) around the mirror and "
                                                 "glass objects here: a path with {scene} and {spp}")
    common.device(p)
    common.json(p)
    p.set_defaults(func=run)
    return p


def run(a) -> int:
    from ..tools.bench_denoise import run_bench_denoise

    return run_bench_denoise(a)
