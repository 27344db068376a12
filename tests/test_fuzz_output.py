"""What `clpt render` writes and what the scene will take, checked by trying
before the first sample: the output's folder is created and a file created
and removed in it (permission bits are not trusted: os.access says yes to
root everywhere, and /proc refuses what they allow), and the scene's meshes
are weighed against the memory there is. The fuzzed command lines of
tests/test_fuzz.py add such outputs (tests/fuzzing.py OUTPUTS)."""

import sys
import tempfile

import numpy as np
import pytest

import clpt
from clpt import preflight
from clpt.cli import main
from meshgen import uv_sphere, write_ply


@pytest.fixture
def no_render(monkeypatch):
    """Fail the test if a Renderer is made (the mistake must be found first)."""
    def refuse(*a, **k):
        raise AssertionError("a Renderer was made before the output was checked")
    monkeypatch.setattr(sys.modules["clpt.render"], "Renderer", refuse)


def _refused(capsys, argv, message):
    assert main(["render", "--spp", "1", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("clpt: error:") and "\n" not in err and message in err, err
    return err


def test_a_folder_that_cannot_be_created_is_refused_at_once(tmp_path, capsys, no_render):
    """-o /proc/nope/x.exr was accepted: the whole render ran before the save
    fell back to the temp folder."""
    _refused(capsys, ["-o", "/proc/nope/x.exr"], "-o /proc/nope/x.exr: cannot create the folder /proc/nope (")
    _refused(capsys, ["-o", "/proc/x.exr"], "-o /proc/x.exr: cannot write in /proc (")
    (tmp_path / "plain").write_text("")
    _refused(capsys, ["-o", str(tmp_path / "plain" / "x.png")], f"{tmp_path / 'plain'} is not a folder")
    _refused(capsys, ["-o", str(tmp_path / "x.png"), "--checkpoint", "/proc/nope/r.ckpt"],
             "--checkpoint /proc/nope/r.ckpt: cannot create the folder /proc/nope (")


def test_missing_folders_are_created_and_tried_before_rendering(tmp_path, capsys, monkeypatch):
    made = []

    class Stop(Exception):
        pass

    def renderer(*a, **k):
        made.append(sorted(p.name for p in (tmp_path / "a" / "b").iterdir()))
        raise Stop()
    monkeypatch.setattr(sys.modules["clpt.render"], "Renderer", renderer)
    with pytest.raises(Stop):
        main(["render", "--spp", "1", "-o", str(tmp_path / "a" / "b" / "x.png")])
    assert made == [[]]  # the folder was there, the probe file gone, before the Renderer was made


def test_a_failed_write_is_refused_whatever_the_permission_bits_say(tmp_path, capsys, monkeypatch, no_render):
    """The probe is what decides: here a file system that refuses writes."""
    def read_only(*a, **k):
        raise OSError(30, "Read-only file system")
    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    _refused(capsys, ["-o", str(tmp_path / "x.png")], f"cannot write in {tmp_path} (read-only file system)")


def test_an_existing_output_that_cannot_be_opened_is_refused(tmp_path, capsys, no_render):
    out = tmp_path / "x.png"
    out.mkdir()
    _refused(capsys, ["-o", str(out)], "is a folder; give a file name")


# --- meshes against memory ------------------------------------------------------------------------


def _mesh_scene(tmp_path):
    v, t, n = uv_sphere(n_theta=20, n_phi=40)
    write_ply(tmp_path / "ball.ply", v, t, n)
    (tmp_path / "s.toml").write_text('[camera]\norigin = [0, 0, 4]\ntarget = [0, 0, 0]\nfov = 40\n'
                                     '[[shapes]]\ntype = "mesh"\nfile = "ball.ply"\nmaterial = "white"\n'
                                     'emission = 1\nname = "ball"\n')
    return tmp_path / "s.toml", len(t)


def test_meshes_are_weighed_against_memory_before_packing(tmp_path, capsys, monkeypatch, no_render):
    path, n = _mesh_scene(tmp_path)
    scene = clpt.load_scene(path)
    per = preflight.MESH_BYTES_PER_TRIANGLE + preflight.MESH_LIGHT_BYTES_PER_TRIANGLE  # an emissive mesh
    assert preflight.scene_resources(scene) == [(f"mesh ball of {n} triangles", n * per)]
    room = preflight.HOST_BASE_BYTES + n * per
    preflight.check_scene_memory(scene, available=room)
    with pytest.raises(clpt.SceneError, match=r"s.toml: its meshes need about 0.1 GiB of memory to render \(1 mesh, "
                                              rf"the largest a mesh ball of {n} triangles: 0.0 GiB\)"):
        preflight.check_scene_memory(scene, available=room - 1)
    monkeypatch.setattr(preflight, "available_host_bytes", lambda: room - 1)
    _refused(capsys, [str(path), "-o", str(tmp_path / "x.png")], "its meshes need about")


def test_the_render_check_counts_the_meshes():
    with pytest.raises(clpt.SceneError, match=r"needs about 2\.\d GiB of memory \(2\.0 GiB of it for the scene's "
                                              r"meshes\) and 2\.0 GiB are available"):
        preflight.check_memory(64, 64, aux=False, adaptive=False, photons=0, available=2 << 30, resources=2 << 30)
    preflight.check_memory(64, 64, aux=False, adaptive=False, photons=0, available=2 << 30, resources=1 << 30)
    assert np.isclose(preflight.host_bytes_needed(64, 64, resources=5), preflight.host_bytes_needed(64, 64) + 5)
