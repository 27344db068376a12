"""Where clpt's time goes on an environment-lit scene: one process, variants
interleaved round by round, path tracing (photons=False).

    python tests/profile_envmap.py [SCENE.xml] [--device intel] [--rounds 3] [--spp 16] [--res 128]
        [--variants default,no_nee,const,depth0,depth1,lanes1,lanes8,lanes16]

Per variant: Msamples per CPU second (best of the rounds) and trace_paths'
device time per sample (median of OpenCL profiling events). Variants:

  default      the tuner's lanes, next event estimation with MIS
  no_nee       Renderer(nee=False): BSDF sampling only (escapes see the map)
  const        the envmap replaced by a constant environment (radiance 1)
  depth0/1     max_depth 0 (camera rays and the map) and 1
  lanesN       Renderer(lanes=N)
  localN       Renderer(local_size=N)
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
VARIANTS = ("default", "no_nee", "const", "depth0", "depth1", "lanes1", "lanes8", "lanes16")


def constant_env(xml: Path) -> Path:
    """A copy of xml beside it with its envmap emitter made a constant one."""
    text = xml.read_text()
    out = xml.with_name(xml.stem + "_const.xml")
    out.write_text(re.sub(r'<emitter type="envmap">.*?</emitter>',
                          '<emitter type="constant"><rgb name="radiance" value="1, 1, 1"/></emitter>',
                          text, flags=re.S))
    return out


def main():
    import clpt

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(HERE / "data" / "env_spheres.xml"))
    ap.add_argument("--device", default=None)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    a = ap.parse_args()
    xml = Path(a.scene)
    params = {"res": str(a.res)}
    runs = {}
    for v in a.variants.split(","):
        if v not in VARIANTS and not v.startswith(("lanes", "local", "depth")):
            raise SystemExit(f"profile_envmap: unknown variant {v} (known: {', '.join(VARIANTS)}, localN)")
        kw = {"device": a.device, "photons": False}
        rkw = {}
        path = xml
        if v == "const":
            path = constant_env(xml)
        elif v == "no_nee":
            kw["nee"] = False
        elif v.startswith("lanes"):
            kw["lanes"] = int(v[5:])
        elif v.startswith("local"):
            kw["local_size"] = int(v[5:])
        elif v.startswith("depth"):
            rkw["max_depth"] = int(v[5:])
        sc = clpt.load_scene(path, params=params)
        if v == "const":
            path.unlink()
        r = clpt.Renderer(sc, **kw)
        r.render(1, seed=0, **rkw)
        runs[v] = {"r": r, "kw": rkw, "cpu": [], "kernel": [], "lanes": r.features.lanes}
    for i in range(a.rounds):
        for v, run in runs.items():
            c = time.process_time()
            res = run["r"].render(a.spp, seed=i + 1, pass_seconds=1e9, **run["kw"])
            run["cpu"].append(time.process_time() - c)
            run["pixels"] = res.image.shape[0] * res.image.shape[1]
            ks = res.stats.kernel_seconds.get("trace_paths", [])
            if ks:
                run["kernel"].append(sum(ks) / a.spp)
    print(f"{xml} at {a.res}x{a.res}, {a.spp} spp, best of {a.rounds} rounds, device {a.device}")
    print(f"{'variant':10} {'lanes':>5} {'Msamp/CPU-s':>12} {'kernel ms/spp':>14}")
    for v, run in runs.items():
        ms = max(run["pixels"] * a.spp / c / 1e6 for c in run["cpu"])
        k = statistics.median(run["kernel"]) * 1e3 if run["kernel"] else float("nan")
        print(f"{v:10} {run['lanes']:5d} {ms:12.3f} {k:14.2f}", flush=True)


if __name__ == "__main__":
    main()
