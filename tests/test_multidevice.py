"""Several devices on one render: PoCL split into two devices gives the
one-device image (in one process, and each device in a process of its own), and a device that fails mid-render leaves its work to the
other without losing a sample."""

import json
import os
import subprocess
import sys
import threading

import numpy as np
import pytest

import clpt

SPLIT = r"""
import json, sys, numpy as np, clpt
try:
    pocl = clpt.device.select_devices("pocl")[0].platform.get_devices()  # the first PoCL that renders here
except clpt.DeviceError as e:
    print(json.dumps({"devices": 0, "why": str(e)}))
    sys.exit(0)
ph = clpt.PhotonSettings(pilot=False)  # the same technique on one device and on two
one = clpt.Renderer("cornell_box_caustics", device=pocl[0], photons=ph).render(24, width=24, height=16, seed=9,
                                                                                 pass_seconds=0.02)
r = clpt.Renderer("cornell_box_caustics", device=list(pocl), photons=ph)
two = r.render(24, width=24, height=16, seed=9, pass_seconds=0.02)
labels = [p[0] for p in two.stats.passes]
procs = r.render(24, width=24, height=16, seed=9, pass_seconds=0.02, executor="processes")
plabels = {p[0] for p in procs.stats.passes}
print(json.dumps({"devices": len(r.states), "same_label_passes": [labels.count(l) for l in sorted(set(labels))],
                  "max_rel": float(np.max(np.abs(one.image - two.image) / np.maximum(np.abs(one.image), 1e-6))),
                  "counts_equal": bool(np.array_equal(one.sample_count, two.sample_count)),
                  "proc_rel": float(np.max(np.abs(one.image - procs.image) / np.maximum(np.abs(one.image), 1e-6))),
                  "proc_counts_equal": bool(np.array_equal(one.sample_count, procs.sample_count)),
                  "proc_labels": sorted(plabels)}))
"""


def test_pocl_split_in_two_devices_gives_the_one_device_image(tmp_path):
    # This PoCL names the per-device thread count POCL_MAX_PTHREAD_COUNT (newer ones POCL_CPU_MAX_CU_COUNT).
    env = dict(os.environ, POCL_DEVICES="pthread pthread", POCL_MAX_PTHREAD_COUNT="1", POCL_CPU_MAX_CU_COUNT="1")
    env.pop("PYOPENCL_CTX", None)
    p = subprocess.run([sys.executable, "-c", SPLIT], env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout.strip().splitlines()[-1])
    if out["devices"] == 0:
        pytest.skip(f"no PoCL renders here: {out['why']}")
    if out["devices"] < 2:
        pytest.skip("this PoCL does not split into two devices")
    assert out["counts_equal"] and len(out["same_label_passes"]) >= 1
    # Only the order of the float64 additions differs: equal to float32 rounding.
    assert out["max_rel"] < 1e-6
    # Each device in a process of its own: the same image, and both processes did work.
    assert out["proc_counts_equal"] and out["proc_rel"] < 1e-6
    assert len(out["proc_labels"]) == 2 and all("[process" in label for label in out["proc_labels"])


def test_a_device_failing_mid_render_leaves_its_work_to_the_other(device_spec):
    dev = clpt.device.select_devices(device_spec)[0]
    ph = clpt.PhotonSettings(count=20_000, progressive=False, pilot=False)  # one map: ranges of any size
    one = clpt.Renderer("cornell_box_caustics", device=dev).render(16, width=16, height=16, seed=9, photons=ph)
    r = clpt.Renderer("cornell_box_caustics", device=[dev, dev])
    good, bad = r.states
    real_run, good_run, calls = bad.run, good.run, []
    failed = threading.Event()

    def failing(item):
        calls.append(item)
        if len(calls) > 2:
            failed.set()
            raise clpt.DeviceError("device lost (CL_OUT_OF_RESOURCES)")
        return real_run(item)

    def waiting(item):
        # The other device's work waits for the failure: else, on a busy machine, it could take
        # every range before the failing one had its third (and the test would test nothing).
        failed.wait(timeout=60)
        return good_run(item)

    bad.run, good.run = failing, waiting
    with pytest.warns(UserWarning, match="device lost"):
        two = r.render(16, width=16, height=16, seed=9, pass_seconds=1e-9, photons=ph)
    assert len(calls) == 3 and two.stats.failures and "device lost" in two.stats.failures[0][1]
    assert (two.sample_count == 16).all()
    assert np.allclose(one.image, two.image, rtol=1e-5, atol=1e-6)
    # The next render uses both devices again.
    bad.run, good.run = real_run, good_run
    again = r.render(16, width=16, height=16, seed=9, photons=ph)
    assert not again.stats.failures and len({p[0] for p in again.stats.passes}) >= 1


def test_a_device_process_that_dies_leaves_its_work_to_the_others(device_spec):
    """Two worker processes on one device; one is killed mid-render: the
    render finishes on the other with every sample, and the next render
    starts a fresh process."""
    import signal

    dev = clpt.device.select_devices(device_spec)[0]
    r = clpt.Renderer("cornell_box", device=[dev, dev])
    one = clpt.Renderer("cornell_box", device=dev).render(12, width=16, height=16, seed=4)
    killed = threading.Event()

    def kill_one(done, total, elapsed, rate):
        if done >= 2 and not killed.is_set():
            killed.set()
            os.kill(r._processes.children[1].proc.pid, signal.SIGKILL)

    with pytest.warns(UserWarning, match="its work goes to the others"):
        res = r.render(12, width=16, height=16, seed=4, executor="processes", pass_seconds=1e-9, progress=kill_one)
    assert killed.is_set() and res.stats.failures
    assert (res.sample_count == 12).all() and np.allclose(res.image, one.image, rtol=1e-6, atol=1e-7)
    again = r.render(12, width=16, height=16, seed=4, executor="processes")
    assert not again.stats.failures and np.allclose(again.image, one.image, rtol=1e-6, atol=1e-7)


def test_a_device_split_into_sub_devices_renders_one_image(device_spec):
    """"SPEC/2" splits a device into two sub-devices of half its compute
    units (device fission); they render one image together, told apart in
    the stats, equal to the whole device's image to float rounding."""
    dev = clpt.device.select_devices(device_spec)[0]
    if dev.max_compute_units < 2 or dev.max_compute_units % 2:
        pytest.skip(f"{dev.name} has {dev.max_compute_units} compute units")
    try:
        subs = clpt.device.split_device(dev, 2)
    except clpt.DeviceError as e:
        pytest.skip(str(e))
    assert len(subs) == 2 and all(s.max_compute_units == dev.max_compute_units // 2 for s in subs)
    one = clpt.Renderer("cornell_box", device=dev).render(16, width=32, height=16, seed=2)
    r = clpt.Renderer("cornell_box", device=subs)
    two = r.render(16, width=32, height=16, seed=2, pass_seconds=1e-9)
    labels = {p[0] for p in two.stats.passes}
    assert len(set(two.devices)) == 2 and labels == set(two.devices)
    assert (two.sample_count == 16).all() and np.allclose(two.image, one.image, rtol=1e-6, atol=1e-7)
    with pytest.raises(clpt.DeviceError, match="compute units"):
        clpt.device.split_device(dev, dev.max_compute_units + 1)
