"""How long the device waits for the host within a render: the gaps between
consecutive kernels, from their OpenCL profiling events.

    python tests/bench_device_idle.py cornell_box_caustics --device intel --spp 512 --renders 2

For uniform and adaptive renders (threshold 1e-3) alternating, per render:
wall seconds, the span from the first kernel's start to the last one's
end, the kernels' summed device time, the idle time within the span (span
less that sum), and the gaps longer than 3 ms (an adaptive round's start,
where the host reads the sums and allocates the next round). Then the
median gap before each kernel, by kernel. On a machine other jobs share
the wall time moves by tens of percent between renders; the idle time,
the host's share, moves far less.
"""

from __future__ import annotations

import statistics
import time
import warnings

from bench_adaptive_merge import scene_parser


def main(argv=None) -> int:
    ap = scene_parser(__doc__)
    ap.add_argument("--spp", type=int, default=512)
    ap.add_argument("--renders", type=int, default=2)
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")

    from clpt.adaptive import AdaptiveSettings
    from clpt.engine import passes
    from clpt.loading import load_scene
    from clpt.render import Renderer

    events = []
    launched = passes.Counters.launched

    def keep(self, name, ev):  # every launch's event, as the passes queue them
        events.append((name, ev))
        launched(self, name, ev)

    passes.Counters.launched = keep
    r = Renderer(load_scene(a.scene), device=a.device)
    kw = dict(width=a.width, height=a.height)
    methods = (("uniform", {}), ("adaptive", {"adaptive": AdaptiveSettings(threshold=1e-3)}))
    for _, m in methods:  # builds and first launches left out
        r.render(16, seed=999, **kw, **m)
    before = {}
    for i in range(a.renders):
        for name, m in methods:
            events.clear()
            t = time.perf_counter()
            res = r.render(a.spp, seed=i + 1, **kw, **m)
            wall = time.perf_counter() - t
            ev = sorted(((n, e.profile.start * 1e-9, e.profile.end * 1e-9) for n, e in events), key=lambda x: x[1])
            busy = sum(e - s for _, s, e in ev)
            span = ev[-1][2] - ev[0][1]
            gaps = [(n, max(s - prev_end, 0.0)) for (_, _, prev_end), (n, s, _) in zip(ev, ev[1:])]
            long = [g for _, g in gaps if g > 3e-3]
            for n, g in gaps:
                before.setdefault((name, n), []).append(g)
            print(f"{name:8s} render {i + 1}: wall {wall:.3f} s, span {span:.3f} s, kernels {busy:.3f} s, idle "
                  f"{span - busy:.3f} s ({(span - busy) / span:.1%}); {len(long)} gaps over 3 ms, "
                  f"{sum(long) * 1e3:.0f} ms in all; {len(ev)} launches, "
                  f"{res.stats.adaptive_rounds} adaptive rounds", flush=True)
    print("median gap before each kernel (us):")
    for (name, n), v in sorted(before.items()):
        print(f"  {name:8s} {n:18s} {statistics.median(v) * 1e6:8.0f}  ({len(v)} launches, "
              f"{sum(v) * 1e3:.1f} ms in all)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
