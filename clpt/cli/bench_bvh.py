"""`clpt bench-bvh`: BVH build time, memory and rays/s on generated meshes;
plain loops against the BVH; scene setup time; a race with Mitsuba 3
(clpt/tools/bench.py)."""

from __future__ import annotations

from . import common


def add_parser(sub):
    p = sub.add_parser("bench-bvh", help="BVH build time, memory and rays/s for generated meshes; plain loops "
                                          "vs BVH; scene setup time")
    p.add_argument("--triangles", type=common.counts, default=[1000, 100000, 1000000],
                   help="mesh sizes (comma list; empty: none)")
    p.add_argument("--methods", default="sah,lbvh", help="BVH builders to compare (comma list)")
    p.add_argument("--walks", default="hybrid", help="BVH traversals to compare (comma list): hybrid (packets "
                                                     "for coherent camera rays, the default) and lane (every ray "
                                                     "alone)")
    common.size(p, 128, 128)
    common.max_depth(p, default=8)
    common.rounds(p, default=3)
    p.add_argument("--threshold", action="store_true", help="also measure plain loops against the BVH")
    p.add_argument("--setup", default=None, metavar="TRIANGLES", help="also time scene setup for this many")
    p.add_argument("--mitsuba", default=None, metavar="MESH", help="also race Mitsuba 3 (llvm_ad_rgb; pip install "
                                                                  "mitsuba) on this mesh in the Cornell box")
    common.device(p)
    common.json(p)
    p.set_defaults(func=run)
    return p


def run(a) -> int:
    from ..tools.bench import run_bench_bvh

    return run_bench_bvh(a)
