"""Textures measured (tests/data/cbox_textured.xml, 64x64):

    python tests/bench_textures.py [--device intel|pocl] [--spp N] [--mitsuba]

1. the cost of CLPT_HAS_TEXTURES on a scene that has textures: the textured
   box against the same box with each texture replaced by its mean colour
   (Mitsuba's Texture::mean: what clpt rendered before it read textures), in
   samples/s (each renderer's second render: no compilation counted), and
   how far the mean-colour image is from Mitsuba's reference (so the
   reference test tells the two apart);
2. with --mitsuba (run by Mitsuba's Python, which has clpt importable):
   samples/s of Mitsuba 3 LLVM (llvm_ad_rgb) on the same scene in the same run.
"""

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
XML = HERE / "data" / "cbox_textured.xml"
RES = 64


def untextured(scene):
    """The scene with each texture replaced by its mean colour."""
    import clpt

    shapes = []
    for s in scene.shapes:
        m = scene.resolve_material(s.material)
        if m.textures:
            fields = {}
            for slot, t in m.textures:
                key = {"reflectance": "kp" if m.plastic else "kd", "specular": "km" if max(m.km) > 0 else "kr"}[slot]
                fields[key] = t.mean()
            s = dataclasses.replace(s, material=clpt.Material(**{**{f.name: getattr(m, f.name)
                                                                    for f in dataclasses.fields(m)},
                                                                 **fields, "textures": ()}))
        shapes.append(s)
    return dataclasses.replace(scene, shapes=shapes)


def clpt_rate(scene, device, spp, repeats=3):
    import clpt

    r = clpt.Renderer(scene, device=device, photons=False)
    r.render(spp=spp, seed=1, width=RES, height=RES)
    best, res = None, None
    for k in range(repeats):
        t = time.perf_counter()
        res = r.render(spp=spp, seed=2 + k, width=RES, height=RES)
        dt = time.perf_counter() - t
        best = dt if best is None else min(best, dt)
    return RES * RES * spp / best, res, r.features


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default=None)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--mitsuba", action="store_true")
    a = ap.parse_args()
    import clpt

    sys.path.insert(0, str(HERE))
    import stats

    ref = json.loads((HERE / "data" / "cbox_textured_mitsuba.json").read_text())
    scene = clpt.load_scene(XML, params={"res": RES})
    out = {}
    for name, sc in (("textured", scene), ("mean colours", untextured(scene))):
        rate, res, feats = clpt_rate(sc, a.device, a.spp)
        e, z = stats.compare_to_reference(res, ref)
        out[name] = rate
        print(f"clpt {name:13s} textures={int(feats.textures)}: {rate / 1e6:.3f} Msamples/s; vs Mitsuba: mean "
              f"{e:.2%} off, worst block {np.abs(z).max():.1f} sigma ({a.spp} spp)")
    print(f"cost of the textures: {1 - out['textured'] / out['mean colours']:.1%} of the samples/s")
    if a.mitsuba:
        import mitsuba as mi

        mi.set_variant("llvm_ad_rgb")
        ms = mi.load_file(str(XML), res=RES)
        np.array(mi.render(ms, spp=a.spp, seed=1))
        t = time.perf_counter()
        np.array(mi.render(ms, spp=a.spp, seed=2))
        rate = RES * RES * a.spp / (time.perf_counter() - t)
        print(f"Mitsuba {mi.__version__} llvm_ad_rgb: {rate / 1e6:.3f} Msamples/s; clpt textured / Mitsuba: "
              f"{out['textured'] / rate:.2f}x")


if __name__ == "__main__":
    main()
