"""Checkpoints and resume: a render stopped and continued gives the image of
the uninterrupted render bit for bit (same device), checkpoints of another
render are refused, signals leave an image and a checkpoint, and SIGKILL at
random moments never leaves a checkpoint that cannot be read."""

import dataclasses
import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

import clpt
from clpt.engine.checkpoint import Checkpoint, CheckpointError
from clpt.photons import PhotonSettings


def stop_after(spp):
    """A stop event and a progress callback that sets it once spp samples are in."""
    ev = threading.Event()

    def progress(done, total, elapsed, rate):
        if done >= spp:
            ev.set()

    return ev, progress


def _gaussian_box():
    s = clpt.load_scene("cornell_box")
    return dataclasses.replace(s, camera=dataclasses.replace(s.camera, pixel_filter=clpt.PixelFilter("gaussian")))


def _lit_box():
    s = _gaussian_box()
    lights = [clpt.PointLight(position=(0.2, 1.5, 0.1), intensity=(0.5, 0.4, 0.3)),
              clpt.SpotLight(position=(-0.3, 1.5, 0.2), intensity=(1.0, 1.0, 1.0), direction=(0, -1, 0),
                             cutoff_angle=30)]
    return dataclasses.replace(s, shapes=list(s.shapes) + lights)


def _sky_scene():
    sky = np.full((8, 16, 3), 0.5, dtype=np.float32)
    sky[2, 3] = 40.0
    return clpt.Scene(camera=clpt.Camera(origin=(0, 1, 3), target=(0, 0.3, 0)), shapes=[
        clpt.Sphere(center=(0, 0.5, 0), radius=0.5, material=clpt.Material(kd=(0.6, 0.5, 0.4))),
        clpt.Quad(corner=(-2, 0, 2), edge_u=(4, 0, 0), edge_v=(0, 0, -4)),
        clpt.EnvironmentLight(image=sky, scale=0.8, to_world=((0, 0, 1), (0, 1, 0), (-1, 0, 0))),
        clpt.DirectionalLight(direction=(0.3, -1, 0.2), irradiance=(2, 2, 1.5))])


CASES = {
    "plain": ("cornell_box", {}, {}),
    "delta_lights": (_lit_box(), {}, {}),  # point and spot lights travel in the checkpoint
    "infinite_lights": (_sky_scene(), {}, {}),  # an environment map and a directional light too
    "pixel_filter": (_gaussian_box(), {}, {}),  # the camera's filter travels in the checkpoint
    "kahan": ("cornell_box", {"accumulate": "kahan"}, {}),
    "progressive": ("cornell_box_caustics", {}, {"photons": PhotonSettings(count=20_000, progressive=True,
                                                                           spp_per_map=2, pilot=False)}),
    "offline": ("cornell_box_caustics", {}, {"photons": PhotonSettings(count=20_000, mode="offline",
                                                                       offline_spp=4)}),
    "adaptive": ("cornell_box", {}, {"adaptive": clpt.AdaptiveSettings(min_spp=8, pass_spp=8)}),
    # Adaptive rounds over progressive photon maps: the maps the rounds used travel in the checkpoint.
    "adaptive_progressive": ("cornell_box_caustics", {}, {
        "adaptive": clpt.AdaptiveSettings(min_spp=4, pass_spp=8, threshold=1e-3),
        "photons": PhotonSettings(count=20_000, progressive=True, spp_per_map=2, pilot=False)}),
    "filtered": ("cornell_box", {"aux": True}, {"filter": clpt.FilterSettings()}),
    # Textures travel in the checkpoint (their texels as arrays).
    "textures": (str(Path(__file__).parent / "data" / "cbox_textured.xml"), {}, {}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_stop_and_resume_is_bit_identical(device_spec, tmp_path, case):
    scene, rkw, kw = CASES[case]
    r = clpt.Renderer(scene, device=device_spec, **rkw)
    args = dict(seed=4, width=20, height=12, **kw)
    ref = r.render(40, **args)
    ck = tmp_path / "r.ckpt"
    stop, progress = stop_after(5)
    part = r.render(40, **args, checkpoint=ck, stop=stop, progress=progress, pass_seconds=1e-9)
    assert part.interrupted and ck.is_file() and 0 < part.samples < ref.samples
    meta = Checkpoint(ck).meta
    assert meta["samples"] == part.samples and meta["clpt_version"] == clpt.__version__
    # Continue from a second interruption too (a checkpoint of a resumed render).
    stop2, progress2 = stop_after(12)
    mid = r.resume(ck, stop=stop2, progress=progress2, pass_seconds=1e-9)
    assert mid.samples >= part.samples
    res = r.resume(ck)
    assert not res.interrupted
    assert np.array_equal(res.image, ref.image) and np.array_equal(res.lum_var, ref.lum_var)
    assert np.array_equal(res.sample_count, ref.sample_count)
    if ref.filtered is not None:
        assert np.array_equal(res.filtered, ref.filtered)
    assert clpt.render_resume(ck, device=device_spec).samples == ref.samples  # from the file alone


def test_other_scene_settings_or_version_are_refused(device_spec, tmp_path):
    r = clpt.Renderer("cornell_box", device=device_spec)
    ck = tmp_path / "r.ckpt"
    stop, progress = stop_after(1)
    r.render(1000, width=8, height=8, checkpoint=ck, stop=stop, progress=progress, pass_seconds=1e-9)
    with pytest.raises(CheckpointError, match="another scene"):
        clpt.Renderer("cornell_box_caustics", device=device_spec).resume(ck)
    with pytest.raises(CheckpointError, match="other settings.*nee"):
        clpt.Renderer("cornell_box", device=device_spec, nee=False).resume(ck)
    # Another version: rewrite the meta entry.
    with np.load(ck) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(bytes(arrays["meta"]).decode())
    meta["clpt_version"] = "0.0.1"
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    old = tmp_path / "old.ckpt"
    with open(old, "wb") as f:
        np.savez(f, **arrays)
    with pytest.raises(CheckpointError, match="clpt 0.0.1"):
        r.resume(old)
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(ck.read_bytes()[:200])
    with pytest.raises(CheckpointError, match="damaged"):
        r.resume(bad)


def test_a_time_limit_render_is_complete_not_interrupted(device_spec, tmp_path):
    r = clpt.Renderer("cornell_box", device=device_spec)
    ck = tmp_path / "t.ckpt"
    res = r.render(1 << 24, width=8, height=8, time_limit=0.5, checkpoint=ck)
    assert not res.interrupted and 0 < res.samples and not ck.exists()


def test_nothing_is_written_before_the_first_sample(device_spec, tmp_path):
    r = clpt.Renderer("cornell_box", device=device_spec)
    stop = threading.Event()
    stop.set()
    ck = tmp_path / "r.ckpt"
    res = r.render(10, width=8, height=8, checkpoint=ck, stop=stop)
    assert res.interrupted and res.samples == 0 and not ck.exists()


def test_periodic_checkpoints_are_written(device_spec, tmp_path):
    r = clpt.Renderer("cornell_box", device=device_spec)
    ck = tmp_path / "r.ckpt"
    res = r.render(300, width=16, height=16, checkpoint=ck, checkpoint_every=1e-9, pass_seconds=1e-9)
    assert len(res.stats.checkpoints) >= 2 and ck.is_file()  # kept: resume turns it into the image at once
    assert Checkpoint(ck).sums.samples == res.samples or Checkpoint(ck).sums.samples < res.samples


# --- the command line, with signals ------------------------------------------------------------

def clpt_cmd(*args, device_spec=None):
    return [sys.executable, "-m", "clpt", "render", *args] + (["--device", device_spec] if device_spec else [])


def wait_for(p, text, timeout=120):
    buf, deadline = "", time.time() + timeout
    while text not in buf and time.time() < deadline:
        c = p.stderr.read(1)
        if not c:
            break
        buf += c
    return buf


# About 2 s of rendering on 2 free cores (7.7 M samples): long enough to be
# killed or stopped mid-render once the process has started.
RENDER = ["--spp", "20000", "--width", "24", "--height", "16", "--seed", "5"]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory, device_spec):
    out = tmp_path_factory.mktemp("ref") / "ref.exr"
    subprocess.run(clpt_cmd(*RENDER, "-o", str(out), "-q", device_spec=device_spec), check=True)
    return clpt.load_image(out)


def test_sigterm_leaves_image_and_checkpoint_and_resume_finishes_it(tmp_path, device_spec, uninterrupted):
    out = tmp_path / "t.exr"
    p = subprocess.Popen(clpt_cmd(*RENDER, "-o", str(out), "--progress", device_spec=device_spec),
                         stderr=subprocess.PIPE, text=True)
    wait_for(p, "spp")
    p.send_signal(signal.SIGTERM)
    # A second signal while it finishes the pass in flight: the image is still written whole.
    head = wait_for(p, "finishing the work in flight")
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    err = head + err
    assert p.returncode == 143, err
    ck = tmp_path / "t.exr.ckpt"
    assert out.is_file() and ck.is_file() and "--resume" in err and "still writing" in err
    assert Checkpoint(ck).sums.samples > 0
    r = subprocess.run(clpt_cmd("--resume", str(ck), "-q", device_spec=device_spec), capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert np.array_equal(clpt.load_image(out), uninterrupted) and not ck.exists()


def kill_resume_cycles(out, cycles, device_spec=None, seed=0, log=None, render=RENDER, every="0.05"):
    """Start (or resume) the CLI render, SIGKILL it after a random time, again
    and again; then let it finish. Returns (kills, resumes, checkpoints seen,
    kills that cut a checkpoint write short)."""
    rng = random.Random(seed)
    ck = out.with_name(out.name + ".ckpt")
    kills = resumes = seen = mid_write = 0
    for i in range(cycles + 1):
        if ck.exists():
            Checkpoint(ck)  # never half-written: it always reads
            seen += 1
            cmd, resumes = clpt_cmd("--resume", str(ck), "-o", str(out), "-q", "--checkpoint-every", every,
                                    device_spec=device_spec), resumes + 1
        else:
            cmd = clpt_cmd(*render, "-o", str(out), "-q", "--checkpoint-every", every, device_spec=device_spec)
        p = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
        if i < cycles:
            time.sleep(rng.uniform(0.4, 2.5))
            if p.poll() is None:
                p.send_signal(signal.SIGKILL)
                kills += 1
        err = p.communicate(timeout=600)[1]
        cut = [f for f in out.parent.glob(f".{ck.name}.*.tmp")]
        mid_write += bool(cut)
        for f in cut:
            f.unlink()
        if log:
            log(f"cycle {i}: rc {p.returncode}, checkpoint {'yes' if ck.exists() else 'no'}"
                f"{', killed during a checkpoint write' if cut else ''}")
        if p.returncode == 0:
            break
        assert p.returncode == -signal.SIGKILL, err
    return kills, resumes, seen, mid_write


def test_sigkill_at_random_moments_then_resume(tmp_path, device_spec, uninterrupted):
    out = tmp_path / "k.exr"
    kills, resumes, seen, _ = kill_resume_cycles(out, 3, device_spec, seed=1)
    assert kills >= 1
    # The last run may be a fresh start if every kill came before the first checkpoint.
    assert np.array_equal(clpt.load_image(out), uninterrupted)
    leftovers = [f for f in os.listdir(tmp_path) if f.startswith(".")]
    assert not [f for f in leftovers if not f.endswith(".tmp") and not f.endswith(".tmp.exr")]


def test_on_update_between_passes_and_once_at_the_end(device_spec):
    r = clpt.Renderer("cornell_box", device=device_spec, aux=True)
    ups = []
    res = r.render(12, width=16, height=8, filter=clpt.FilterSettings(), on_update=ups.append, update_interval=0,
                   pass_seconds=1e-9)
    assert len(ups) >= 3 and [u.final for u in ups].count(True) == 1 and ups[-1].final
    assert all(u.filtered is None for u in ups[:-1]) and np.array_equal(ups[-1].filtered, res.filtered)
    spp = [u.spp_done for u in ups]
    assert spp == sorted(spp) and spp[-1] == 12 and ups[-1].spp_total == 12
    last = ups[-1]
    assert last.image.shape == (8, 16, 3) and last.image.dtype == np.float32
    assert np.array_equal(last.image, res.image) and np.array_equal(last.sample_count, res.sample_count)
    assert {"normal", "albedo", "depth", "emission", "caustic"} <= set(last.aux) and last.elapsed > 0
    few = []
    r.render(12, width=16, height=8, on_update=few.append, update_interval=1e9, pass_seconds=1e-9)
    # At most every update_interval: here the first item done, then only the final image.
    assert len(few) == 2 and not few[0].final and few[1].final
