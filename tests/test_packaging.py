"""Kernel sources and scenes are found from a source checkout and from a
plain (non-editable) install, run from a folder that is neither."""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROBE = ("import clpt, sys; img = clpt.render('cornell_box', spp=1, width=8, height=8); "
         "from clpt.resources import kernel_dir, scene_dir; print(clpt.__file__); print(kernel_dir()); "
         "print(scene_dir()); assert img.mean() > 0")


def run_probe(env_path, cwd):
    env = dict(os.environ, PYTHONPATH=str(env_path))
    p = subprocess.run([sys.executable, "-c", PROBE], cwd=cwd, env=env, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    return p.stdout.split()


def test_from_source_checkout(tmp_path):
    mod, kdir, sdir = run_probe(ROOT, tmp_path)
    assert Path(mod).parent == ROOT / "clpt" and Path(kdir) == ROOT / "kernels" and Path(sdir) == ROOT / "scenes"


@pytest.mark.skipif(not (ROOT / "pyproject.toml").exists(), reason="needs the source tree")
def test_from_a_plain_install(tmp_path):
    wheels = tmp_path / "wheels"
    # Built from a copy: the checkout's build/ folder may hold files of packages pyproject.toml no longer lists.
    src = tmp_path / "src"
    for part in ("clpt", "kernels", "scenes"):
        shutil.copytree(ROOT / part, src / part, ignore=shutil.ignore_patterns("__pycache__"))
    for part in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / part, src / part)
    p = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                        "-w", str(wheels), str(src)], capture_output=True, text=True)
    if p.returncode != 0:  # no setuptools in this environment: let pip fetch it
        p = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(wheels), str(src)],
                           capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    whl = next(wheels.glob("clpt-*.whl"))
    names = zipfile.ZipFile(whl).namelist()
    assert "clpt/kernels/trace.cl" in names and "clpt/scenes/cornell_box.toml" in names
    assert "clpt/data/cie1931_2deg.csv" in names and "clpt/data/mitsuba_ior.json" in names
    assert "clpt/cli/__init__.py" in names and "clpt/cli/render.py" in names  # pyproject lists packages
    assert "clpt/tools/bench.py" in names and "clpt/tools/reference.py" in names
    target = tmp_path / "site"
    p = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target), str(whl)],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    mod, kdir, sdir = run_probe(target, tmp_path)
    assert Path(mod).is_relative_to(target) and Path(kdir) == target / "clpt" / "kernels"
    assert Path(sdir) == target / "clpt" / "scenes"
    p = subprocess.run([sys.executable, "-m", "clpt", "scenes"], cwd=tmp_path, capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(target)))
    assert p.returncode == 0 and "cornell_box" in p.stdout, p.stderr
