"""The engine's pieces on their own: jobs, accumulators, the schedule, the
driver with fake workers (plain numpy functions: balancing, failures, sums
returned per item), and trace_paths' argument list against the kernel."""

import pickle
import re
import threading
import time

import numpy as np
import pytest

import clpt
from clpt.engine.accum import Accumulator
from clpt.engine.driver import Driver, lane_group_max
from clpt.engine.executors import LocalExecutor
from clpt.engine.job import RenderJob, WorkItem
from clpt.engine.launch import AUX_ARGS, PHOTON_ARGS, PHOTON_PASS_ARGS, TRACE_ARGS
from clpt.engine.runresult import RunResult
from clpt.engine.schedule import Schedule
from clpt.photons import PhotonSettings
from clpt.result import RenderStats
from clpt.resources import kernel_dir


def make_job(spp=16, w=6, h=5, **kw):
    return RenderJob(clpt.load_scene("cornell_box"), spp, 3, 4, 2, w, h, **kw)


# --- jobs ------------------------------------------------------------------------------------

def test_job_is_picklable_hashable_and_keyed_by_what_changes_the_image():
    a, b = make_job(), make_job()
    assert a == b and hash(a) == hash(b) and a.key == b.key
    assert pickle.loads(pickle.dumps(a)).key == a.key
    assert make_job(spp=17).key != a.key and make_job(photons=PhotonSettings(count=7)).key != a.key
    other = clpt.load_scene("cornell_box")
    other.shapes = other.shapes[:-1]
    assert RenderJob(other, 16, 3, 4, 2, 6, 5).scene_key() != a.scene_key()
    assert {a: 1}[b] == 1


# --- accumulators -------------------------------------------------------------------------------

def random_acc(rng, n, **kw):
    acc = Accumulator(n, **kw)
    for v in acc.planes.values():
        v[...] = rng.random(v.shape)
    return acc


def test_accumulator_add_merge_and_bytes():
    rng = np.random.default_rng(1)
    a, b = random_acc(rng, 10, aux=True), random_acc(rng, 10, aux=True)
    m = Accumulator.merge([a, b])
    for k in a.planes:
        assert np.array_equal(m.planes[k], a.planes[k] + b.planes[k])
    back = Accumulator.from_bytes(m.to_bytes())
    assert back.same_layout(m) and all(np.array_equal(back.planes[k], m.planes[k]) for k in m.planes)
    with pytest.raises(ValueError):
        a.add(Accumulator(11))
    with pytest.raises(ValueError):
        Accumulator(10).add(a)  # a has planes (aux) the other lacks


def test_accumulator_device_layouts_round_trip_exactly():
    rng = np.random.default_rng(2)
    n = 7
    s = rng.random((n, 8)).astype(np.float32)
    s[:, 4:] *= 1e-7  # Kahan compensations are small
    sq = rng.random((n, 2)).astype(np.float32)
    aux = [rng.random((n, 4)).astype(np.float32) for _ in range(4)]
    acc = Accumulator.from_device((s, sq), (s * 2, sq * 2), aux)
    ds, dq = acc.to_device("", kahan=True)
    assert np.array_equal(ds, s) and np.array_equal(dq, sq)
    assert np.array_equal(acc.to_device("c_", kahan=True)[0], s * 2)
    assert all(np.array_equal(x, y) for x, y in zip(acc.aux_to_device(), aux))
    # The value of Kahan sums is sum - compensation.
    assert np.allclose(acc.count, s[:, 3].astype(np.float64) - s[:, 7])
    d = Accumulator.from_device((s.astype(np.float64)[:, :4], sq[:, 0].astype(np.float64)))
    assert "comp" not in d.planes and np.array_equal(d.to_device()[0], s[:, :4].astype(np.float64))


def test_accumulator_changes_layout_between_fp64_and_kahan_devices():
    """A checkpoint of a device without fp64 continues on one with it ("auto" sums), and back."""
    rng = np.random.default_rng(3)
    k = random_acc(rng, 5, kahan=True, aux=True)
    d = k.with_layout(Accumulator(5, aux=True))
    assert "comp" not in d.planes and np.allclose(d.stats()[0], k.stats()[0], rtol=1e-12)
    back = d.with_layout(Accumulator(5, kahan=True, aux=True))
    assert np.array_equal(back.planes["comp"], np.zeros((5, 5))) and np.array_equal(back.count, d.count)
    with pytest.raises(ValueError):
        k.with_layout(Accumulator(5))  # no feature buffers there


def test_accumulator_statistics():
    acc = Accumulator(2)
    x = np.array([[1.0, 2.0, 3.0], [0.5, 0.5, 0.5], [2.0, 1.0, 0.0]])
    lum = x @ np.array([0.2126, 0.7152, 0.0722])
    acc.planes["sum"][0] = [*x.sum(0), 3]
    acc.planes["sq"][0] = (lum ** 2).sum()
    mean, var, count = acc.stats()
    assert np.allclose(mean[0], x.mean(0)) and np.isclose(var[0], lum.var(ddof=1)) and count[0] == 3
    assert count[1] == 0 and np.all(mean[1] == 0)


# --- schedule ---------------------------------------------------------------------------------------

def drain(sch, sizes):
    items = []
    while (it := sch.take(next(sizes))) is not None:
        items.append(it)
        sch.done(it)
    return items


def test_schedule_covers_every_sample_once_in_order():
    sch = Schedule(make_job(spp=50))
    sizes = iter([1, 7, 100, 3, 3, 40] * 5)
    items = drain(sch, sizes)
    spans = [(i.s0, i.s0 + i.n) for i in items]
    assert spans[0] == (0, 1) and spans[-1][1] == 50
    assert all(a[1] == b[0] for a, b in zip(spans, spans[1:]))
    assert sch.finished


def test_schedule_progressive_iterations_and_offline_prepass():
    prog = Schedule(make_job(spp=10, photons=PhotonSettings(progressive=True, spp_per_map=4)))
    items = drain(prog, iter([99] * 10))
    assert [(i.s0, i.n, i.iteration) for i in items] == [(0, 4, 0), (4, 4, 1), (8, 2, 2)]
    off = Schedule(make_job(spp=10, photons=PhotonSettings(mode="offline", offline_spp=3)))
    first = off.take(5)
    assert first.kind == "prepass" and first.n == 3
    second = off.take(5)
    assert second.kind == "samples" and (second.s0, second.n) == (0, 5)


def test_schedule_failed_items_come_back_first_and_state_round_trips():
    job = make_job(spp=20)
    sch = Schedule(job)
    a, b = sch.take(4), sch.take(4)
    sch.failed(a)
    sch.done(b)
    again = sch.take(4)
    assert (again.s0, again.n) == (a.s0, a.n)
    sch.done(again)
    st = sch.state()
    back = Schedule.from_state(job, st)
    assert back.next == 8 and back.state() == st
    sch.take(1)
    with pytest.raises(RuntimeError):
        sch.state()  # undefined with work out


# --- the driver, with fake workers ---------------------------------------------------------------------

def fake_sample(pixels, s):
    """A deterministic radiance for sample s of each pixel (rgb)."""
    h = (pixels.astype(np.uint64) * np.uint64(2654435761) + np.uint64(s) * np.uint64(40503)) % np.uint64(9973)
    v = h.astype(np.float64) / 9973.0
    return np.stack([v, v * 0.5, 1.0 - v], axis=1)


class FakeWorker:
    """A 'device' in numpy: sums kept here, samples added in sample order."""

    def __init__(self, label, delay=0.0, fail_after=None):
        self.label, self.delay, self.fail_after = label, delay, fail_after
        self.items = []

    def empty_sums(self, job):
        return Accumulator(job.n_pix)

    def start(self, job, initial=None):
        self.job = job
        self.acc = initial.copy() if initial is not None else Accumulator(job.n_pix)
        self.items = []

    def _add(self, pixels, s):
        L = fake_sample(pixels, s)
        lum = L @ np.array([0.2126, 0.7152, 0.0722])
        self.acc.planes["sum"][pixels, :3] += L
        self.acc.planes["sum"][pixels, 3] += 1
        self.acc.planes["sq"][pixels] += lum ** 2

    def run(self, item):
        if self.fail_after is not None and len(self.items) >= self.fail_after:
            raise RuntimeError(f"{self.label} lost")
        time.sleep(self.delay * max(item.n, 1))
        all_pix = np.arange(self.job.n_pix)
        if item.kind == "pixels":
            for p, (n, _, first, _) in zip(item.pixels, item.jobs):
                for s in range(first, first + n):
                    self._add(np.array([p]), s)
        else:
            for s in range(item.s0, item.s0 + item.n):
                self._add(all_pix, s)
        self.items.append(item)
        return RunResult(seconds=0.0, first=len(self.items) == 1)

    def sums(self):
        return self.acc.copy()


class ReturningExecutor(LocalExecutor):
    """Fake workers whose items come back with their own sums (as Dask's do)."""

    resident = False

    def submit(self, slot, item, done):
        w = self.workers[slot]

        def run():
            w.acc = Accumulator(w.job.n_pix)
            res = w.run(item)
            res.sums = w.sums()
            return res

        self._queues[slot].put((run, lambda err, res: done(slot, item, res, err)))


def drive(job, workers, executor=None, **kw):
    ex = (executor or LocalExecutor)(workers)
    drv = Driver(job, ex, stats=RenderStats(), empty=lambda: Accumulator(job.n_pix), **kw)
    interrupted = drv.run()
    total = drv.total()
    ex.close()
    return drv, total, interrupted


def test_fake_workers_one_or_two_give_the_same_sums():
    job = make_job(spp=40)
    _, one, _ = drive(job, [FakeWorker("a")], pass_seconds=1e-9)
    drv, two, _ = drive(job, [FakeWorker("a", delay=1e-4), FakeWorker("b", delay=1e-3)], pass_seconds=1e-3)
    assert (one.count == 40).all() and (two.count == 40).all()
    assert np.allclose(one.planes["sum"], two.planes["sum"], rtol=1e-13)
    passes = drv.stats.passes
    done = {lab: sum(p[2] for p in passes if p[0] == lab) for lab in ("a", "b")}
    assert done["a"] > done["b"] > 0  # the faster worker did more
    _, ret, _ = drive(job, [FakeWorker("a"), FakeWorker("b")], executor=ReturningExecutor, pass_seconds=1e-3)
    assert np.allclose(one.planes["sum"], ret.planes["sum"], rtol=1e-13)


def test_ranges_are_sized_so_workers_finish_together():
    """Two workers, one 4x faster: the slow one is not left with a long last range."""
    job = make_job(spp=400, w=2, h=2)
    drv, acc, _ = drive(job, [FakeWorker("fast", delay=2e-4), FakeWorker("slow", delay=8e-4)], pass_seconds=0.05)
    assert (acc.count == 400).all()
    last_slow = [p for p in drv.stats.passes if p[0] == "slow"][-1]
    assert last_slow[2] * 8e-4 < 0.1  # a range of at most ~pass_seconds, not the rest of the render


def test_a_failing_worker_loses_no_sample():
    job = make_job(spp=30)
    _, ref, _ = drive(job, [FakeWorker("a")])
    with pytest.warns(UserWarning, match="b lost"):
        drv, acc, _ = drive(job, [FakeWorker("a", delay=1e-3), FakeWorker("b", delay=1e-4, fail_after=3)],
                            pass_seconds=2e-3)
    assert (acc.count == 30).all()
    assert np.allclose(ref.planes["sum"], acc.planes["sum"], rtol=1e-13)
    assert drv.failures and drv.failures[0][0] == "b"
    with pytest.raises(RuntimeError, match="every worker failed"):
        with pytest.warns(UserWarning):
            drive(job, [FakeWorker("a", fail_after=1)])


def test_adaptive_rounds_with_fake_workers_match_across_worker_counts():
    job = make_job(spp=24, adaptive=clpt.AdaptiveSettings(min_spp=8, pass_spp=4, threshold=1e-3))
    drv1, one, _ = drive(job, [FakeWorker("a")])
    _, two, _ = drive(job, [FakeWorker("a"), FakeWorker("b")])
    assert drv1.stats.adaptive_rounds >= 1 and one.samples > 8 * job.n_pix
    assert one.samples <= 24 * job.n_pix
    # Rounds are planned from the same sums; only lane grouping of the parts may differ (lanes=1 here).
    assert np.array_equal(one.count, two.count)
    assert np.allclose(one.planes["sum"], two.planes["sum"], rtol=1e-13)


def test_stop_ends_after_the_work_in_flight():
    job = make_job(spp=10_000)
    stop = threading.Event()
    seen = []

    def progress(done, total, elapsed, rate):
        seen.append(done)
        if done >= 5:
            stop.set()

    drv, acc, interrupted = drive(job, [FakeWorker("a")], stop=stop, progress=progress, pass_seconds=1e-9)
    assert interrupted and 5 <= acc.count[0] < 10_000 and (acc.count == acc.count[0]).all()


def test_lane_group_max():
    assert lane_group_max(np.array([1, 5, 2, 0, 3]), 2).tolist() == [5, 5, 2, 2, 3]


# --- trace_paths' arguments ---------------------------------------------------------------------------

def _kernel_params(file, kernel):
    src = (kernel_dir() / file).read_text()
    sig = src[src.index(f" void {kernel}("):]  # (after __kernel and any attributes)
    sig = sig[:sig.index(")\n{")]
    sig = re.sub(r"#if \w+|#endif", "", sig)
    return tuple(re.findall(r"(\w+)\s*$", p.strip())[0] for p in sig[sig.index("(") + 1:].split(",") if p.strip())


def test_kernel_args_match_the_kernel_signatures():
    """The host's argument lists are the kernels' parameters, in order; and
    trace_paths keeps to at most 12 (everything by value is its launch record)."""
    assert _kernel_params("trace.cl", "trace_paths") == TRACE_ARGS + AUX_ARGS + PHOTON_ARGS
    assert len(TRACE_ARGS + AUX_ARGS + PHOTON_ARGS) <= 12
    assert _kernel_params("photons.cl", "trace_photons") == PHOTON_PASS_ARGS


class FlakyWorker(FakeWorker):
    """Fails the first try of every item (a lost task, not a lost device)."""

    seen = set()

    def run(self, item):
        if id(item) not in FlakyWorker.seen:
            FlakyWorker.seen.add(id(item))
            raise RuntimeError("task lost")
        return super().run(item)


def test_executors_that_retry_keep_their_workers():
    class Retrying(ReturningExecutor):
        retries = 3

    job = make_job(spp=12)
    _, ref, _ = drive(job, [FakeWorker("a")])
    with pytest.warns(UserWarning, match="trying again"):
        drv, acc, _ = drive(job, [FlakyWorker("a"), FlakyWorker("b")], executor=Retrying, pass_seconds=1e-9)
    assert (acc.count == 12).all() and not drv.failures
    assert np.allclose(ref.planes["sum"], acc.planes["sum"], rtol=1e-13)
