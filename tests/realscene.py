"""A benchmark scene of real complexity, generated: a gallery hall as Mitsuba 3 XML
that clpt and Mitsuba 3 both render, so a speed comparison is of the same work.

    python tests/realscene.py [--out DIR] [--scale K]

writes DIR/gallery.xml and its PLY meshes (DIR defaults to
$XDG_CACHE_HOME/clpt/realscene, ~/.cache/clpt/realscene; the meshes take
about 10 MiB, so they stay out of git) and prints the file's path. The hall
(12 x 4 x 10 units, the camera inside it at eye height) holds:

- 3 Stanford bunnies (69,451 triangles each, /work/shared/meshes/bunny.ply or
  $CLPT_BUNNY; where neither exists, bumpy spheres of the same size stand in
  and the script says so), diffuse, rough gold and rough plastic;
- 6 bumpy spheres (20k triangles each, smooth normals): glass, rough copper,
  rough plastics, diffuse;
- 4 tori (12k triangles each) of rough aluminium and rough plastic, 8
  columns (2.5k triangles each), 6 pedestals (Mitsuba cubes);
- 13 lights of mixed sizes and colours: 8 ceiling panels (0.1 to 2.2 square
  units), 2 small wall lamps (rectangles) and 3 emissive spheres (meshes);
- walls, floor (rough plastic) and ceiling as rectangles.

About 0.5 million triangles (495,561 with the bunny) in 27 PLY meshes, depth 64 (Mitsuba's max_depth 65),
320x180. --scale multiplies the generated meshes' triangle counts.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from meshgen import uv_sphere, write_ply  # noqa: E402

from clpt.tools.bench import sphere_mesh  # noqa: E402

SHARED_BUNNY = HERE.parent.parent.parent / "shared" / "meshes" / "bunny.ply"  # /work/shared beside the checkouts


def default_out() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "clpt" / "realscene"


def bunny_path() -> Path | None:
    for p in (os.environ.get("CLPT_BUNNY"), "/work/shared/meshes/bunny.ply", SHARED_BUNNY):
        if p and Path(p).is_file():
            return Path(p)
    return None


def torus(R=1.0, r=0.3, n_u=96, n_v=48):
    """(vertices, triangles, normals) of a torus around the y axis, outward normals."""
    u = np.linspace(0, 2 * np.pi, n_u, endpoint=False)
    v = np.linspace(0, 2 * np.pi, n_v, endpoint=False)
    U, V = np.meshgrid(u, v, indexing="ij")
    n = np.stack([np.cos(V) * np.cos(U), np.sin(V), np.cos(V) * np.sin(U)], -1).reshape(-1, 3)
    c = np.stack([R * np.cos(U), np.zeros_like(U), R * np.sin(U)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_u), np.arange(n_v), indexing="ij")
    a = i * n_v + j
    b = ((i + 1) % n_u) * n_v + j
    cc = ((i + 1) % n_u) * n_v + (j + 1) % n_v
    d = i * n_v + (j + 1) % n_v
    tris = np.concatenate([np.stack([a, d, cc], -1).reshape(-1, 3), np.stack([a, cc, b], -1).reshape(-1, 3)])
    return c + r * n, tris, n


def column(radius=0.18, height=4.0, n_phi=48, n_y=24, flutes=12):
    """(vertices, triangles, None) of a fluted open column from y = 0 to height
    (no caps: it stands from floor to ceiling). No normals: both renderers give
    it Mitsuba's smooth vertex normals (analytic normals of the flutes lean up
    to 36 degrees off the facets, and one-sided materials then differ between
    the two renderers at grazing angles)."""
    ph = np.linspace(0, 2 * np.pi, n_phi, endpoint=False)
    y = np.linspace(0, height, n_y + 1)
    P, Y = np.meshgrid(ph, y, indexing="ij")
    rr = radius * (1 + 0.06 * np.cos(flutes * P))
    v = np.stack([rr * np.cos(P), Y, rr * np.sin(P)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_phi), np.arange(n_y), indexing="ij")
    a = i * (n_y + 1) + j
    b = ((i + 1) % n_phi) * (n_y + 1) + j
    tris = np.concatenate([np.stack([a, a + 1, b + 1], -1).reshape(-1, 3), np.stack([a, b + 1, b], -1).reshape(-1, 3)])
    return v, tris, None


def _fmt(m) -> str:
    return ", ".join(f"{x:.9g}" for x in np.asarray(m, dtype=np.float64).ravel())


def _emitter(radiance) -> str:
    if not radiance:
        return ""
    rgb = ", ".join(f"{LIGHT_SCALE * float(x):g}" for x in radiance.split(","))
    return f'<emitter type="area"><rgb name="radiance" value="{rgb}"/></emitter>'


LIGHT_SCALE = 1.0  # the radiances below, scaled


def rect_matrix(center, u, v):
    """to_world of a Mitsuba rectangle ([-1, 1]^2 in xy, normal +z) spanning
    center +- u +- v; its normal is u x v."""
    u, v = np.asarray(u, float), np.asarray(v, float)
    n = np.cross(u, v)
    n /= np.linalg.norm(n)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = u, v, n, center
    return m


MATERIALS = """
    <bsdf type="twosided" id="white"><bsdf type="diffuse"><rgb name="reflectance" value="0.72, 0.71, 0.68"/></bsdf></bsdf>
    <bsdf type="twosided" id="wall_warm"><bsdf type="diffuse"><rgb name="reflectance" value="0.65, 0.52, 0.38"/></bsdf></bsdf>
    <bsdf type="twosided" id="wall_blue"><bsdf type="diffuse"><rgb name="reflectance" value="0.25, 0.35, 0.55"/></bsdf></bsdf>
    <bsdf type="twosided" id="clay"><bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.3, 0.2"/></bsdf></bsdf>
    <bsdf type="roughplastic" id="floor_plastic">
        <string name="distribution" value="ggx"/><float name="alpha" value="0.25"/>
        <rgb name="diffuse_reflectance" value="0.35, 0.25, 0.18"/>
    </bsdf>
    <bsdf type="roughplastic" id="plastic_red">
        <string name="distribution" value="ggx"/><float name="alpha" value="0.1"/>
        <rgb name="diffuse_reflectance" value="0.7, 0.08, 0.06"/>
    </bsdf>
    <bsdf type="roughplastic" id="plastic_green">
        <string name="distribution" value="beckmann"/><float name="alpha" value="0.3"/>
        <rgb name="diffuse_reflectance" value="0.1, 0.5, 0.15"/>
    </bsdf>
    <bsdf type="roughplastic" id="marble">
        <string name="distribution" value="ggx"/><float name="alpha" value="0.05"/>
        <rgb name="diffuse_reflectance" value="0.8, 0.8, 0.78"/>
    </bsdf>
    <bsdf type="roughconductor" id="gold">
        <string name="material" value="Au"/><string name="distribution" value="ggx"/><float name="alpha" value="0.2"/>
    </bsdf>
    <bsdf type="roughconductor" id="copper">
        <string name="material" value="Cu"/><string name="distribution" value="ggx"/><float name="alpha" value="0.1"/>
    </bsdf>
    <bsdf type="roughconductor" id="aluminium">
        <string name="material" value="Al"/><string name="distribution" value="beckmann"/><float name="alpha" value="0.3"/>
    </bsdf>
    <bsdf type="dielectric" id="glass"><float name="int_ior" value="1.5"/><float name="ext_ior" value="1.0"/></bsdf>
"""


def generate(out: Path, scale: float = 1.0, log=print) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    shapes: list[str] = []
    n_tris = 0

    def ply(name, vtn, bsdf, emitter=None, transform=None):
        nonlocal n_tris
        v, t, n = vtn
        write_ply(out / f"{name}.ply", v, t, n)
        n_tris += len(t)
        em = _emitter(emitter)
        tr = f'<transform name="to_world"><matrix value="{_fmt(transform)}"/></transform>' if transform is not None else ""
        shapes.append(f'    <shape type="ply" id="{name}"><string name="filename" value="{name}.ply"/>{tr}'
                      f'<ref id="{bsdf}"/>{em}</shape>')

    def rect(name, center, u, v, bsdf, emitter=None):
        em = _emitter(emitter)
        shapes.append(f'    <shape type="rectangle" id="{name}"><transform name="to_world"><matrix value="'
                      f'{_fmt(rect_matrix(center, u, v))}"/></transform><ref id="{bsdf}"/>{em}</shape>')

    # The hall: x in [-6, 6], y in [0, 4], z in [-5, 5]; every face's normal points inwards.
    W, H, D = 6.0, 4.0, 5.0
    rect("floor", (0, 0, 0), (W, 0, 0), (0, 0, -D), "floor_plastic")
    rect("ceiling", (0, H, 0), (W, 0, 0), (0, 0, D), "white")
    rect("back", (0, H / 2, -D), (W, 0, 0), (0, H / 2, 0), "wall_warm")
    rect("front", (0, H / 2, D), (-W, 0, 0), (0, H / 2, 0), "white")
    rect("left", (-W, H / 2, 0), (0, 0, -D), (0, H / 2, 0), "wall_blue")
    rect("right", (W, H / 2, 0), (0, 0, D), (0, H / 2, 0), "wall_warm")
    # 8 ceiling panels of mixed sizes (half-extents), facing down, and 2 small wall lamps.
    panels = [((-4, -3), (1.0, 0.5), "9, 8.5, 7.5"), ((0, -3), (1.2, 0.45), "8, 8, 8"),
              ((4, -3), (0.5, 0.5), "14, 12, 9"), ((-4, 0.5), (0.3, 0.3), "30, 28, 24"),
              ((0, 0.5), (0.9, 0.6), "7, 7.5, 8"), ((4, 0.5), (0.2, 0.6), "20, 20, 22"),
              ((-2, 3.5), (0.4, 0.15), "25, 20, 14"), ((2.5, 3.5), (0.16, 0.16), "60, 55, 45")]
    for k, ((x, z), (a, b), rad) in enumerate(panels):
        rect(f"panel{k}", (x, H - 1e-3, z), (a, 0, 0), (0, 0, b), "white", emitter=rad)
    rect("lamp_left", (-W + 1e-3, 2.4, -1.5), (0, 0, -0.12), (0, 0.2, 0), "white", emitter="40, 25, 12")
    rect("lamp_right", (W - 1e-3, 2.4, 1.5), (0, 0, 0.12), (0, 0.2, 0), "white", emitter="12, 25, 40")

    s = max(scale, 0.01)
    bunny = bunny_path()
    if bunny is None:
        log("realscene: /work/shared/meshes/bunny.ply is absent (and $CLPT_BUNNY unset): "
            "bumpy spheres of 69k triangles stand in for the bunnies")
    pedestals = [(-3.5, -2.0), (0.0, -2.5), (3.5, -2.0), (-2.0, 1.0), (2.0, 1.0), (0.0, -0.5)]
    for k, (x, z) in enumerate(pedestals):
        m = np.diag([0.45, 0.4, 0.45, 1.0])
        m[:3, 3] = (x, 0.4, z)
        shapes.append(f'    <shape type="cube" id="pedestal{k}"><transform name="to_world"><matrix value="{_fmt(m)}"/>'
                      f'</transform><ref id="marble"/></shape>')
    top = 0.8
    for k, (bsdf, (x, z)) in enumerate(zip(("white", "gold", "plastic_red"), pedestals[:3])):
        if bunny is not None:
            from clpt.meshio import read_mesh
            v, t, _ = read_mesh(bunny)
            lo, hi = v.min(0), v.max(0)
            kk = 1.0 / (hi[1] - lo[1])
            m = np.diag([kk, kk, kk, 1.0])
            m[:3, 3] = [x - kk * 0.5 * (lo[0] + hi[0]), top - kk * lo[1], z - kk * 0.5 * (lo[2] + hi[2])]
            n_tris += len(t)
            shapes.append(f'    <shape type="ply" id="bunny{k}"><string name="filename" value="{bunny}"/>'
                          f'<boolean name="face_normals" value="true"/><transform name="to_world">'
                          f'<matrix value="{_fmt(m)}"/></transform><ref id="{bsdf}"/></shape>')
        else:
            ply(f"bunny{k}", sphere_mesh(69451, center=(x, top + 0.5, z), radius=0.5, bumps=0.1), bsdf)
    for k, (bsdf, (x, z)) in enumerate(zip(("glass", "copper", "plastic_green"), pedestals[3:])):
        ply(f"ball{k}", sphere_mesh(int(20000 * s), center=(x, top + 0.45, z), radius=0.45, bumps=0.05), bsdf)
    floor_balls = [("clay", (-4.8, 3.8), 0.5), ("marble", (4.6, -4.0), 0.6), ("plastic_red", (-1.0, 3.0), 0.35)]
    for k, (bsdf, (x, z), r) in enumerate(floor_balls):
        ply(f"floorball{k}", sphere_mesh(int(20000 * s), center=(x, r, z), radius=r, bumps=0.08), bsdf)
    for k, (bsdf, (x, y, z)) in enumerate(zip(("aluminium", "plastic_green", "aluminium", "gold"),
                                             ((-4.5, 0.3, -4.0), (4.5, 0.3, 3.5), (1.5, 0.3, -4.2), (-2.5, 0.3, 3.8)))):
        nu = max(8, int(96 * s ** 0.5))
        v, t, n = torus(R=0.6, r=0.25, n_u=2 * nu, n_v=nu)
        ax = rng.normal(size=3)
        ax /= np.linalg.norm(ax)
        ang = 0.4 + 0.3 * k
        kx = np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]], [-ax[1], ax[0], 0]])
        rot = np.eye(3) + np.sin(ang) * kx + (1 - np.cos(ang)) * kx @ kx
        ply(f"torus{k}", (v @ rot.T + (x, y, z), t, n @ rot.T), bsdf)
    for k, x in enumerate((-5.0, -2.5, 2.5, 5.0)):
        for j, z in enumerate((-4.2, 4.2)):
            v, t, n = column(n_phi=max(12, int(48 * s ** 0.5)), n_y=max(4, int(24 * s ** 0.5)))
            ply(f"column{k}{j}", (v + (x, 0, z), t, None), "marble" if (k + j) % 2 else "white")
    for k, ((x, y, z), r, rad) in enumerate((((-3.0, 2.8, 2.0), 0.12, "40, 30, 20"),
                                            ((3.2, 2.2, -0.8), 0.2, "15, 20, 30"),
                                            ((0.8, 3.1, 2.6), 0.08, "80, 70, 50"))):
        ply(f"bulb{k}", uv_sphere((x, y, z), r, n_theta=16, n_phi=32), "white", emitter=rad)

    xml = f"""<?xml version="1.0" encoding="utf-8"?>
<!-- A gallery hall of real complexity, generated by tests/realscene.py: {n_tris} triangles in
     {sum('type="ply"' in s for s in shapes)} PLY meshes, 6 cubes, 13 area lights, diffuse, rough plastic,
     rough conductor and glass, depth 64 (Mitsuba's max_depth 65), camera inside the hall. -->
<scene version="3.0.0">
    <default name="spp" value="64"/>
    <default name="width" value="320"/>
    <default name="height" value="180"/>
    <default name="max_depth" value="65"/>
    <integrator type="path"><integer name="max_depth" value="$max_depth"/></integrator>
    <sensor type="perspective">
        <string name="fov_axis" value="x"/>
        <float name="fov" value="70"/>
        <transform name="to_world"><lookat origin="0.3, 2.7, 4.7" target="0, 0.9, -2" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="$width"/><integer name="height" value="$height"/>
            <rfilter type="box"/></film>
    </sensor>
{MATERIALS}
{chr(10).join(shapes)}
</scene>
"""
    path = out / "gallery.xml"
    path.write_text(xml)
    log(f"realscene: {path}: {n_tris} triangles")
    return path


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=default_out())
    ap.add_argument("--scale", type=float, default=1.0)
    a = ap.parse_args()
    generate(a.out, a.scale, log=lambda s: print(s, file=sys.stderr))
    print(a.out / "gallery.xml")


if __name__ == "__main__":
    main()
