"""Bit-identity check for kernel refactors: render every shipped scene in a
set of variants, save everything a render returns, and later compare a new
tree's renders with the saved ones, bit for bit.

    python tests/bitident.py save before-intel.npz --device intel     # with the old tree installed
    python tests/bitident.py compare before-intel.npz --device intel  # with the new one

Only the public API is used (clpt.Renderer and its render keywords), so the
same script runs against an older tree. Variants: the defaults, lanes 1, 8
and 16, the generic build, double precision, feature buffers with the cone
filter (aux sums and filtered image), and for scenes with caustic photons
each photon mode (merge, online, offline) over two progressive photon maps,
plus both adaptive schemes (pixel lists, per-pixel depths). Each variant
keeps the image, per-pixel counts and variances, the caustic buffer, the
feature images, the filtered image and the ray counts. A differing image is
also measured against its noise (the standard error of each pixel's mean). Builds go to a cache
of their own (CLPT_CACHE_DIR, default /tmp/clpt-bitident-cache), keyed by
source as always, so a changed kernel is always rebuilt.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("CLPT_CACHE_DIR", "/tmp/clpt-bitident-cache")
os.environ.setdefault("CLPT_TUNE", "query")  # defaults from device queries, never trial renders

import numpy as np  # noqa: E402

SIZE = 48
SPP = 8


def variants(caustic: bool):
    """(name, Renderer keywords, render keywords)."""
    from clpt import AdaptiveSettings, FilterSettings, PhotonSettings
    out = [("default", {}, {}),
           ("lanes1", {"lanes": 1}, {}),
           ("lanes8", {"lanes": 8}, {}),
           ("lanes16", {"lanes": 16}, {}),
           ("generic", {"kernel": "generic"}, {}),
           ("double", {"precision": "double", "lanes": 8}, {}),
           ("filter", {}, {"filter": FilterSettings()}),
           ("filter_through", {}, {"filter": FilterSettings(), "aux_specular": "through"}),
           ("adaptive_error", {}, {"spp": 16, "adaptive": AdaptiveSettings(min_spp=4, pass_spp=4)}),
           ("adaptive_paper", {}, {"spp": 16, "adaptive": AdaptiveSettings(scheme="paper", min_spp=4, pass_spp=4)})]
    if caustic:
        for mode in ("merge", "online", "offline"):
            # Offline gathers need a fixed map (a progressive render gathers online).
            p = PhotonSettings(mode=mode, spp_per_map=8, offline_spp=4, progressive=mode != "offline",
                               count=20000 if mode == "offline" else None, pilot=False)
            out.append((f"photons_{mode}", {}, {"spp": 16, "photons": p}))
        out.append(("photons_filter", {}, {"spp": 16, "filter": FilterSettings(),
                                           "photons": PhotonSettings(spp_per_map=8, pilot=False)}))
        out.append(("photons_lanes1", {"lanes": 1}, {"spp": 16, "photons": PhotonSettings(spp_per_map=8, pilot=False)}))
        out.append(("photons_merge_budget", {"lanes": 16}, {"photons": PhotonSettings(
            budget=4, merge_probability=0.5, merge_vertices=1, aim="equal", pilot=False)}))
    return out


def arrays(res) -> dict:
    out = {"image": res.image, "count": res.sample_count, "lum_var": res.lum_var,
           "rays": np.array([res.stats.nonfinite, res.stats.camera_rays, res.stats.bounce_rays,
                             res.stats.shadow_rays], dtype=np.int64)}
    if res.caustic_image is not None:
        out["caustic"] = res.caustic_image
    if res.filtered is not None:
        out["filtered"] = res.filtered
    for k, v in (res.aux or {}).items():
        out[f"aux_{k}"] = np.asarray(v)
    return out


def render_all(device, scenes, only=None):
    import clpt
    from clpt.resources import shipped_scenes
    out = {}
    for name in scenes or shipped_scenes():
        caustic = clpt.Renderer(name, device=device, lanes=1).features.photons
        for vname, rkw, kw in variants(caustic):
            if only and vname not in only:
                continue
            t0 = time.perf_counter()
            r = clpt.Renderer(name, device=device, **rkw)
            res = r.render(**{"spp": SPP, "width": SIZE, "height": SIZE, "seed": 7, **kw})
            for k, v in arrays(res).items():
                out[f"{name}/{vname}/{k}"] = v
            print(f"{name:34s} {vname:22s} lanes={r.features.lanes:2d} {time.perf_counter() - t0:5.1f} s",
                  file=sys.stderr, flush=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=("save", "compare"))
    ap.add_argument("file")
    ap.add_argument("--device", default=None)
    ap.add_argument("--scenes", default="", help="comma list (default: every shipped scene)")
    ap.add_argument("--variants", default="", help="comma list (default: all)")
    a = ap.parse_args(argv)
    scenes = [s for s in a.scenes.split(",") if s]
    only = {v for v in a.variants.split(",") if v}
    got = render_all(a.device, scenes, only)
    if a.what == "save":
        np.savez_compressed(a.file, **got)
        print(f"saved {len(got)} arrays to {a.file}")
        return 0
    before = np.load(a.file)
    bad, same = [], 0
    rows = {}
    for k, v in got.items():
        scene, variant, _ = k.split("/")
        ok = k in before and before[k].shape == v.shape and np.array_equal(before[k], v, equal_nan=True)
        rows.setdefault((scene, variant), []).append(ok)
        if ok:
            same += 1
        else:
            bad.append(k)
    for (scene, variant), oks in rows.items():
        print(f"{scene:34s} {variant:22s} {'identical' if all(oks) else 'DIFFERENT'}")
    for k in bad:
        if k in before and before[k].shape == got[k].shape:
            d = np.abs(before[k].astype(np.float64) - got[k].astype(np.float64))
            noise = ""
            base = k[:-len("image")]
            if k.endswith("/image") and base + "lum_var" in before:
                # Against the noise: the standard error of each pixel's mean (luminance's, from the sums).
                se = np.sqrt(before[base + "lum_var"] / np.maximum(before[base + "count"], 1))
                z = d.max(axis=-1) / np.where(se > 0, se, np.inf)
                noise = f", at most {z.max():.2g} standard errors of the pixel's mean"
            print(f"  {k}: max |diff| {d.max():.3g}, {np.count_nonzero(d)} of {d.size} differ{noise}")
        else:
            print(f"  {k}: missing before or shape changed")
    print(f"{same} of {len(got)} arrays bit-identical")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
