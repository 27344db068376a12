"""`clpt bench`: samples/s, rays/s, kernel times, memory and builds per
scene, device and kernel variant (clpt/tools/bench.py)."""

from __future__ import annotations

from . import common


def add_parser(sub):
    p = sub.add_parser("bench", help="measure samples/s, rays/s and kernel build times")
    p.add_argument("scene", nargs="*", default=["cornell_box"], help="scenes to measure ('all': every shipped "
                                                                      "scene; default cornell_box)")
    common.size(p, 256, 256)
    common.max_depth(p, default=8)
    common.rounds(p, default=5, help="timed passes per configuration, taken in turn")
    p.add_argument("--no-cold", action="store_true", help="skip the cold-build measurement (a subprocess)")
    common.json(p, help="print the results as JSON (for --compare)")
    p.add_argument("--csv", action="store_true", help="print the results as CSV")
    p.add_argument("--compare", metavar="OLD.json", help="also print ratios against an earlier --json run")
    common.device(p, help="as for render; a comma list measures each device")
    p.add_argument("--lanes", default=None, help="paths per work-item, or a comma list to compare (auto,1,8,16)")
    p.add_argument("--local-size", default=None, help="work-group size, or a comma list (auto,16,64)")
    p.add_argument("--kernel", default="specialized", help="specialized, generic, or specialized,generic")
    p.add_argument("--precision", default="float", help="float, double, or float,double")
    p.add_argument("--mitsuba", action="store_true", help="also time Mitsuba 3's cornell_box() (if installed)")
    common.no_nee(p)
    common.sampler(p)
    p.set_defaults(func=run)
    return p


def run(a) -> int:
    from ..tools.bench import run_bench

    return run_bench(a)
