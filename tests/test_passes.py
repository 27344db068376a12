"""The device side's passes (clpt/engine/passes.py) alone where they can be:
their counters with fake events, their typed argument records against the
kernels' parameters, and the launch record every field of which the host
sets; then, on the device, a worker's "photons" item (the photon pilot's
job) and the tuning trial as a job of its own."""

import dataclasses
import math
import re
from pathlib import Path
from functools import partial

import numpy as np
import pyopencl as cl
import pytest

import clpt
from clpt import constants, layout
from clpt.constants import LANE_PIXELS, work_item_entries
from clpt.engine.driver import run_item
from clpt.engine.executors import LocalExecutor
from clpt.engine.job import RenderJob, WorkItem
from clpt.engine.passes import IMAGE_FIELDS, ITEM_FIELDS, Counters, PhotonPassArgs, TraceArgs, pulls_runs
from clpt.engine.runresult import RunResult
from clpt.photons import (RELMSE_EPS, PhotonSettings, path_variance, pilot_choice, relmse_per_sample, trial_size,
                          weigh_cost)
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
    sig = src[src.index(f" void {name}("):]  # (after __kernel and any attributes)
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
    assert w.trace.pull == pulls_runs(w.dctx) and rec["pull_runs"] == w.trace.pull
    assert (rec["width"], rec["height"], rec["seed"]) == (20, 12, 3)
    assert w.trace.entries == work_item_entries(4) == 4 * LANE_PIXELS  # the most pixels a work-item takes
    e = int(rec["wi_entries"])  # (240 pixels: one per lane, so that the groups spread over the units)
    assert e == w.trace.entries_for(240) and 4 <= e <= w.trace.entries and e % 4 == 0
    assert gsize % w.local == 0 and gsize * e >= 240 and (gsize - w.local) * e < 240
    pixels = np.array([5, 6, 7, 100, 101])
    jobs = np.zeros((5, 4), np.uint32)
    jobs[:, 0] = 2
    rec, gsize = w.trace.item_record(job.seed, WorkItem("pixels", pixels=pixels, jobs=jobs))
    assert (rec["n_samples"], rec["wi_entries"]) == (0, 4)
    assert gsize == w.local  # two work-items' worth, in a whole group
    assert rec["n_list"] == 8 and rec["pull_runs"] == w.trace.pull  # two runs as uploaded, the last padded
    got = np.empty((9, 4), np.uint32)
    cl.enqueue_copy(w.dctx.queue, got, w.trace.jobs_buf)
    assert (got[:5, 3] == pixels).all() and (got[:5, 0] == 2).all()
    assert (got[5:8, 0] == 0).all() and (got[5:8, 3] == 0xFFFFFFFF).all()  # no samples: lanes skip them
    assert (got[8] == 0).all()  # the runs' counter (kernels/film.h lane_pull)


def _gaussian_box():
    s = clpt.load_scene("cornell_box")
    return dataclasses.replace(s, camera=dataclasses.replace(s.camera, pixel_filter=clpt.PixelFilter("gaussian")))


@pytest.mark.parametrize("scene,kw", [
    ("cornell_box", dict(spp=12, adaptive=clpt.AdaptiveSettings(min_spp=4, pass_spp=4), aux=True)),
    ("cornell_box_caustics", dict(spp=16)),
    (_gaussian_box, dict(spp=12)),
])
def test_lanes_taking_pixels_in_turn_give_the_same_bits(device_spec, monkeypatch, scene, kw):
    """A lane that has finished its pixel takes the work-item's next one
    (kernels/film.h lane_next): the image, the sample counts, the features and
    the ray counts are the same bits as with one pixel per lane, on an image
    whose pixels do not fill the last work-item, in uniform and adaptive
    passes, with photon merging, and with a Gaussian pixel filter (whose
    samples by the film's edge are drawn lane by lane: kernels/camera.h)."""
    scene = scene() if callable(scene) else scene
    kw = dict(width=23, height=13, seed=5, max_depth=16, **kw)
    aux = kw.pop("aux", False)
    out = {}
    for lp in (1, 3):
        monkeypatch.setattr(constants, "LANE_PIXELS", lp)
        r = clpt.Renderer(scene, device=device_spec, lanes=8, aux=aux)
        res = r.render(**kw)
        assert r.states[0].trace.entries == 8 * lp
        assert r.states[0].trace.entries_for(1 << 20) == 8 * lp
        out[lp] = res
    a, b = out[1], out[3]
    assert np.array_equal(a.image, b.image) and np.array_equal(a.sample_count, b.sample_count)
    assert np.array_equal(a.lum_var, b.lum_var)
    assert (a.stats.camera_rays, a.stats.bounce_rays, a.stats.shadow_rays) == \
        (b.stats.camera_rays, b.stats.bounce_rays, b.stats.shadow_rays)
    assert a.stats.camera_rays > 0
    for k in (a.aux or {}):
        assert np.array_equal(np.asarray(a.aux[k]), np.asarray(b.aux[k])), k
    assert bool(a.aux) == aux


@pytest.mark.parametrize("lanes, n, units, local, want", [
    (1, 10**6, 2, 16, 1),          # one lane: one pixel
    (16, 128 * 128, 2, 16, 64),    # 128 work-groups per unit even at four pixels a lane
    (16, 64 * 64, 2, 16, 32),      # two pixels a lane: 8 work-groups, 4 per unit
    (16, 32 * 32, 2, 16, 16),      # one pixel a lane (fewer would idle lanes): 4 work-groups
    (16, 32 * 32, 64, 16, 16),     # a many-core CPU: never below one pixel per lane
    (8, 1920 * 1080, 64, 16, 32),  # 64 units, a full HD image: four pixels a lane
    (8, 512 * 512, 64, 16, 32),    # 512 x 512 on 64 units: four pixels a lane
    (8, 256 * 256, 64, 16, 16),    # 256 x 256 on 64 units: two pixels a lane
])
def test_work_item_entries_keep_every_unit_busy(lanes, n, units, local, want):
    e = work_item_entries(lanes, n, units, local)
    assert e == want and e % lanes == 0 and lanes <= max(e, lanes) <= lanes * LANE_PIXELS
    groups = -(-(-(-n // e)) // local)
    assert groups >= constants.GROUPS_PER_UNIT * units or e == lanes


def test_entries_per_work_item_leave_the_bits_alone(device_spec):
    """An image whose launches take one pixel per lane (a small one) and
    the same image with four per lane: the same bits."""
    r = clpt.Renderer("cornell_box_caustics", device=device_spec, lanes=8)
    t = r.states[0].trace
    kw = dict(spp=6, width=40, height=24, seed=2, max_depth=12)
    a = r.render(**kw)
    assert t.wi_entries < t.entries  # (2 work-groups per unit at most on any CPU here)
    t.entries_for = lambda n: t.entries
    b = r.render(**kw)
    assert t.wi_entries == t.entries
    assert np.array_equal(a.image, b.image) and np.array_equal(a.lum_var, b.lum_var)


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
    r = clpt.Renderer("cornell_box_caustics", device=device_spec, photons=PhotonSettings(pilot_trial=False))
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


def test_a_path_tracing_choice_renders_with_the_build_without_photons(device_spec):
    """Where the pilot chooses path tracing (caustic photons carry under
    min_caustic_share of the power), the render runs on a build without the
    photon map's code: the image photons=False gives, bit for bit, and the
    result's kernel says so."""
    scene = str(Path(__file__).parent / "data" / "many_lights_glass.xml")
    r = clpt.Renderer(scene, device=device_spec)
    assert r.features.photons
    res = r.render(2, width=16, height=12, seed=5)
    pilot = res.stats.photon_pilot
    assert pilot["choice"] == "path tracing" and 0 < pilot["caustic_share"] < PhotonSettings().min_caustic_share
    assert not res.features.photons and res.photons is None
    plain = clpt.Renderer(scene, device=device_spec, photons=False).render(2, width=16, height=12, seed=5)
    assert np.array_equal(res.image, plain.image) and np.array_equal(res.lum_var, plain.lum_var)
    # Adaptive renders ask the pilot too.
    ad = clpt.AdaptiveSettings(min_spp=2, pass_spp=2, threshold=0.05)
    res = r.render(6, width=16, height=12, seed=5, adaptive=ad)
    plain = clpt.Renderer(scene, device=device_spec, photons=False).render(6, width=16, height=12, seed=5,
                                                                            adaptive=ad)
    assert res.stats.photon_pilot["choice"] == "path tracing" and not res.features.photons
    assert np.array_equal(res.image, plain.image) and np.array_equal(res.sample_count, plain.sample_count)
    # A share above the threshold merges, on the photon build.
    low = r.render(2, width=16, height=12, seed=5, photons=PhotonSettings(min_caustic_share=1e-4))
    assert low.stats.photon_pilot["choice"] == "photon merging" and low.features.photons
    assert not np.array_equal(low.image, plain.image)


def test_the_tuning_trial_renders_a_job_on_one_worker(device_spec):
    r = clpt.Renderer("cornell_box_caustics", device=device_spec)
    states = list(r.states)
    rate, per_spp = r._trial(r.states[0], 2, 1)
    assert rate > 0 and per_spp > 0 and r.states == states
    # The trial's job leaves the worker ready for the Renderer's own renders.
    a = r.render(2, width=16, height=12, seed=5).image
    b = clpt.Renderer("cornell_box_caustics", device=device_spec).render(2, width=16, height=12, seed=5).image
    assert np.array_equal(a, b)


def test_the_pilot_weighs_each_techniques_error_against_its_cost(device_spec):
    """Where caustic photons carry light, the pilot renders a small trial with
    each technique and keeps merging only if its relMSE per second is the
    lower: the errors come from the trial images alone (reproducible from the
    seed), the costs from the trial's device seconds, measured once per
    device and trial and cached, so the same seed makes the same choice."""
    r = clpt.Renderer("cornell_box_caustics", device=device_spec, photons=PhotonSettings(pilot_trial=True))
    a = r.render(2, width=40, height=30, seed=5).stats.photon_pilot
    b = r.render(2, width=40, height=30, seed=5).stats.photon_pilot
    assert a["relmse_per_sample"] == b["relmse_per_sample"]  # bit for bit: the same trial images
    assert a["seconds_per_sample"] == b["seconds_per_sample"] and a["choice"] == b["choice"]  # costs measured once
    assert a["relmse_per_sample"]["merge"] != a["relmse_per_sample"]["path"]
    for p in (a, b):
        at_1s = {k: p["relmse_per_sample"][k] * p["seconds_per_sample"][k] * 40 * 30 for k in ("merge", "path")}
        assert p["predicted_relmse_1s"] == pytest.approx(at_1s, rel=1e-12)
        assert p["choice"] == ("photon merging" if at_1s["merge"] < at_1s["path"] else "path tracing")
    c = r.render(2, width=40, height=30, seed=6).stats.photon_pilot
    assert c["relmse_per_sample"] != a["relmse_per_sample"]  # another seed, other trial samples


def test_the_merges_estimate_path_tracings_variance_on_the_paths_they_take(device_spec):
    """The merges' photons estimate path tracing's second moment on the paths
    they take (kernels/photon_grid.h): with merging's own variance it must
    match path tracing's variance, measured by brute force (8192 spp), in the
    caustic's pixels. On cornell_box_caustics path tracing finds the caustic
    often enough for the brute force to be reliable (under a small bulb,
    16384 spp still miss most of its rare paths: there the moment is what
    the pilot needs, and the brute force cannot check it). Measured at
    24x24, two seeds: estimate / brute force 1.03 and 1.13; merging's
    variance alone 0.65 and 0.76 of it."""
    from dataclasses import replace

    r = clpt.Renderer("cornell_box_caustics", device=device_spec, photons=PhotonSettings(pilot=False), aux=True)
    size = dict(width=24, height=24, max_depth=64)
    pt = r.render(8192, seed=11, photons=PhotonSettings(count=0), **size).lum_var.astype(np.float64)
    merge = r.render(64, seed=12, **size).lum_var.astype(np.float64)
    job = r.job(64, seed=13, photons=PhotonSettings(pilot=False), **size)
    moment = r._run(replace(job, moments=True), None, None, 0.0).aux["caustic_sq"].astype(np.float64)
    assert np.isfinite(moment).all() and (moment >= 0).all()
    caustic = moment > 0.05 * moment.max()
    assert caustic.sum() >= 5
    ratio = path_variance(np.zeros_like(moment), merge, moment)[caustic].mean() / pt[caustic].mean()
    assert 0.8 < ratio < 1.6, ratio
    assert merge[caustic].mean() < 0.8 * pt[caustic].mean()  # (so the moment is what brings it up)
    # Without moments (the same build, RenderJob.moments off) the plane holds the caustic's squares.
    plain = r._run(job, None, None, 0.0).aux["caustic_sq"].astype(np.float64)
    assert not np.allclose(plain, moment)


def test_path_variance_is_the_trials_or_merging_plus_the_moment():
    trial = np.array([1.0, 5.0, 0.5, 2.0])
    merge = np.array([0.5, 0.5, 0.5, 0.5])
    moment = np.array([2.0, 1.0, -1.0, np.inf])  # a negative moment counts as 0, a non-finite one not at all
    assert np.array_equal(path_variance(trial, merge, moment), [2.5, 5.0, 0.5, 2.0])


def test_weigh_cost_keeps_merging_only_where_it_reaches_the_lower_error_per_second():
    base = PhotonSettings(count=1000)
    info = {"choice": "photon merging", "caustic_share": 0.1}
    # merging halves the error per sample but costs three times as much: path tracing wins
    s, out = weigh_cost(base, info, 100, {"merge": 0.1, "path": 0.2}, {"merge": 3e-6, "path": 1e-6})
    assert s.count == 0 and out["choice"] == "path tracing"
    assert out["predicted_gain"] == pytest.approx((0.2 * 1e-6) / (0.1 * 3e-6))
    # ... and at 1.5 times the cost, merging
    s, out = weigh_cost(base, info, 100, {"merge": 0.1, "path": 0.2}, {"merge": 1.5e-6, "path": 1e-6})
    assert s.count == 1000 and out["choice"] == "photon merging"
    assert out["predicted_relmse_1s"]["merge"] == pytest.approx(0.1 * 1.5e-6 * 100)


def test_the_trial_relmse_uses_both_techniques_mean_as_reference():
    ref = np.full((2, 2), 0.5)
    out = relmse_per_sample({"path": (ref * 0.8, np.full((2, 2), 0.3)), "merge": (ref * 1.2, np.full((2, 2), 0.1))})
    den = 0.25 + RELMSE_EPS
    assert out == pytest.approx({"path": 0.3 / den, "merge": 0.1 / den})
    assert trial_size(1920, 1080)[0] * trial_size(1920, 1080)[1] <= 64 * 64
    assert trial_size(16, 12) == (16, 12)


@pytest.mark.parametrize("scene", ["cornell_box", "cornell_box_caustics"])
def test_pulled_runs_give_the_same_bits(device_spec, scene):
    """Work-items that pull their runs from a counter (TracePass.pull, as on
    CPUs: kernels/film.h lane_pull) and work-items that keep their own run
    give the same sums bit for bit: two launches over the image (each starts
    its counter from 0, so the second's samples all arrive) on an image whose
    last run is part empty, then an adaptive list."""
    r = clpt.Renderer(scene, device=device_spec, lanes=4)
    w = r.states[0]
    if w.dctx.is_pocl and not pulls_runs(w.dctx):
        pytest.skip(f"this PoCL ({w.dctx.device.driver_version}) renders pulled runs wrong: they stay off there")
    job = r.job(9, width=61, height=37, seed=7)
    pixels = np.arange(0, 61 * 37, 3, dtype=np.uint32)[::-1].copy()
    jobs = np.zeros((len(pixels), 4), np.uint32)
    jobs[:, 0] = 1 + pixels % 5
    jobs[:, 1] = job.max_depth
    jobs[:, 2] = 9
    got = []
    kept = w.trace.pull
    try:
        for pull in (False, True):
            w.trace.pull = pull
            w.start(job)
            assert w.trace.global_size // w.local >= 3
            w.run(WorkItem("samples", 0, 6))
            w.run(WorkItem("samples", 6, 3))
            w.run(WorkItem("pixels", pixels=pixels, jobs=jobs))
            got.append(w.sums())
    finally:
        w.trace.pull = kept
    assert got[0].samples == got[1].samples == 61 * 37 * 9 + int(jobs[:, 0].sum())
    for k, v in got[0].planes.items():
        np.testing.assert_array_equal(v, got[1].planes[k], err_msg=k)


def test_runs_are_pulled_on_the_cpu_runtimes_checked():
    """Pulled runs on Intel's CPU runtime and PoCL 3.1 and later; not on
    GPUs (coherent work-groups), not on PoCL 3.0 (wrong images)."""
    import types

    def fake(platform, cpu, version=""):
        kind = cl.device_type.CPU if cpu else cl.device_type.GPU
        return types.SimpleNamespace(platform=platform, is_cpu=cpu, is_pocl="Portable" in platform,
                                     device=types.SimpleNamespace(type=kind, driver_version=version))
    assert pulls_runs(fake("Intel(R) OpenCL", True))
    assert pulls_runs(fake("Portable Computing Language", True, "3.1+debian"))
    assert pulls_runs(fake("Portable Computing Language", True, "6.0"))
    assert not pulls_runs(fake("Portable Computing Language", True, "3.0-rc2"))
    assert not pulls_runs(fake("Portable Computing Language", False, "6.0"))
    assert not pulls_runs(fake("NVIDIA CUDA", False))
    assert not pulls_runs(fake("Oclgrind", False))
