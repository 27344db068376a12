"""The command line: images written with metadata, clean errors with exit
codes, Ctrl-C writing what was rendered, `python -m clpt`."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import clpt
from clpt.cli import main
from clpt.image import read_metadata


def test_render_png_and_exr(tmp_path, device_spec, capsys):
    dev = ["--device", device_spec] if device_spec else []
    png, exr = tmp_path / "a.png", tmp_path / "sub" / "a.exr"
    assert main(["render", "--spp", "2", "--width", "20", "--height", "10", "-o", str(png), "-q", *dev]) == 0
    assert main(["render", "cornell_box", "--spp", "3", "--width", "20", "--height", "10", "--seed", "5",
                 "--max-depth", "4", "-o", str(exr), "-v", *dev]) == 0
    err = capsys.readouterr().err
    assert "kernel: specialized" in err and "rays:" in err and "wrote" in err
    p = clpt.load_image(png)
    assert p.shape == (10, 20, 3) and 0 < p.mean() < 1
    e = clpt.load_image(exr)
    assert e.shape == (10, 20, 3) and np.isfinite(e).all()
    meta = read_metadata(exr)
    assert meta["clpt:spp"] == 3 and meta["clpt:seed"] == 5 and meta["clpt:max_depth"] == 4
    assert "clpt:device" in meta and "clpt:render_seconds" in meta


def test_scene_mistake_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[camera]\norigin = [0,0,1]\ntarget = [0,0,0]\nfov = 40\n[[shapes]]\ntype = "sphere"\n'
                   'material = "white"\ncenter = [0,0,0]\nradius = -1\nemission = 1\n')
    assert main(["render", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"clpt: error: {bad}: shapes[0].radius: must be > 0.0 (got -1.0)"
    assert main(["render", str(tmp_path / "missing.toml")]) == 2
    assert "no such scene file" in capsys.readouterr().err
    assert main(["check", str(bad)]) == 2


@pytest.mark.parametrize("argv, flag", [
    (["bench-photons", "--counts", "1e5,lots"], "--counts"),
    (["bench-photons", "--counts", "-5"], "--counts"),
    (["bench-photons", "--equal-time", "4,soon"], "--equal-time"),
    (["bench-photons", "--equal-time", "0"], "--equal-time"),
    (["bench-bvh", "--triangles", "1e3,x"], "--triangles")])
def test_bench_lists_refused_in_one_line(argv, flag, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {flag}" in err and "Traceback" not in err


def test_bench_lists_parse():
    from clpt.cli import build_parser

    a = build_parser().parse_args(["bench-photons", "--counts", "", "--equal-time", "4, 16"])
    assert a.counts == [] and a.equal_time == [4.0, 16.0]
    assert build_parser().parse_args(["bench-bvh", "--triangles", "1e3,99224"]).triangles == [1000, 99224]


def test_unknown_device_exit_1(capsys):
    assert main(["render", "--device", "no-such-device-xyz", "--spp", "1"]) == 1
    err = capsys.readouterr().err
    assert "no OpenCL device matches 'no-such-device-xyz'" in err and "Traceback" not in err


def test_devices_scenes_check_cache(capsys):
    assert main(["devices"]) == 0
    assert "[0]" in capsys.readouterr().out
    assert main(["scenes"]) == 0
    assert "cornell_box" in capsys.readouterr().out
    assert main(["check", "cornell_box_caustics"]) == 0
    assert "spheres 2" in capsys.readouterr().out
    assert main(["cache"]) == 0


def test_python_m_and_ctrl_c_writes_partial_image(tmp_path, device_spec):
    """Ctrl-C stops after the pass in flight and still writes the image."""
    out = tmp_path / "int.png"
    cmd = [sys.executable, "-m", "clpt", "render", "--spp", "1000000", "--width", "32", "--height", "32",
           "-o", str(out), "--progress"] + (["--device", device_spec] if device_spec else [])
    p = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, env=dict(os.environ))
    buf = ""
    deadline = time.time() + 120
    while "spp" not in buf and time.time() < deadline:  # wait for the first progress line
        buf += p.stderr.read(1)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "interrupted after" in err and "Traceback" not in err
    img = clpt.load_image(out)
    assert img.shape == (32, 32, 3) and img.mean() > 0


def test_time_limit(tmp_path, device_spec):
    dev = ["--device", device_spec] if device_spec else []
    t0 = time.time()
    assert main(["render", "--spp", "1000000", "--width", "32", "--height", "32", "--time-limit", "1.5",
                 "-o", str(tmp_path / "t.png"), "-q", *dev]) == 0
    assert time.time() - t0 < 30


def test_devices_verbose_shows_defaults(capsys):
    assert main(["devices", "-v"]) == 0
    out = capsys.readouterr().out
    assert "float vector width: native" in out and "defaults:" in out


def test_bench_table_csv_json_and_compare(tmp_path, device_spec, capsys):
    dev = ["--device", device_spec] if device_spec else []
    args = ["bench", "cornell_box", "--width", "16", "--height", "16", "--rounds", "2", "--no-cold",
            "--lanes", "auto,4", *dev]
    assert main(args + ["--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["variant"].split()[0] for r in rows] == ["lanes=auto", "lanes=4"] and rows[1]["lanes"] == 4
    for r in rows:
        assert r["msamples_per_s"] > 0 and len(r["rates"]) == 2
        assert r["kernel_ms"]["trace_paths"]["median"] > 0 and r["memory_bytes"]["pixel sums"] == 16 * 16 * 40
    old = tmp_path / "old.json"
    old.write_text(json.dumps(rows))
    assert main(args + ["--compare", str(old)]) == 0
    out = capsys.readouterr().out
    assert "path ms/spp" in out and "trace_paths" in out and f"against {old}" in out and "x  " in out
    assert main(args + ["--csv"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("scene,device,platform,variant") and len(lines) == 3


def test_denoise_options(tmp_path, device_spec, capsys):
    dev = ["--device", device_spec] if device_spec else []
    out = tmp_path / "d.png"
    base = ["render", "--spp", "2", "--width", "16", "--height", "16", "-q", *dev]
    assert main([*base, "--denoise", "cone", "-o", str(out)]) == 0
    assert out.exists() and (tmp_path / "d.unfiltered.png").exists()
    # Unbounded work is refused in one line, not run.
    assert main([*base, "--filter", "--filter-width", "1000000", "-o", str(out)]) == 2
    assert "width must be an integer from 0 to 16" in capsys.readouterr().err
    assert main([*base, "--filter", "--filter-iterations", "1000", "-o", str(out)]) == 0
    assert main([*base, "--denoise", "cone", "--oidn-aux", "none", "-o", str(out)]) == 2
    try:
        import pyoidn  # noqa: F401
    except ImportError:
        assert main([*base, "--denoise", "oidn", "-o", str(out)]) == 2
        assert "pip install 'clpt[oidn]'" in capsys.readouterr().err
    else:
        assert main([*base, "--denoise", "oidn", "--oidn-aux", "noisy", "-o", str(out)]) == 0


def test_devices_tune_measures_and_caches_for_later_renders(device_spec, monkeypatch, tmp_path, capsys):
    """`clpt devices --tune SCENE` measures lanes and local size for the
    scene's kernel (the trial renders are faked here: tests/test_tune.py
    measures for real) and caches the choice, which a later render with the
    default policy takes without measuring."""
    from clpt import tune

    if not clpt.Renderer("cornell_box", device=device_spec).states[0].dctx.is_cpu:
        pytest.skip("lanes are measured on CPU runtimes")
    monkeypatch.setattr(tune, "_path", lambda key: tmp_path / "tune" / f"{key}.json")
    wide = {}

    def fake_candidates(states, trial):
        wide["lanes"] = max(st.features.lanes for st in states)
        return {"msamples_per_s": {st.features.lanes: float(st.features.lanes) for st in states},
                "launch_seconds": 1e-4}

    monkeypatch.setattr(tune, "measure_candidates", fake_candidates)
    monkeypatch.setattr(tune, "measure_local_sizes", lambda st, trial, sizes: {s: 1.0 for s in sizes})
    monkeypatch.setenv("CLPT_TUNE", "query")
    assert main(["devices", "--tune", "cornell_box", "--device", device_spec]) == 0
    assert os.environ["CLPT_TUNE"] == "query"  # measuring was for the command only
    out = capsys.readouterr().out
    assert f"cornell_box: lanes {wide['lanes']}, local size {tune.LOCAL_SIZE_CPU}" in out and "measured" in out
    assert len(list((tmp_path / "tune").glob("*.json"))) == 1
    monkeypatch.setenv("CLPT_TUNE", "auto")
    t = clpt.Renderer("cornell_box", device=device_spec).states[0].tuning
    assert (t.lanes, t.how) == (wide["lanes"], "cached")
