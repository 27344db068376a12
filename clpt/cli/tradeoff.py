"""`clpt tradeoff`: every speed/accuracy knob swept against a path-traced
reference; tables, plots and a markdown summary (clpt/tools/studies.py)."""

from __future__ import annotations

import sys
from pathlib import Path

from . import common


def add_parser(sub):
    p = sub.add_parser("tradeoff", help="sweep every speed/accuracy knob; tables, plots and a summary")
    p.add_argument("scene", nargs="+", help="scenes, or 'all' for the shipped ones")
    p.add_argument("--out", default="tradeoff", help="output folder (one subfolder per scene, README.md)")
    common.size(p, 64, 64)
    common.spp(p, default=64)
    common.ref_spp(p)
    common.reference(p, help="reference EXR (one scene); default: rendered and cached")
    p.add_argument("--compare-seconds", type=float, default=0.0,
                   help="also run the equal-time comparison for this long per method")
    common.device(p)
    p.set_defaults(func=run)
    return p


def run(a) -> int:
    from ..resources import shipped_scenes
    from ..loading import load_scene
    from ..tools.reference import reference_image
    from ..tools.studies import compare, standard_comparison, tradeoff, write_summary

    names = shipped_scenes() if a.scene == ["all"] else a.scene
    summaries, comparisons = [], {}
    for name in names:
        print(f"{name}:", file=sys.stderr)
        sub_dir = Path(a.out) / Path(name).stem
        summaries.append(tradeoff(name, out_dir=sub_dir, width=a.width, height=a.height, spp=a.spp,
                                  ref_spp=a.ref_spp, reference=a.reference, device=a.device,
                                  log=lambda m: print(m, file=sys.stderr)))
        if a.compare_seconds > 0:  # against the sweep's reference (read back: it was saved)
            ref_path = (Path(a.reference) if a.reference
                        else sub_dir / f"reference_{a.width}x{a.height}_{a.ref_spp}spp.exr")
            ref = reference_image(load_scene(name), a.width, a.height, a.ref_spp, ref_path, a.device)
            comparisons[name] = compare(load_scene(name), standard_comparison(), ref=ref, seconds=a.compare_seconds,
                                        width=a.width, height=a.height, device=a.device)
    command = "clpt tradeoff " + " ".join(a.scene) + f" --out {a.out} --width {a.width} --height {a.height} " \
              f"--spp {a.spp} --ref-spp {a.ref_spp}" + (f" --compare-seconds {a.compare_seconds}"
                                                       if a.compare_seconds else "")
    write_summary(a.out, summaries, comparisons or None, command)
    print(f"wrote {Path(a.out) / 'README.md'}", file=sys.stderr)
    return 0
