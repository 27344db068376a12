"""Environment-lit rendering, measured (the figures in README, "Environment and directional lights").

    python tests/bench_envmap.py [--device intel] [--res 128] [--spp 256]
        [--mitsuba-python /path/to/python-with-mitsuba]
    python tests/bench_envmap.py --alternate [--device intel] [--res 128] [--spp 64] [--rounds 4]
        [--big-map 2048x1024] [--mitsuba-python /path/to/python-with-mitsuba]

Samples/s of tests/data/env_spheres.xml (a diffuse and a rough gold sphere
on a plane under an HDR sky, path traced with MIS between the map's
importance sampling and BSDF sampling) in clpt and, with --mitsuba-python,
in Mitsuba 3 LLVM in the same run (its own process; the first render,
which compiles, left out): bench_lights.speed.

--alternate times clpt and a persistent Mitsuba process round by round, per
CPU second (tests/bench_mitsuba.py), on env_spheres, on the same scene
under a large map (tests/envmaps.py sky_map at --big-map's size, written
to a temporary folder with a copy of the scene that reads it), and on that
one under a roof (roof_scene).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_lights  # noqa: E402


def big_map_scene(folder: Path, w: int, h: int) -> Path:
    """env_spheres.xml under a w x h sky map (sky_map's), both written to folder."""
    import clpt
    from envmaps import sky_map

    clpt.save_image(folder / "env_big.exr", sky_map(w, h))
    xml = folder / "env_spheres_big.xml"
    xml.write_text((HERE / "data" / "env_spheres.xml").read_text().replace("env_sky.exr", str(folder / "env_big.exr")))
    return xml


ROOF = """    <shape type="rectangle">
        <transform name="to_world">
            <rotate x="1" angle="90"/>
            <scale value="6"/>
            <translate y="2.2"/>
        </transform>
        <bsdf type="diffuse">
            <rgb name="reflectance" value="0.5, 0.5, 0.4501"/>
        </bsdf>
    </shape>
"""


def roof_scene(big: Path) -> Path:
    """big_map_scene's scene under a 12 x 12 diffuse roof 2.2 above the
    ground (facing down): few rays leave the scene. The roof has a BSDF of
    its own (not the ground's by reference, which Mitsuba 3 would merge
    with the ground into one mesh and then light the ground under it
    about twice as brightly as the gap allows)."""
    xml = big.with_name("env_spheres_roof.xml")
    text = big.read_text()
    at = text.index('    <shape type="sphere">')
    xml.write_text(text[:at] + ROOF + text[at:])
    return xml


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default=None)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=None, help="256 (64 with --alternate)")
    ap.add_argument("--mitsuba-python", default=None)
    ap.add_argument("--alternate", action="store_true")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--big-map", default="2048x1024", help="WxH ('' for env_spheres alone)")
    a = ap.parse_args()
    if not a.alternate:
        bench_lights.speed(a.device, a.mitsuba_python, spp=a.spp or 256, res=a.res,
                           xml=HERE / "data" / "env_spheres.xml")
        return
    import bench_mitsuba

    with tempfile.TemporaryDirectory() as tmp:
        scenes = [HERE / "data" / "env_spheres.xml"]
        if a.big_map:
            w, h = map(int, a.big_map.split("x"))
            scenes.append(big_map_scene(Path(tmp), w, h))
            scenes.append(roof_scene(scenes[-1]))
        for xml in scenes:
            o = bench_mitsuba.bench(str(xml), device=a.device, rounds=a.rounds, spp=a.spp or 64,
                                    params={"res": str(a.res)},
                                    mitsuba_python=a.mitsuba_python or bench_mitsuba.MITSUBA_PYTHON)
            print(f"{xml.name} {o['width']}x{o['height']} {o['spp']} spp, {o['clpt_kernel']}\n"
                  f"  clpt    {o['clpt_msamples_per_cpu_s']:.3f} Msamples/CPU-s\n"
                  f"  Mitsuba {o['mitsuba_msamples_per_cpu_s']:.3f} Msamples/CPU-s\n"
                  f"  ratio {o['ratio_cpu']:.2f}x per CPU-s; image means {o['clpt_mean']:.5f} and "
                  f"{o['mitsuba_mean']:.5f}, {o['mean_diff_sigma']:+.1f} sigma apart", flush=True)


if __name__ == "__main__":
    main()
