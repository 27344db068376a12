"""What streaming to tev costs a render: interleaved renders without and with
a listening viewer (tests/tevserver.py, in a process of its own, decoding
every packet as tev would), the same scene, size and samples.

    python tests/bench_tev.py [SCENE] [--width W] [--height H] [--spp N] [--pairs P] [--aux]

Prints per pair the render seconds without and with the viewer, then:
- the wall-clock slowdown (median and range over the pairs);
- the update rate reached;
- the work streaming adds, per update, as CPU time: in the render thread
  (queueing the copies of the device sums between two passes: the device
  waits for it), in the device (the copies themselves, timed alone on an idle
  queue) and in the sending thread (images from the copies, tev's packets,
  the socket); the viewer's own process is reported apart;
- the device's idle time between passes (kernel end to the next kernel's
  start, from the queue's profiling timestamps), without and with the
  viewer: what the render thread's share of streaming (queueing the copies,
  waiting for Python's lock while the sending thread holds it) adds to the
  render, measured rather than estimated;
- from these, the cost on a machine the render has to itself: the work per
  second at the rate reached, over the CPU time per second a CPU device
  renders with (all cores), or, on a GPU, the render thread's and the
  copies' part alone (the sending thread runs beside the device).
On a shared machine the wall-clock figure is noisy and CPU counts are the
steadier measure.
"""

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pyopencl as cl

import clpt
from clpt.tev import UPDATE_INTERVAL, TevViewer, _cpu_count


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene", nargs="?", default="cornell_box")
    ap.add_argument("--width", type=int, default=256)
    ap.add_argument("--height", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--pairs", type=int, default=5)
    ap.add_argument("--aux", action="store_true", help="feature buffers too (albedo and normal layers)")
    ap.add_argument("--device", default=None)
    a = ap.parse_args()
    server = subprocess.Popen([sys.executable, str(Path(__file__).with_name("tevserver.py"))], stdout=subprocess.PIPE,
                              text=True)
    port = int(server.stdout.readline())
    r = clpt.Renderer(a.scene, device=a.device, aux=a.aux)
    queueing = []
    snapshot = r._snapshot

    def timed_snapshot(*args):
        t0 = time.thread_time()
        try:
            return snapshot(*args)
        finally:
            queueing.append(time.thread_time() - t0)

    r._snapshot = timed_snapshot
    kernels = []
    launch = cl.enqueue_nd_range_kernel

    def recorded_launch(queue, kernel, *args, **kw):
        event = launch(queue, kernel, *args, **kw)
        if kernel.function_name == "trace_paths":
            kernels.append(event)
        return event

    cl.enqueue_nd_range_kernel = recorded_launch  # render.py launches through this module
    r.render(4, width=a.width, height=a.height)  # the device's lazy compile, outside the timing
    copy_s = copy_seconds(r)
    plain, streamed, rates, sending, per_update_queue, server_cpu = [], [], [], [], [], []
    idle = {False: [], True: []}
    kernel_s = {False: [], True: []}
    try:
        for i in range(a.pairs):
            for with_viewer in ((False, True) if i % 2 == 0 else (True, False)):
                viewer = TevViewer(f"bench {i}", f"127.0.0.1:{port}",
                                    cpu_device=any(st.dctx.is_cpu for st in r.states)) if with_viewer else None
                queueing.clear()
                kernels.clear()
                server0 = process_cpu_seconds(server.pid)
                res = r.render(a.spp, width=a.width, height=a.height, seed=i, on_update=viewer,
                               update_interval=UPDATE_INTERVAL)
                idle[with_viewer].append(idle_between(kernels) / res.stats.render_seconds)
                kernel_s[with_viewer].append(busy(kernels))
                if viewer is None:
                    plain.append(res.stats.render_seconds)
                    continue
                viewer.close()
                server_cpu.append((process_cpu_seconds(server.pid) - server0) / max(viewer.updates, 1))
                streamed.append(res.stats.render_seconds)
                rates.append(viewer.rate())
                sending.append(viewer.cpu_seconds / max(viewer.updates, 1))
                per_update_queue.append(statistics.mean(queueing) if queueing else 0.0)
            print(f"pair {i}: {plain[-1]:.3f} s without, {streamed[-1]:.3f} s with the viewer, "
                  f"{rates[-1]:.1f} updates/s", flush=True)
    finally:
        server.kill()
    ratios = [s / p - 1 for p, s in zip(plain, streamed)]
    rate, q, send = statistics.median(rates), statistics.median(per_update_queue), statistics.median(sending)
    cores = _cpu_count()
    dev = r.states[0].dctx
    print(f"{a.scene} {a.width}x{a.height}, {a.spp} spp{', feature buffers' if a.aux else ''}, {dev.label}, "
          f"{cores} cores")
    print(f"wall clock: slowdown median {100 * statistics.median(ratios):+.1f}% (range {100 * min(ratios):+.1f}% "
          f"to {100 * max(ratios):+.1f}%) over {a.pairs} pairs; render {statistics.median(plain):.2f} s median")
    print(f"updates: {rate:.1f}/s median; per update: render thread {1e3 * q:.2f} ms, device copies "
          f"{1e3 * copy_s:.2f} ms, sending thread {1e3 * send:.2f} ms CPU; the viewer's process "
          f"{1e3 * statistics.median(server_cpu):.2f} ms")
    added_idle = statistics.median(idle[True]) - statistics.median(idle[False])
    print(f"device idle between passes: median {100 * statistics.median(idle[False]):.2f}% of the render without, "
          f"{100 * statistics.median(idle[True]):.2f}% with the viewer ({100 * added_idle:+.2f}%)")
    k0, k1 = statistics.median(kernel_s[False]), statistics.median(kernel_s[True])
    print(f"kernels: median {k0:.2f} s of device time without, {k1:.2f} s with the viewer ({100 * (k1 / k0 - 1):+.1f}%)")
    if dev.is_cpu:
        cost = rate * (q + copy_s + send) / cores
        print(f"cost on a machine of its own: {100 * cost:.2f}% of the render's CPU time "
              f"((render thread + copies + sending) x rate / {cores} cores)")
    else:
        print(f"cost on a machine of its own: {100 * rate * (q + copy_s):.2f}% of the device's time "
              f"(render thread + copies, x rate)")


def busy(events) -> float:
    """Seconds the kernels ran, summed."""
    cl.wait_for_events(events)
    return sum(e.profile.end - e.profile.start for e in events) * 1e-9


def idle_between(events) -> float:
    """Seconds between one kernel's end and the next one's start, summed."""
    cl.wait_for_events(events)
    spans = sorted((e.profile.start, e.profile.end) for e in events)
    return sum(max(b[0] - a[1], 0) for a, b in zip(spans, spans[1:])) * 1e-9


def copy_seconds(r, repeats=20):
    """Seconds one snapshot's copies take on an idle queue (the best of some)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for st in r.states:
            _, events = st.snapshot(False)
            cl.wait_for_events(events)
        best = min(best, time.perf_counter() - t0)
    return best


def process_cpu_seconds(pid):
    """User and system CPU seconds of another process (Linux)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


if __name__ == "__main__":
    main()
