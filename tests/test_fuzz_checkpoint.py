"""Fuzzing of checkpoints (tests/fuzzing.py has the inputs and the checks):
checkpoints of tiny jobs of every kind, damaged byte by byte or rewritten
with a member changed (JSON values, arrays, members dropped or added), load
with finite sums or fail with one line naming the file, the member and the
reason; a sample of those that load resume to a finite image. Below them,
the defects found, each as a plain test, and the rule that reading a
checkpoint never unpickles."""

import io
import os
import pickle

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given  # noqa: E402

import fuzzing  # noqa: E402
from clpt.engine.checkpoint import Checkpoint, CheckpointError  # noqa: E402
from fuzzing import bounded  # noqa: E402
from test_fuzz import run_main  # noqa: E402


@pytest.fixture(scope="module")
def seeds():
    return fuzzing.checkpoint_seeds()


@bounded(300)
@given(data=fuzzing.checkpoint_inputs())
def test_fuzzed_checkpoints_load_or_fail_in_one_line(tmp_path_factory, data):
    p = tmp_path_factory.mktemp("ckpt") / "fuzz.ckpt"
    p.write_bytes(data)
    fuzzing.check_checkpoint_file(p, render=False)


@pytest.mark.parametrize("i", range(5))
def test_each_kind_of_checkpoint_resumes_finite(tmp_path, device_spec, seeds, i):
    """The undamaged seeds (plain, offline caustics, adaptive, a mesh, feature
    buffers and the filter) load and resume; few damaged ones load at all."""
    p = tmp_path / "seed.ckpt"
    p.write_bytes(seeds[i])
    assert fuzzing.check_checkpoint_file(p, render=True, device=device_spec) == "resumed"


@bounded(8)
@given(data=fuzzing.checkpoint_edits(fuzzing.checkpoint_seeds()))
def test_fuzzed_checkpoints_that_load_resume_finite(tmp_path_factory, device_spec, data):
    p = tmp_path_factory.mktemp("ckpt") / "fuzz.ckpt"
    p.write_bytes(data)
    fuzzing.check_checkpoint_file(p, render=True, device=device_spec)


# --- the defects found, one by one ----------------------------------------------------------


def _refused(p, match):
    with pytest.raises(CheckpointError, match=match) as e:
        Checkpoint(p)
    assert "\n" not in str(e.value) and str(p) in str(e.value)


def _rewrite(path, seed, **changes):
    m = fuzzing._members(seed)
    for k, v in changes.items():
        if v is None:
            del m[k]
        else:
            m[k] = v
    path.write_bytes(fuzzing._archive(m))
    return path


def test_an_empty_checkpoint_is_refused_in_one_line(tmp_path):
    """It gave a traceback (EOFError: No data left in file) and exit 1."""
    p = tmp_path / "empty.ckpt"
    p.write_bytes(b"")
    _refused(p, "empty.ckpt: the file is empty, not a clpt checkpoint")
    status, err = run_main(["render", "--resume", str(p), "-o", str(tmp_path / "x.png")])
    assert status == 2 and err.strip().splitlines() == [f"clpt: error: {p}: the file is empty, not a clpt checkpoint"]


def test_reading_never_unpickles(tmp_path, seeds):
    """A pickle in place of the job is refused without being run; so is a
    checkpoint of the older layout, whose job was a pickle."""
    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (os.mkdir, (str(marker),))

    evil = np.frombuffer(pickle.dumps(Payload()), dtype=np.uint8)
    _refused(_rewrite(tmp_path / "a.ckpt", seeds[0], job=evil), r"a.ckpt: member 'job': is not JSON")
    meta = fuzzing._json_member(fuzzing._members(seeds[0])["meta"])
    del meta["job_encoding"]
    _refused(_rewrite(tmp_path / "b.ckpt", seeds[0], job=evil, meta=fuzzing._as_member(meta)),
             r"b.ckpt: member 'job': not in the JSON encoding of this clpt \(older checkpoints pickled the job")
    assert not marker.exists()


def test_a_class_outside_the_job_is_not_built(tmp_path, seeds):
    job = fuzzing._json_member(fuzzing._members(seeds[0])["job"])
    job["f"]["scene"] = {"$": "Popen", "f": {"args": "true"}}
    _refused(_rewrite(tmp_path / "c.ckpt", seeds[0], job=fuzzing._as_member(job)),
             r"c.ckpt: member 'job': unknown class 'Popen'")


def test_a_member_is_checked_against_its_size_before_it_is_read(tmp_path, seeds):
    """An array header that claims 10^12 values is refused before allocating."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": (10 ** 12,)})
    m = fuzzing._members(seeds[0])
    p = tmp_path / "d.ckpt"
    import zipfile
    with zipfile.ZipFile(p, "w") as z:
        for k, v in m.items():
            if k == "plane_sq":
                z.writestr("plane_sq.npy", buf.getvalue() + b"\0" * 64)
            else:
                b = io.BytesIO()
                np.save(b, v)
                z.writestr(f"{k}.npy", b.getvalue())
    _refused(p, r"d.ckpt: member 'plane_sq': its header says \(1000000000000,\) of float64 \(8000000000000 bytes\), "
                r"it has 64 bytes")


def test_non_finite_sums_and_a_schedule_outside_the_job_are_refused(tmp_path, seeds):
    """Both loaded before: the first gave non-finite pixels, the second broke the resume."""
    m = fuzzing._members(seeds[0])
    s = m["plane_sum"].copy()
    s[3, 1] = np.nan
    _refused(_rewrite(tmp_path / "e.ckpt", seeds[0], plane_sum=s), r"e.ckpt: member 'plane_sum': holds values "
                                                                    r"that are not finite")
    s[3, 1] = -5.0
    _refused(_rewrite(tmp_path / "f.ckpt", seeds[0], plane_sum=s), r"f.ckpt: member 'plane_sum': holds negative sums")
    meta = fuzzing._json_member(m["meta"])
    meta["schedule"]["next"] = 9
    _refused(_rewrite(tmp_path / "g.ckpt", seeds[0], meta=fuzzing._as_member(meta)),
             r"g.ckpt: member 'meta': schedule: next 9 is past the job's 8 samples")
    del meta["schedule"]
    _refused(_rewrite(tmp_path / "h.ckpt", seeds[0], meta=fuzzing._as_member(meta)),
             r"h.ckpt: member 'meta': schedule: missing")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_pipe_is_refused_before_reading(tmp_path):
    os.mkfifo(tmp_path / "pipe.ckpt")
    _refused(tmp_path / "pipe.ckpt", r"pipe.ckpt: not a regular file")


def test_settings_of_the_wrong_type_are_refused(tmp_path, seeds):
    """A job whose options were not DeviceOptions raised TypeError (asdict)."""
    m = fuzzing._members(seeds[0])
    job = fuzzing._json_member(m["job"])
    job["f"]["options"] = 5
    _refused(_rewrite(tmp_path / "i.ckpt", seeds[0], job=fuzzing._as_member(job)),
             r"i.ckpt: member 'job': options has the wrong type \(int 5\)")
    job["f"]["options"] = {"$": "DeviceOptions", "f": {"nee": "yes"}}
    _refused(_rewrite(tmp_path / "j.ckpt", seeds[0], job=fuzzing._as_member(job)),
             r"j.ckpt: member 'job': DeviceOptions.nee must be a bool \(got 'yes'\)")

    job["f"]["options"] = fuzzing._json_member(m["job"])["f"]["options"]
    job["f"]["scene"]["f"]["materials"] = {"$d": [[1, {"$": "Material", "f": {}}],
                                                  ["white", {"$": "Material", "f": {}}]]}
    _refused(_rewrite(tmp_path / "k.ckpt", seeds[0], job=fuzzing._as_member(job)),
             r"k.ckpt: member 'job': the scene's materials must be a table by name")  # was TypeError (sorting keys)
