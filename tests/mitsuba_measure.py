"""Measure, with Mitsuba 3 itself, the numbers tests/test_mitsuba.py expects.

Mitsuba is never a dependency of clpt; this script is how the expected values
in the tests (and clpt/data/mitsuba_ior.json) were produced:

    pip install mitsuba            # 3.9.1 when these were measured
    python tests/mitsuba_measure.py            # prints the values for the tests
    python tests/mitsuba_measure.py --ior-json clpt/data/mitsuba_ior.json
    python tests/mitsuba_measure.py --compare tests/data/cbox_mesh.xml res=64   # images side by side
    MI_VARIANT=llvm_ad_rgb python tests/mitsuba_measure.py --albedo            # BSDF albedos
    python tests/mitsuba_measure.py --normals tests/data/mitsuba_normals.json  # computed vertex normals
    MI_VARIANT=llvm_ad_rgb python tests/mitsuba_measure.py --reference tests/data/cbox_blob.xml \
        tests/data/cbox_blob_mitsuba.json spp=16384                         # a render's block means
    MI_VARIANT=llvm_ad_rgb python tests/mitsuba_measure.py --reference tests/data/cbox_lamp_gaussian.xml \
        tests/data/cbox_lamp_gaussian_mitsuba.json spp=16384
    MI_VARIANT=llvm_ad_rgb python tests/mitsuba_measure.py --reference tests/data/cbox_textured.xml \
        tests/data/cbox_textured_mitsuba.json spp=8192                      # textures (tests/texgen.py first)
    MI_VARIANT=llvm_ad_rgb python tests/mitsuba_measure.py --reference tests/data/brushed.xml \
        tests/data/brushed_mitsuba.json spp=16384                          # anisotropic roughness
    MI_VARIANT=llvm_ad_rgb python tests/mitsuba_measure.py --reference tests/data/cbox_textured_lights.xml \
        tests/data/cbox_textured_lights_mitsuba.json spp=4096               # textured area lights
    MI_VARIANT=llvm_ad_rgb python tests/mitsuba_measure.py --reference tests/data/spot_texture.xml \
        tests/data/spot_texture_mitsuba.json spp=8192                       # a textured spot light
    MI_VARIANT=llvm_ad_rgb python tests/mitsuba_measure.py --reference tests/data/smooth_bumpy.xml \
        tests/data/smooth_bumpy_mitsuba.json spp=8192                       # tilted shading normals
"""

import json
import os
import sys

import mitsuba as mi

# MI_VARIANT=llvm_ad_rgb for --compare: Mitsuba's LLVM backend needs LLVM 16 or newer
# (DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 after apt-get install libllvm19).
mi.set_variant(os.environ.get("MI_VARIANT", "scalar_rgb") if {"--compare", "--albedo", "--reference"} & set(sys.argv)
               else "scalar_rgb")

# Spectra as the tests give them: (value attribute, inside an emitter?).
SPECTRA = {
    "refl_ramp": ("400:0.343, 404:0.445, 500:0.5, 600:0.6, 700:0.65", False),
    "refl_narrow": ("550:0.2, 560:0.9, 570:0.2", False),
    "refl_gamut": ("450:0.9, 460:0.05, 600:0.05, 610:0.9", False),
    "emit_ramp": ("400:1, 500:8, 600:15.6, 700:18.4", True),
    "emit_line": ("500:0, 550:10, 600:0", True),
    "emit_const": ("3", True),
}

IORS = ["vacuum", "helium", "hydrogen", "air", "carbon dioxide", "water", "acetone", "ethanol",
        "carbon tetrachloride", "glycerol", "benzene", "silicone oil", "bromine", "water ice", "fused quartz",
        "pyrex", "acrylic glass", "polypropylene", "bk7", "sodium chloride", "amber", "pet", "diamond"]
CONDUCTORS = ["a-C", "Ag", "Al", "AlAs", "AlSb", "Au", "Be", "Cr", "CsI", "Cu", "Cu2O", "CuO", "d-C", "Hg", "HgTe",
              "Ir", "K", "Li", "MgO", "Mo", "Na_palik", "Nb", "Ni_palik", "Rh", "Se", "SiC", "SnTe", "Ta", "Te",
              "ThF4", "TiC", "TiN", "TiO2", "VC", "V_palik", "VN", "W"]


def spectra():
    xml = '<scene version="3.0.0">'
    for k, (v, em) in SPECTRA.items():
        if em:
            xml += (f'<shape type="rectangle" id="{k}"><emitter type="area">'
                    f'<spectrum name="radiance" value="{v}"/></emitter></shape>')
        else:
            xml += (f'<shape type="rectangle" id="{k}"><bsdf type="diffuse">'
                    f'<spectrum name="reflectance" value="{v}"/></bsdf></shape>')
    p = mi.traverse(mi.load_string(xml + "</scene>"))
    out = {}
    for k, (_, em) in SPECTRA.items():
        v = p[f"{k}.emitter.radiance.value" if em else f"{k}.bsdf.reflectance.value"]
        out[k] = [round(float(c), 6) for c in v]
    return out


def transforms_and_camera():
    s = mi.load_string("""<scene version="3.0.0">
        <shape type="rectangle" id="r"><transform name="to_world">
            <scale x="2"/><translate x="1"/><rotate z="1" angle="90"/></transform></shape>
        <sensor type="perspective" id="cam"><float name="fov" value="40"/><string name="fov_axis" value="diagonal"/>
            <film type="hdrfilm"><integer name="width" value="200"/><integer name="height" value="100"/></film>
        </sensor>
        <sensor type="perspective" id="cam50">
            <film type="hdrfilm"><integer name="width" value="300"/><integer name="height" value="200"/></film>
        </sensor></scene>""")
    p = mi.traverse(s)
    m = [[round(float(p["r.to_world"].matrix[i][j]), 6) for j in range(4)] for i in range(4)]
    return {"rect_to_world": m, "x_fov_diag40_200x100": round(float(p["cam.x_fov"]), 5),
            "x_fov_50mm_300x200": round(float(p["cam50.x_fov"]), 5)}


def conductor_spectra():
    """Spectra for eta and k are unbounded and D65-weighted; reflectances bounded."""
    b = mi.load_string('<bsdf version="3.0.0" type="conductor"><spectrum name="eta" value="400:0.2, 700:1.3"/>'
                       '<spectrum name="k" value="400:3.5, 700:2.0"/>'
                       '<spectrum name="specular_reflectance" value="400:0.5, 700:1.0"/></bsdf>')
    p = mi.traverse(b)
    return {k: [round(float(c), 6) for c in p[f"{k}.value"]] for k in ("eta", "k", "specular_reflectance")}


def albedos():
    """Cosine-weighted hemispherical albedos of Mitsuba's diffuse and specular
    parts (the mean sample weight over 64 incidence angles, 2^18 samples each;
    needs a vectorized variant: MI_VARIANT=llvm_ad_rgb ... --albedo)."""
    import drjit as dr
    import numpy as np

    mus = (np.arange(64) + 0.5) / 64
    flags = {"diffuse": mi.BSDFFlags.DiffuseReflection,
             "specular": mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.GlossyReflection}
    out = {}
    kinds = {"plastic": {"diffuse_reflectance": {"type": "rgb", "value": [0.8, 0.4, 0.2]}},
             "roughplastic": {"diffuse_reflectance": {"type": "rgb", "value": [0.8, 0.4, 0.2]}},
             "thindielectric": {}, "conductor": {"material": "Au"}, "roughconductor": {"material": "Au"}}
    for t, extra in kinds.items():
        b = mi.load_dict({"type": t, **extra})
        for part, mask in flags.items():
            vals = []
            for mu in mus:
                n = 1 << 18
                si = dr.zeros(mi.SurfaceInteraction3f, n)
                si.wi = mi.Vector3f(float(np.sqrt(1 - mu * mu)), 0.0, float(mu))
                si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
                rng = mi.PCG32(n)
                _, w = b.sample(mi.BSDFContext(mi.TransportMode.Radiance, int(mask)), si, rng.next_float32(),
                                mi.Point2f(rng.next_float32(), rng.next_float32()))
                vals.append([float(np.mean(np.array(c))) for c in (w.x, w.y, w.z)])
            out[f"{t}_{part}"] = [round(float(v), 4) for v in 2 * np.mean(np.array(vals) * mus[:, None], axis=0)]
    return out


def ior_table():
    out = {"ior": {}, "conductor": {}}
    for n in IORS:
        b = mi.load_dict({"type": "dielectric", "int_ior": n, "ext_ior": 1.0})
        out["ior"][n] = round(float(mi.traverse(b)["eta"]), 6)
    for n in CONDUCTORS:
        p = mi.traverse(mi.load_dict({"type": "conductor", "material": n}))
        out["conductor"][n] = {"eta": [round(float(c), 6) for c in p["eta.value"]],
                               "k": [round(float(c), 6) for c in p["k.value"]]}
    return out


def compare(xml, params, res=64, spp=256):
    """Render one XML file in Mitsuba and clpt; print image means, 8x8-pixel
    block differences and samples/s (each renderer's second render, so that
    neither's kernel compilation counts)."""
    import time

    import numpy as np

    import clpt

    params = {**params, "spp": str(spp)}
    scene = mi.load_file(xml, **params)
    np.array(mi.render(scene, spp=spp, seed=1))
    t = time.perf_counter()
    img_m = np.array(mi.render(scene, spp=spp))[..., :3]
    tm = time.perf_counter() - t
    r = clpt.Renderer(clpt.load_scene(xml, params=params))
    r.render(width=res, height=res, seed=1)
    t = time.perf_counter()
    img_c = r.render(width=res, height=res).image
    tc = time.perf_counter() - t
    print(f"{xml}, {res}x{res}, {spp} spp; Mitsuba {mi.__version__} {mi.variant()}, clpt on "
          f"{r.devices[0].label}")
    for name, img, secs in (("mitsuba", img_m, tm), ("clpt", img_c, tc)):
        print(f"{name:8s} mean {np.round(img.mean(axis=(0, 1)), 5)}  {secs:.1f} s  "
              f"{res * res * spp / secs / 1e3:.0f} ksamples/s")
    b = res // 8
    bm, bc = (im.reshape(8, b, 8, b, 3).mean(axis=(1, 3)) for im in (img_m, img_c))
    rel = np.abs(bm - bc) / np.maximum(bm, 1e-3)
    print(f"image means differ by {np.abs(img_c.mean((0, 1)) / img_m.mean((0, 1)) - 1).max():.2%}; "
          f"8x8-pixel blocks by {np.median(rel):.2%} (median), {np.percentile(rel, 90):.2%} (90th percentile)")


LUMINANCE = (0.2126, 0.7152, 0.0722)


def reference(xml, out, spp=16384, block=16, per_pass=512, params=None):
    """A Mitsuba render of an XML scene, stored small for a test: two
    independent halves of spp samples per pixel each (passes of per_pass
    samples with seeds of their own), kept as the whole image's mean colour
    and the block x block-pixel block means of luminance, with each block's
    variance estimated from the halves' pixel differences ((a - b)^2 / 4 per
    pixel of the average, summed over the block's pixels: a few hundred
    degrees of freedom, where the two block means alone would give one), and
    the same for the image's outermost ring of pixels (where a filter meets
    the film's edge)."""
    import time

    import numpy as np

    t0 = time.perf_counter()
    scene = mi.load_file(xml, **(params or {}))
    halves = []
    for h in range(2):
        acc = 0.0
        for k in range(spp // per_pass):
            acc = acc + np.array(mi.render(scene, spp=per_pass, seed=1 + h * 100000 + k), dtype=np.float64)[..., :3]
        halves.append(acc / (spp // per_pass))
    a, b = halves
    img = 0.5 * (a + b)
    lum = lambda im: im @ np.array(LUMINANCE)  # noqa: E731
    h, w = img.shape[:2]
    blocks = lambda x: x.reshape(h // block, block, w // block, block).sum(axis=(1, 3)) / block ** 2  # noqa: E731
    var = blocks((lum(a) - lum(b)) ** 2 / 4) / block ** 2
    ring = np.ones((h, w), dtype=bool)
    ring[1:-1, 1:-1] = False
    ring_var = float(((lum(a) - lum(b)) ** 2 / 4)[ring].sum() / ring.sum() ** 2)
    doc = {"_source": f"Mitsuba {mi.__version__} {mi.variant()}: python tests/mitsuba_measure.py --reference {xml} "
                      f"{out} spp={spp} (two halves of {spp} spp, {time.perf_counter() - t0:.0f} s)",
           "scene": os.path.basename(xml), "params": params or {}, "width": w, "height": h, "spp_per_half": spp,
           "block": block, "mean_rgb": [round(float(c), 7) for c in img.reshape(-1, 3).mean(axis=0)],
           "mean_rgb_halves": [[round(float(c), 7) for c in x.reshape(-1, 3).mean(axis=0)] for x in halves],
           "block_luminance": np.round(blocks(lum(img)), 7).tolist(),
           "block_luminance_var": [[float(f"{x:.4g}") for x in row] for row in var],
           "ring_luminance": round(float(lum(img)[ring].mean()), 7), "ring_luminance_var": float(f"{ring_var:.4g}")}
    with open(out, "w") as f:
        f.write(json.dumps(doc, indent=1) + "\n")
    print(json.dumps({k: v for k, v in doc.items() if not k.startswith("block")}, indent=1))


def mesh_normals(out):
    """The vertex normals Mitsuba computes for meshes without them (and reads
    from those with them), for tests/test_mitsuba_meshes.py: each mesh's
    positions, triangles and normals after a to_world with a non-uniform scale
    (angles, and so the weights, change under it), the blob OBJ also mirrored,
    and every shape of the serialized seed files."""
    import numpy as np

    here = os.path.dirname(os.path.abspath(__file__))
    data = os.path.join(here, "data")
    to_world = [[0.4, 0.1, 0.0, 0.3], [0.0, 0.34, 0.05, -0.6], [-0.1, 0.0, 0.36, 0.2], [0, 0, 0, 1]]
    mirror = [[-1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1]]
    cases = {"blob_obj": ("obj", "cbox/blob.obj", {}, to_world),
             "blob_obj_mirrored": ("obj", "cbox/blob.obj", {}, mirror),
             "blob_obj_face_normals": ("obj", "cbox/blob.obj", {"face_normals": True}, to_world)}
    for name in ("shapes_v4", "shapes_v3"):
        for i in range(3 if name == "shapes_v4" else 2):
            cases[f"{name}_{i}"] = ("serialized", f"serialized/{name}.serialized", {"shape_index": i}, to_world)
    result = {"_source": f"Mitsuba {mi.__version__} scalar_rgb: python tests/mitsuba_measure.py --normals {out}"}
    for key, (kind, file, extra, m) in cases.items():
        shape = mi.load_dict({"type": kind, "filename": os.path.join(data, file),
                              "to_world": mi.ScalarTransform4f(m), **extra})
        result[key] = {"type": kind, "filename": file, **extra, "to_world": m,
                       "vertices": np.round(np.array(shape.vertex_positions_buffer()).reshape(-1, 3), 6).tolist(),
                       "triangles": np.array(shape.faces_buffer()).reshape(-1, 3).tolist(),
                       "normals": (np.round(np.array(shape.vertex_normals_buffer()).reshape(-1, 3), 6).tolist()
                                   if shape.has_vertex_normals() else None)}
    with open(out, "w") as f:
        f.write(json.dumps(result) + "\n")
    print(f"{out}: {', '.join(k for k in result if not k.startswith('_'))}")


if __name__ == "__main__":
    if len(sys.argv) >= 3 and sys.argv[1] == "--compare":
        # python tests/mitsuba_measure.py --compare tests/data/cbox_mesh.xml res=64
        compare(sys.argv[2], dict(a.split("=", 1) for a in sys.argv[3:]),
                res=int(dict(a.split("=", 1) for a in sys.argv[3:]).get("res", 64)))
    elif len(sys.argv) >= 4 and sys.argv[1] == "--reference":
        # MI_VARIANT=llvm_ad_rgb python tests/mitsuba_measure.py --reference tests/data/cbox_blob.xml \
        #     tests/data/cbox_blob_mitsuba.json spp=16384
        kw = dict(a.split("=", 1) for a in sys.argv[4:])
        reference(sys.argv[2], sys.argv[3], spp=int(kw.pop("spp", 16384)), params=kw)
    elif len(sys.argv) == 3 and sys.argv[1] == "--normals":
        mesh_normals(sys.argv[2])  # python tests/mitsuba_measure.py --normals tests/data/mitsuba_normals.json
    elif sys.argv[1:] == ["--albedo"]:
        print(json.dumps(albedos(), indent=1))
    elif len(sys.argv) == 3 and sys.argv[1] == "--ior-json":
        table = {"_source": f"Measured with Mitsuba {mi.__version__} (pip install mitsuba), variant scalar_rgb: "
                            "the eta of dielectric(int_ior=NAME, ext_ior=1) and the RGB eta and k of "
                            "conductor(material=NAME), read with mitsuba.traverse. Regenerate with "
                            "tests/mitsuba_measure.py --ior-json clpt/data/mitsuba_ior.json.",
                 **ior_table()}
        with open(sys.argv[2], "w") as f:
            f.write(json.dumps(table, indent=1) + "\n")
    else:
        print("mitsuba", mi.__version__)
        print(json.dumps({"spectra": spectra(), "conductor_spectra": conductor_spectra(), **transforms_and_camera()},
                         indent=1))
