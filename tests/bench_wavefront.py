"""The wavefront alternative to trace_paths' megakernel, measured where it
would have to win: the intersection stage on its own.

    python tests/bench_wavefront.py [SCENE] [--device intel] [--lanes 1,8,16] [--rounds 5]
        [--depth 3] [--spp 4] [--json OUT] [--mitsuba-python /work/main/.venv/bin/python]
        [--working-set 512]

SCENE as tests/bench_mitsuba.py takes it: `gallery` (the default; the
real-complexity hall of tests/realscene.py), `bunny`, `cornell_box` or a
Mitsuba XML file. Path tracing (photons=False), at the scene's resolution.

A wavefront path tracer keeps its paths in buffers and runs one kernel per
stage over all of them: intersect, shade, trace shadow rays. Each kernel
sees full vectors of live paths (none idle while others finish) and rays can
be reordered between stages for coherence; the price is every path's state
written out and read back at each stage. The stage that must carry it is the
intersection: it is 65% of trace_paths' samples on PoCL (perf, gallery).

The bench builds tests/kernels/wavefront.cl (the megakernel's own
scene_intersect and scene_occluded, rays from buffers, hits to buffers) with
the scene's specialised build options and runs queues of real rays through
it: camera rays (one a pixel, jittered), then `--depth` generations of
bounce rays from the hits (cosine-distributed about the facing geometric
normal; escaped paths leave the queue) and one shadow ray per hit towards a
point the kernels' own light sampler picks. Each queue is timed from
profiling events (median of the rounds) in launch order (pixel order, as a
wavefront would hold it) and sorted by the ray's direction octant and the
Morton code of its origin (the reordering a wavefront allows).

Printed per lane width: Mrays per device second by ray kind and order, and
the intersection stage's device time per sample at trace_paths' own ray mix
(camera, bounce and shadow rays per sample, from the render's counts),
against trace_paths' whole device time per sample at that lane width. The
ratio bounds what a wavefront split could gain: if intersection alone costs
a share s of the megakernel's sample, the split can at best run 1/s times
as fast, before paying for its buffers.

With --working-set K, each lane width's bounce and shadow queues are timed
twice more at the same length: K of their rays, each repeated in a run
(caches and branch predictors warm), and the same K rays shuffled (the
memory they touch small enough to stay in the caches, the branches as
unpredictable as in the real queue). The real queue against the shuffled
one is the cost of the BVH's memory not being in the caches.

With --mitsuba-python (a Python with Mitsuba 3; '' to leave it out, the
default), the same queues (the last lane width's) go to Mitsuba's
`llvm_ad_rgb` in a process of its own, which loads the same file and times
`Scene.ray_intersect_preliminary` (closest hits: Embree's traversal, no
surface interaction) and `Scene.ray_test` (shadow rays) on them, wall
seconds (both use every core), median of the rounds.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


MITSUBA_CHILD = r"""
import json, statistics, sys, time
import numpy as np
import drjit as dr
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
spec = json.loads(sys.argv[1])
scene = mi.load_file(spec["scene"], **spec["params"])
data = np.load(spec["queues"])
out = {}
for name in spec["names"]:
    o, d = data[name + "_o"].astype(np.float32), data[name + "_d"].astype(np.float32)
    tmax = data[name + "_t"].astype(np.float32) if name + "_t" in data else None
    ray = mi.Ray3f(mi.Point3f(*[mi.Float(o[:, k]) for k in range(3)]), mi.Vector3f(*[mi.Float(d[:, k]) for k in range(3)]))
    if tmax is not None:
        ray.maxt = mi.Float(tmax)
    dr.eval(ray)
    secs = []
    for r in range(spec["rounds"] + 1):
        dr.sync_thread()
        w = time.perf_counter()
        res = scene.ray_test(ray) if tmax is not None else scene.ray_intersect_preliminary(ray).t
        dr.eval(res)
        dr.sync_thread()
        secs.append(time.perf_counter() - w)
    out[name] = {"rays": len(o), "mrays_per_s": len(o) / statistics.median(secs[1:]) / 1e6}
print(json.dumps(out), flush=True)
"""


def mitsuba_queues(python, path, params, queues, rounds):
    """Mitsuba's Mrays per wall second on the queues ({name: (o, d, tmax)})."""
    import os
    import subprocess
    import tempfile

    import bench_mitsuba as bm

    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / "queues.npz"
        arrays = {}
        for name, (o, d, t) in queues.items():
            arrays[name + "_o"], arrays[name + "_d"] = o, d
            if t is not None:
                arrays[name + "_t"] = t
        np.savez(f, **arrays)
        spec = {"scene": path, "params": params, "queues": str(f), "names": list(queues), "rounds": rounds}
        env = dict(os.environ, DRJIT_LIBLLVM_PATH=os.environ.get("DRJIT_LIBLLVM_PATH", bm.LLVM))
        res = subprocess.run([python, "-c", MITSUBA_CHILD, json.dumps(spec)], capture_output=True, text=True, env=env)
        if res.returncode != 0:
            raise SystemExit(f"bench_wavefront: Mitsuba's process failed: {res.stderr.strip()[-500:]}")
        return json.loads(res.stdout.strip().splitlines()[-1])


def camera_rays(cam, rng, scale=1.0):
    """One jittered pinhole ray a pixel (row-major), as (origin, direction)
    arrays, through clpt's own camera frame (clpt/pack.py camera_frame)."""
    from clpt.pack import camera_frame

    w, h = cam.width, cam.height
    fr = camera_frame(cam, w, h, scale)
    y, x = np.mgrid[0:h, 0:w]
    sx = x.ravel() + rng.random(w * h)
    sy = y.ravel() + rng.random(w * h)
    d = fr.corner[None] + sx[:, None] * fr.dx[None] + sy[:, None] * fr.dy[None]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(fr.origin, d.shape).copy(), d


def cosine_about(n, rng):
    """Cosine-distributed unit directions about unit normals n (rows)."""
    k = len(n)
    u1, u2 = rng.random(k), rng.random(k)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    a = np.where(np.abs(n[:, :1]) > 0.9, np.array([[0.0, 1.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]))
    t = np.cross(n, a)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(n, t)
    z = np.sqrt(np.maximum(0.0, 1 - u1))
    return (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b + z[:, None] * n


def morton_order(o, d):
    """Sort order: direction octant, then the Morton code (10 bits an axis) of the origin."""
    lo, hi = o.min(0), o.max(0)
    q = np.clip(((o - lo) / np.where(hi > lo, hi - lo, 1) * 1023).astype(np.int64), 0, 1023)
    code = np.zeros(len(o), dtype=np.int64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + 2 - axis)
    octant = (d[:, 0] < 0) * 4 + (d[:, 1] < 0) * 2 + (d[:, 2] < 0)
    return np.lexsort((code, octant))


class Stage:
    """wavefront.cl built for one lane width with the scene's build options."""

    def __init__(self, renderer, lanes):
        import pyopencl as cl

        from clpt import program
        from clpt.engine.launch import scene_info

        self.cl = cl
        dctx = renderer.devices[0]
        self.dctx, self.lanes = dctx, lanes
        feats = dataclasses.replace(renderer.features, lanes=lanes)
        src = program.stitch([str(HERE / "kernels" / f) for f in ("lane_io.cl", "wavefront.cl")])
        self.prog, _ = program.build(dctx, src, feats.options())
        self.real = np.float64 if feats.double else np.float32
        self.scale = renderer.packed.length_scale
        mf = cl.mem_flags
        recs = np.ascontiguousarray(renderer.packed.records, dtype=self.real)
        self.rec = cl.Buffer(dctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=recs)
        info = np.ascontiguousarray(scene_info(renderer.packed.counts, 0.0, feats.double))
        self.info = cl.Buffer(dctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=info)
        self.kernels = {k: getattr(self.prog, k) for k in ("wf_closest", "wf_occluded", "probe_light_sample")}

    def run(self, name, inputs, n_out):
        """Launch kernel `name` over len(inputs[0]) items; (outputs, device seconds)."""
        cl = self.cl
        ctx, q = self.dctx.context, self.dctx.queue
        n = len(inputs[0])
        pad = -(-n // self.lanes) * self.lanes
        mf = cl.mem_flags
        bufs = []
        for a in inputs:
            h = np.zeros(pad, dtype=self.real)
            h[:n] = a
            bufs.append(cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=h))
        outs = [np.zeros(pad, dtype=self.real) for _ in range(n_out)]
        obufs = [cl.Buffer(ctx, mf.WRITE_ONLY, o.nbytes) for o in outs]
        ev = self.kernels[name](q, (pad // self.lanes,), None, self.rec, self.info, *bufs, *obufs)
        ev.wait()
        for o, b in zip(outs, obufs):
            cl.enqueue_copy(q, o, b)
        q.finish()
        return [o[:n] for o in outs], (ev.profile.end - ev.profile.start) * 1e-9


def make_queues(stage, cam, depth, rng, eps):
    """The ray queues of `depth` bounces: lists of (o, d, tmax) per kind."""
    o, d = camera_rays(cam, rng, stage.scale)
    queues = {"camera": [(o, d, None)], "bounce": [], "shadow": []}
    for gen in range(depth + 1):
        (t, nx, ny, nz, _), _ = stage.run("wf_closest", [*o.T, *d.T], 5)
        hit = np.isfinite(t)
        o, d, t = o[hit], d[hit], t[hit].astype(np.float64)
        n = np.stack([nx[hit], ny[hit], nz[hit]], 1).astype(np.float64)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        n = np.where((np.sum(n * d, axis=1) > 0)[:, None], -n, n)  # facing the ray
        p = o + t[:, None] * d + eps * n
        u = rng.random((3, len(p)))
        (wx, wy, wz, dist, _, _, valid), _ = stage.run("probe_light_sample", [*p.T, *u], 7)
        w = np.stack([wx, wy, wz], 1).astype(np.float64)
        ok = (valid > 0) & (np.sum(w * n, axis=1) > 0)
        queues["shadow"].append((p[ok], w[ok], dist[ok].astype(np.float64) * (1 - 1e-4)))
        if gen == depth:
            break
        o, d = p, cosine_about(n, rng)
        queues["bounce"].append((o, d, None))
    return {k: (np.concatenate([x[0] for x in v]), np.concatenate([x[1] for x in v]),
                None if v[0][2] is None else np.concatenate([x[2] for x in v])) for k, v in queues.items() if v}


def time_queue(stage, o, d, tmax, rounds):
    if tmax is None:
        secs = [stage.run("wf_closest", [*o.T, *d.T], 5)[1] for _ in range(rounds)]
    else:
        secs = [stage.run("wf_occluded", [*o.T, *d.T, tmax], 1)[1] for _ in range(rounds)]
    return statistics.median(secs)


def megakernel(scene, device, lanes, spp, rounds):
    import clpt

    r = clpt.Renderer(scene, device=device, photons=False, lanes=lanes)
    r.render(1, seed=0)
    per_spp, mix = [], None
    for i in range(rounds):
        res = r.render(spp, seed=i + 1, pass_seconds=1e9)
        per_spp.append(sum(res.stats.kernel_seconds.get("trace_paths", [])) / spp)
        n = res.image.shape[0] * res.image.shape[1] * spp
        s = res.stats
        mix = {"camera": s.camera_rays / n, "bounce": s.bounce_rays / n, "shadow": s.shadow_rays / n}
    return r, statistics.median(per_spp), mix


def main():
    import clpt
    import bench_mitsuba as bm

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default="gallery")
    ap.add_argument("--device", default=None)
    ap.add_argument("--lanes", default="1,8,16")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--depth", type=int, default=3, help="bounce generations after the camera rays")
    ap.add_argument("--spp", type=int, default=4, help="the megakernel's samples per pixel a round")
    ap.add_argument("--json", default=None)
    ap.add_argument("--working-set", type=int, default=0, help="K rays repeated and shuffled (0: not timed)")
    ap.add_argument("--mitsuba-python", default="", help="a Python with Mitsuba 3, to time Embree on the same rays")
    a = ap.parse_args()
    path, params = bm.resolve(a.scene, {})
    scene = clpt.load_scene(path, **({"params": params} if path.endswith(".xml") else {}))
    rows = []
    print(f"{a.scene}: {scene.camera.width}x{scene.camera.height}, device time, median of {a.rounds}")
    for lanes in [int(x) for x in a.lanes.split(",")]:
        r, mega, mix = megakernel(scene, a.device, lanes, a.spp, a.rounds)
        stage = Stage(r, lanes)
        eps = 1e-4 * r.packed.extent
        rng = np.random.default_rng(1)
        queues = make_queues(stage, scene.camera, a.depth, rng, eps)
        row = {"lanes": lanes, "megakernel_ms_per_spp": mega * 1e3, "rays_per_sample": mix, "queues": {}}
        per_ray = {}
        for kind, (o, d, tmax) in queues.items():
            for order in ("launch", "sorted"):
                if order == "sorted":
                    k = morton_order(o, d)
                    oo, dd, tt = o[k], d[k], None if tmax is None else tmax[k]
                else:
                    oo, dd, tt = o, d, tmax
                sec = time_queue(stage, oo, dd, tt, a.rounds)
                row["queues"][f"{kind}_{order}"] = {"rays": len(o), "mrays_per_s": len(o) / sec / 1e6}
                per_ray[kind, order] = sec / len(o)
        pixels = scene.camera.width * scene.camera.height
        for order in ("launch", "sorted"):
            stage_s = sum(mix[k] * per_ray[k, order] for k in ("camera", "bounce", "shadow")) * pixels
            row[f"intersect_ms_per_spp_{order}"] = stage_s * 1e3
            row[f"share_{order}"] = stage_s / mega
        rows.append(row)
        q = row["queues"]
        print(f"lanes {lanes:2d}: trace_paths {mega * 1e3:7.1f} ms/spp (rays/sample camera {mix['camera']:.2f} "
              f"bounce {mix['bounce']:.2f} shadow {mix['shadow']:.2f})")
        for kind in ("camera", "bounce", "shadow"):
            print(f"    {kind:6} {q[kind + '_launch']['rays']:8d} rays: {q[kind + '_launch']['mrays_per_s']:6.2f} "
                  f"Mrays/s in launch order, {q[kind + '_sorted']['mrays_per_s']:6.2f} sorted")
        if a.working_set:
            for kind in ("bounce", "shadow"):
                o, d, tmax = queues[kind]
                pick = rng.choice(len(o), a.working_set, replace=False)
                rep = np.repeat(pick, len(o) // a.working_set)
                ws = {}
                for label, idx in (("repeated", rep), ("shuffled", rng.permutation(rep))):
                    sec = time_queue(stage, o[idx], d[idx], None if tmax is None else tmax[idx], a.rounds)
                    ws[label] = len(idx) / sec / 1e6
                row["queues"][f"{kind}_working_set"] = ws
                print(f"    {kind:6} {a.working_set} rays, each repeated: {ws['repeated']:6.2f} Mrays/s, "
                      f"shuffled: {ws['shuffled']:6.2f} (all rays: {q[kind + '_launch']['mrays_per_s']:.2f})")
        print(f"    intersection at trace_paths' ray mix: {row['intersect_ms_per_spp_launch']:7.1f} ms/spp "
              f"({row['share_launch']:.2f} of trace_paths), sorted {row['intersect_ms_per_spp_sorted']:7.1f} "
              f"({row['share_sorted']:.2f})")
    out = {"rows": rows}
    if a.mitsuba_python:
        named = {}
        for kind, (o, d, tmax) in queues.items():
            named[kind + "_launch"] = (o, d, tmax)
            k = morton_order(o, d)
            named[kind + "_sorted"] = (o[k], d[k], None if tmax is None else tmax[k])
        mi = mitsuba_queues(a.mitsuba_python, path, params, named, a.rounds)
        out["mitsuba"] = mi
        q = rows[-1]["queues"]
        print(f"Mitsuba 3 (Embree), the same queues, Mrays per wall second (clpt at {rows[-1]['lanes']} lanes, "
              f"device time):")
        for name in named:
            print(f"    {name:15} Mitsuba {mi[name]['mrays_per_s']:6.2f}  clpt {q[name]['mrays_per_s']:6.2f}  "
                  f"ratio {q[name]['mrays_per_s'] / mi[name]['mrays_per_s']:.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
