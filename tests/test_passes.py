"""The device side's passes (clpt/engine/passes.py) alone where they can be:
their counters with fake events, their typed argument records against the
kernels' parameters, and the launch record every field of which the host
sets; then, on the device, a worker's "photons" item (the photon pilot's
job) and the tuning trial as a job of its own."""

import math
import re
from functools import partial

import numpy as np
import pyopencl as cl
import pytest

import clpt
from clpt import layout
from clpt.engine.driver import run_item
from clpt.engine.executors import LocalExecutor
from clpt.engine.job import RenderJob, WorkItem
from clpt.engine.passes import IMAGE_FIELDS, ITEM_FIELDS, Counters, PhotonPassArgs, TraceArgs
from clpt.engine.runresult import RunResult
from clpt.photons import pilot_choice
from clpt.resources import kernel_dir


class _Profile:
    def __init__(self, start, end):
        self.start, self.end = start, end


class _Event:
    def __init__(self, ns):
        self.profile = _Profile(1000, 1000 + ns)


class _Unprofiled:
    @property
    def profile(self):
        raise cl.Error("profiling info not available")


def test_counters_count_launches_and_read_times_once_settled():
    c = Counters()
    c.launched("a", _Event(2_000_000))
    c.launched("a", _Event(4_000_000))
    c.launched("b", _Unprofiled())
    assert c.launches == {"a": 2, "b": 1} and c.seconds == {}  # times are read once the launches are done
    launches, seconds = c.take()
    assert launches == {"a": 2, "b": 1}
    assert seconds["a"] == pytest.approx([2e-3, 4e-3]) and math.isnan(seconds["b"][0])
    assert c.take() == ({}, {})  # taken: counting starts afresh
    c.launched("a", _Event(1))
    c.clear()
    assert c.take() == ({}, {})


def _kernel_params(path, name):
    src = (kernel_dir() / path).read_text()
    sig = src[src.index(f"__kernel void {name}("):]
    sig = sig[:sig.index(")\n{")]
    sig = re.sub(r"#if \w+|#endif", "", sig)
    return tuple(re.findall(r"(\w+)\s*$", p.strip())[0] for p in sig[sig.index("(") + 1:].split(",") if p.strip())


def test_argument_records_are_the_kernels_parameters_and_refuse_a_missing_buffer():
    assert tuple(TraceArgs.__dataclass_fields__) == _kernel_params("trace.cl", "trace_paths")
    assert tuple(PhotonPassArgs.__dataclass_fields__) == _kernel_params("photons.cl", "trace_photons")
    bufs = {n: object() for n in ("scene", "launch", "pix_sum", "pix_sq", "stats", "pix_jobs")}
    plain = TraceArgs(**bufs)
    assert plain.ordered(aux=False, photons=False) == list(bufs.values())
    with pytest.raises(ValueError, match="TraceArgs: no aux"):
        plain.ordered(aux=True, photons=False)
    with pytest.raises(ValueError, match="no ph_pos, ph_dir, ph_pow, bucket_start, ph_occ"):
        plain.ordered(aux=False, photons=True)
    with pytest.raises(ValueError, match="PhotonPassArgs: no n_stored"):
        PhotonPassArgs(*[object()] * 5, None).ordered()


def test_the_host_sets_every_field_of_the_trace_launch_record():
    """start() sets the image's fields, each item its own: none is left at
    the zero it was made with (group_offset included)."""
    names = set(layout.TRACE_LAUNCH.zeros(False).dtype.names)
    assert not set(IMAGE_FIELDS) & set(ITEM_FIELDS)
    assert set(IMAGE_FIELDS) | set(ITEM_FIELDS) == names


def _unset(rec, prefix=""):
    """Fields of rec whose bytes are all 0xA5 still."""
    out = []
    for name in rec.dtype.names:
        v = rec[name]
        if v.dtype.names:
            out += _unset(v, f"{prefix}{name}.")
        elif (np.ascontiguousarray(v).reshape(-1).view(np.uint8) == 0xA5).all():
            out.append(prefix + name)
    return out


def test_every_launch_record_field_is_set_before_a_launch(device_spec, monkeypatch):
    """A record made of 0xA5 bytes instead of zeros: start() and an item's
    record leave no field as it was made, for sample ranges and pixel lists,
    photon part included."""
    import clpt.engine.passes as passes

    made = passes.trace_record

    def poisoned(double):
        rec = made(double)
        rec.reshape(-1).view(np.uint8)[:] = 0xA5
        return rec

    monkeypatch.setattr(passes, "trace_record", poisoned)
    r = clpt.Renderer("cornell_box_caustics", device=device_spec)
    w = r.states[0]
    job = r.job(2, width=8, height=6, seed=3)
    w.start(job)
    w.prepare_photons(0)
    lookup = partial(w.photon.lookup, settings=job.photons, mode=job.pm_mode)
    rec, _ = w.trace.item_record(job.seed, WorkItem("samples", 0, 2), lookup)
    assert _unset(rec) == [] and rec["group_offset"] == 0
    jobs = np.ones((3, 4), np.uint32)
    rec, _ = w.trace.item_record(job.seed, WorkItem("pixels", pixels=np.arange(3), jobs=jobs), lookup)
    assert _unset(rec) == []


def _job(scene, spp=4, w=20, h=12, **kw):
    return RenderJob(clpt.load_scene(scene), spp, 3, 6, 3, w, h, **kw)


def test_trace_pass_records_for_ranges_and_pixel_lists(device_spec):
    r = clpt.Renderer("cornell_box", device=device_spec, lanes=4)
    w = r.states[0]
    job = r.job(4, width=20, height=12, seed=3)
    w.start(job)
    rec, gsize = w.trace.item_record(job.seed, WorkItem("samples", 2, 5))
    assert (rec["sample_begin"], rec["n_samples"], rec["n_list"], rec["group_offset"]) == (2, 5, 0, 0)
    assert (rec["width"], rec["height"], rec["seed"]) == (20, 12, 3)
    assert gsize % w.local == 0 and gsize * 4 >= 240
    pixels = np.array([5, 6, 7, 100, 101])
    jobs = np.zeros((5, 4), np.uint32)
    jobs[:, 0] = 2
    rec, gsize = w.trace.item_record(job.seed, WorkItem("pixels", pixels=pixels, jobs=jobs))
    assert (rec["n_list"], rec["n_samples"]) == (5, 0) and gsize == w.local  # 2 work-items of 4 lanes
    got = np.empty((5, 4), np.uint32)
    cl.enqueue_copy(w.dctx.queue, got, w.trace.jobs_buf)
    assert (got[:, 3] == pixels).all() and (got[:, 0] == 2).all()


def test_run_item_runs_one_item_on_the_first_live_worker():
    class Fake:
        def __init__(self, label):
            self.label, self.started, self.ran = label, None, []

        def start(self, job, initial=None):
            self.started = job

        def run(self, item):
            if item.kind == "fail":
                raise RuntimeError("lost")
            self.ran.append(item)
            return RunResult(seconds=1.0, photon_maps=[{"power": [1.0, 2.0, 3.0]}])

    job = _job("cornell_box")
    a, b = Fake("a"), Fake("b")
    ex = LocalExecutor([a, b])
    try:
        ex.drop(0)
        res = run_item(ex, job, WorkItem("photons"))
        assert res.photon_maps[0]["power"] == [1.0, 2.0, 3.0]
        assert b.started is job and [i.kind for i in b.ran] == ["photons"] and not a.ran
        with pytest.raises(RuntimeError, match="lost"):
            run_item(ex, job, WorkItem("fail"))
    finally:
        ex.close()


def test_the_pilot_is_a_photons_item_of_the_render_job(device_spec):
    """A "photons" item builds the job's first photon map and measures the
    power it stores; the render's pilot makes its choice from the same map."""
    r = clpt.Renderer("cornell_box_caustics", device=device_spec)
    res = r.render(2, width=16, height=12, seed=5)
    pilot = res.stats.photon_pilot
    assert pilot is not None and pilot["choice"] == "photon merging"
    job = r.job(2, width=16, height=12, seed=5)
    ex = LocalExecutor(r.states[:1])
    try:
        item = run_item(ex, job, WorkItem("photons", iteration=0))
    finally:
        ex.close()
    pm = item.photon_maps[0]
    assert item.stats.sum() == 0 and "trace_paths" not in item.launches and item.launches["trace_photons"] == 1
    n = job.photons.count
    pw = np.empty((n, 4), np.float32)
    cl.enqueue_copy(r.states[0].dctx.queue, pw, r.states[0].pmap.sorted[2])
    assert pm["power"] == pytest.approx(list(pw[:, :3].sum(axis=0, dtype=np.float64)), rel=1e-12)
    settings, info = pilot_choice(job.photons, pm["power"], r.packed.max_flux, pm["stored"], 0.0)
    assert info["caustic_share"] == pilot["caustic_share"] and info["stored"] == pilot["stored"]
    assert settings.count == job.photons.count and not settings.pilot


def test_the_tuning_trial_renders_a_job_on_one_worker(device_spec):
    r = clpt.Renderer("cornell_box_caustics", device=device_spec)
    states = list(r.states)
    rate, per_spp = r._trial(r.states[0], 2, 1)
    assert rate > 0 and per_spp > 0 and r.states == states
    # The trial's job leaves the worker ready for the Renderer's own renders.
    a = r.render(2, width=16, height=12, seed=5).image
    b = clpt.Renderer("cornell_box_caustics", device=device_spec).render(2, width=16, height=12, seed=5).image
    assert np.array_equal(a, b)
