"""Where clpt's time goes on a scene of real complexity (tests/realscene.py's
gallery unless a file is given): one process, variants interleaved round by
round, path tracing (photons=False).

    python tests/profile_realscene.py [SCENE.xml] [--device intel] [--rounds 3] [--spp 8]
        [--variants default,depth0,depth1,no_nee,diffuse,lanes1,lanes8,lanes16,sah]

Per variant: Msamples per CPU second (best of the rounds), trace_paths'
device time per sample per pixel from OpenCL profiling events (median), rays
per sample (camera, bounce, shadow) and device Mrays/s. Variants:

  default      the tuner's lanes, LBVH, next event estimation
  depth0/1     max_depth 0 (camera rays and emission only) and 1 (one
               scattering event: the camera ray, its shadow ray, one bounce)
  no_nee       Renderer(nee=False): BSDF sampling only (the light sampler
               among 13 lights and its shadow rays left out)
  diffuse      every material replaced by a two-sided diffuse white
               (shading made trivial; the same geometry and lights)
  lanesN       Renderer(lanes=N)
  sah          Renderer(bvh_method="sah")

Also the BVH of each builder: binary nodes, leaves, depth, wide nodes and
the SAH cost (expected node visits plus primitive tests of a random ray
through the root, in units of a primitive test: Tree.sah_cost).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

VARIANTS = ("default", "depth0", "depth1", "no_nee", "diffuse", "lanes1", "lanes8", "lanes16", "sah")


def all_diffuse(xml: Path) -> Path:
    """A copy of xml beside it with every material reference made 'white'."""
    text = xml.read_text()
    out = xml.with_name(xml.stem + "_diffuse.xml")
    out.write_text(re.sub(r'<ref id="[A-Za-z0-9_]+"/>', '<ref id="white"/>', text))
    return out


def tree_stats(scene, method):
    from clpt import bvh as bvh_mod
    from clpt.pack import pack_scene

    t = time.perf_counter()
    p = pack_scene(scene, bvh_method=method)
    tree = p.bvh
    wide = bvh_mod.collapse(tree)
    return {"method": method, "pack_seconds": time.perf_counter() - t, "binary_nodes": tree.n_nodes,
            "leaves": tree.n_leaves, "depth": tree.depth(), "wide_nodes": wide.n_nodes, "wide_levels": wide.levels,
            "sah_cost": tree.sah_cost(), "primitives": p.primitives}


def main():
    import clpt

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=None)
    ap.add_argument("--device", default=None)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    if a.scene is None:
        import realscene
        xml = realscene.default_out() / "gallery.xml"
        if not xml.is_file():
            realscene.generate(xml.parent, log=lambda s: print(s, file=sys.stderr))
    else:
        xml = Path(a.scene)
    variants = a.variants.split(",")
    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        raise SystemExit(f"profile_realscene: unknown variants {bad} (known: {', '.join(VARIANTS)})")
    scene = clpt.load_scene(xml)
    runs = {}
    for v in variants:
        kw = {"device": a.device, "photons": False}
        sc, rkw = scene, {}
        if v == "diffuse":
            sc = clpt.load_scene(all_diffuse(xml))
        elif v == "no_nee":
            kw["nee"] = False
        elif v.startswith("lanes"):
            kw["lanes"] = int(v[5:])
        elif v == "sah":
            kw["bvh_method"] = "sah"
        elif v.startswith("depth"):
            rkw["max_depth"] = int(v[5:])
        r = clpt.Renderer(sc, **kw)
        r.render(1, seed=0, **rkw)  # first launch
        runs[v] = {"r": r, "kw": rkw, "cpu": [], "kernel": [], "rays": None, "lanes": r.features.lanes}
    for i in range(a.rounds):
        for v, run in runs.items():
            c = time.process_time()
            res = run["r"].render(a.spp, seed=i + 1, pass_seconds=1e9, **run["kw"])
            run["cpu"].append(time.process_time() - c)
            n = res.image.shape[0] * res.image.shape[1]
            run["pixels"] = n
            ks = res.stats.kernel_seconds.get("trace_paths", [])
            if ks:
                run["kernel"].append(sum(ks) / a.spp)
            s = res.stats
            run["rays"] = {"camera": s.camera_rays / n / a.spp, "bounce": s.bounce_rays / n / a.spp,
                           "shadow": s.shadow_rays / n / a.spp}
            run["rays_total"] = s.rays
            run["kernel_total"] = sum(ks)
    rows = []
    print(f"{xml} ({a.spp} spp, best of {a.rounds} rounds; device time of trace_paths per spp)")
    print(f"{'variant':10} {'lanes':>5} {'Msamp/CPU-s':>12} {'kernel ms/spp':>14} {'camera':>7} {'bounce':>7} "
          f"{'shadow':>7} {'Mrays/dev-s':>11}")
    for v, run in runs.items():
        row = {"variant": v, "lanes": run["lanes"],
               "msamples_per_cpu_s": max(run["pixels"] * a.spp / c / 1e6 for c in run["cpu"]),
               "kernel_ms_per_spp": statistics.median(run["kernel"]) * 1e3 if run["kernel"] else float("nan"),
               "rays_per_sample": run["rays"],
               "mrays_per_device_s": run["rays_total"] / run["kernel_total"] / 1e6 if run["kernel_total"] else
               float("nan")}
        rows.append(row)
        rp = row["rays_per_sample"]
        print(f"{v:10} {row['lanes']:5d} {row['msamples_per_cpu_s']:12.3f} {row['kernel_ms_per_spp']:14.1f} "
              f"{rp['camera']:7.2f} {rp['bounce']:7.2f} {rp['shadow']:7.2f} {row['mrays_per_device_s']:11.2f}")
    trees = [tree_stats(scene, m) for m in ("lbvh", "sah")]
    for t in trees:
        print(f"BVH {t['method']}: {t['primitives']} primitives, {t['binary_nodes']} binary nodes, {t['leaves']} "
              f"leaves, depth {t['depth']}, {t['wide_nodes']} wide nodes in {t['wide_levels']} levels, SAH cost "
              f"{t['sah_cost']:.1f}, pack {t['pack_seconds']:.2f} s")
    if a.json:
        Path(a.json).write_text(json.dumps({"rows": rows, "trees": trees}, indent=1))


if __name__ == "__main__":
    main()
