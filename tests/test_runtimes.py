"""The runtimes installed with clpt join the ICD loader's vendor list
(clpt/runtimes.py) without hiding any device the user had."""

import os
import subprocess
import sys

import pytest

from clpt import runtimes


def _lib(tmp_path):
    p = tmp_path / "site" / "lib" / "libintelocl.so"
    p.parent.mkdir(parents=True)
    p.write_bytes(b"")
    return p


def test_the_system_vendors_and_the_runtime_are_listed(tmp_path, monkeypatch):
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path / "cache"))
    system = tmp_path / "etc-vendors"
    system.mkdir()
    (system / "nvidia.icd").write_text("libnvidia-opencl.so.1\n")
    (system / "pocl.icd").write_text("libpocl.so.2\n")
    lib = _lib(tmp_path)
    env = {"OPENCL_VENDOR_PATH": str(system)}
    r = runtimes.register(env, [lib])
    folder = env["OCL_ICD_VENDORS"]
    assert r.added == (str(lib),) and r.folder == folder
    listed = {p.name: p.read_text().strip() for p in (tmp_path / "cache" / "opencl-vendors").glob("*/*.icd")}
    assert listed == {"nvidia.icd": "libnvidia-opencl.so.1", "pocl.icd": "libpocl.so.2",
                      "clpt-libintelocl.icd": str(lib)}
    # Again (a child process inherits the variable): nothing to add, nothing changes.
    again = runtimes.register(env, [lib])
    assert again.added == () and env["OCL_ICD_VENDORS"] == folder and "already listed" in again.note


def test_a_users_vendor_folder_or_file_is_kept(tmp_path, monkeypatch):
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path / "cache"))
    lib = _lib(tmp_path)
    mine = tmp_path / "mine.icd"
    mine.write_text("/opt/vendor/libmine.so\n")
    env = {"OCL_ICD_VENDORS": str(mine)}
    runtimes.register(env, [lib])
    entries = runtimes.current_vendors(env)[1]
    assert entries == {"mine.icd": "/opt/vendor/libmine.so", "clpt-libintelocl.icd": str(lib)}
    # A folder that lists Intel's runtime already is left alone.
    folder = tmp_path / "with-intel"
    folder.mkdir()
    (folder / "intel.icd").write_text("/elsewhere/libintelocl.so\n")
    env = {"OCL_ICD_VENDORS": str(folder)}
    assert runtimes.register(env, [lib]).added == () and env["OCL_ICD_VENDORS"] == str(folder)


def test_registration_can_be_turned_off_and_needs_a_runtime(tmp_path, monkeypatch):
    monkeypatch.setenv("CLPT_CACHE_DIR", str(tmp_path / "cache"))
    env = {"CLPT_REGISTER_RUNTIMES": "0"}
    assert runtimes.register(env, [_lib(tmp_path)]).folder is None and "OCL_ICD_VENDORS" not in env
    env = {}
    assert runtimes.register(env, []).folder is None and env == {}


@pytest.mark.skipif(not runtimes.bundled_runtime_libraries(), reason="Intel's CPU runtime is not installed here "
                                                                     "(clpt installs it on Linux x86-64 only)")
def test_importing_clpt_makes_intels_runtime_visible(tmp_path):
    """In a fresh process with the system's vendor folder only, as a new user has it."""
    env = {k: v for k, v in os.environ.items() if k not in ("OCL_ICD_VENDORS", "CLPT_REGISTER_RUNTIMES")}
    env["CLPT_CACHE_DIR"] = str(tmp_path)
    code = "import clpt, pyopencl as cl; print([p.name for p in cl.get_platforms()])"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "Intel(R) OpenCL" in out.stdout
