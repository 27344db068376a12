"""`clpt bench-photons`: photon pass, grid build and gather costs, and the
error of caustics at equal render time (clpt/tools/bench.py)."""

from __future__ import annotations

from . import common


def add_parser(sub):
    p = sub.add_parser("bench-photons", help="photon pass and grid build times, gather cost, and the error "
                                             "of caustics at equal render time")
    p.add_argument("scene", nargs="?", default="cornell_box_caustics")
    p.add_argument("--counts", type=common.counts, default=[100000, 1000000, 10000000],
                   help="photon counts to build (comma list; empty: none)")
    common.size(p, 128, 128)
    p.add_argument("--equal-time", type=common.seconds, default=None, metavar="SECONDS",
                   help="also compare errors at these render times (comma list)")
    common.reference(p, help="reference EXR: read if it exists, else rendered and saved")
    common.ref_spp(p)
    common.max_depth(p, default=64, help="path depth of the equal-time renders (default 64)")
    p.add_argument("--cpu-time", action="store_true",
                   help="equal CPU time of this process instead of equal wall time (for a machine shared with "
                        "other work)")
    p.add_argument("--methods", default=None,
                   help="equal-time methods to run (comma list of: path, default, trial, forced, first, "
                        "online, progressive, offline; default all)")
    common.device(p)
    common.json(p)
    p.set_defaults(func=run)
    return p


def run(a) -> int:
    from ..tools.bench import run_bench_photons

    return run_bench_photons(a)
