"""`clpt compare`: uniform and adaptive sampling and the denoisers rendered
for the same time, their errors against a path-traced reference
(clpt/tools/studies.py)."""

from __future__ import annotations

from . import common


def add_parser(sub):
    p = sub.add_parser("compare", help="uniform vs adaptive sampling vs the filter, at equal render time")
    p.add_argument("scene", nargs="+")
    p.add_argument("--seconds", type=float, default=4.0)
    common.size(p, 128, 128)
    common.ref_spp(p)
    common.ref_dir(p)
    common.device(p)
    common.json(p)
    p.set_defaults(func=run)
    return p


def run(a) -> int:
    import json

    from ..loading import load_scene
    from ..tools.reference import cached_path, reference_image
    from ..tools.studies import compare, format_table, standard_comparison

    out = {}
    for name in a.scene:
        scene = load_scene(name)
        ref = reference_image(scene, a.width, a.height, a.ref_spp,
                              cached_path(a.ref_dir, name, a.width, a.height, a.ref_spp), a.device)
        out[name] = compare(scene, standard_comparison(), ref=ref, seconds=a.seconds, width=a.width,
                            height=a.height, device=a.device)
    if a.json:
        print(json.dumps(out, indent=1, default=str))
    else:
        for name, rows in out.items():
            print(f"{name}, {a.seconds} s each:")
            print(format_table(rows, ("value", "seconds", "spp", "relmse", "rmse", "ssim", "flip")))
    return 0
