"""Property-based fuzzing (hypothesis) of scene files and of `clpt render`'s
options, with a bounded number of inputs: every input is rendered to a finite
image or refused with a one-line error (tests/fuzzing.py says exactly what
passes). tests/fuzz_long.py runs the same checks for as long as one likes."""

import contextlib
import io
import traceback

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given  # noqa: E402

import fuzzing  # noqa: E402
from clpt.cli import main  # noqa: E402
from fuzzing import bounded  # noqa: E402


def run_main(argv):
    """(exit status or "usage", stderr) of `clpt` in this process."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            status = main(argv)
        except SystemExit as e:
            status = "usage" if e.code == 2 else e.code
        except Exception:  # noqa: BLE001 - reported as a failure by check_command
            return 99, err.getvalue() + traceback.format_exc()
    return status, err.getvalue()


@bounded(150)
@given(text=fuzzing.scene_texts())
def test_fuzzed_scene_files_load_or_fail_in_one_line(tmp_path_factory, text):
    """Mutated scene files (wrong types, extreme numbers, missing and unknown
    keys, the whole scene scaled by 10^-45 to 10^45, flipped bytes) load or
    are refused with a one-line SceneError."""
    p = tmp_path_factory.mktemp("fuzz") / "scene.toml"
    p.write_bytes(text)
    fuzzing.check_scene_file(p, render=False)


@bounded(25)
@given(text=fuzzing.scene_texts())
def test_fuzzed_scene_files_render_finite_or_fail_in_one_line(tmp_path_factory, device_spec, text):
    """Accepted fuzzed scenes render (4x4, 1 spp) to a finite, non-negative image."""
    p = tmp_path_factory.mktemp("fuzz") / "scene.toml"
    p.write_bytes(text)
    fuzzing.check_scene_file(p, render=True, device=device_spec)


@bounded(30)
@given(cmd=fuzzing.command_lines())
def test_fuzzed_command_lines_render_or_fail_in_one_line(tmp_path_factory, device_spec, cmd):
    """Fuzzed `clpt render` options (NaN, infinities, negative and huge
    numbers, words, unknown formats, unwritable outputs) render a finite image
    or end with one error line and exit status 1 or 2 (argparse: 2)."""
    argv, output = cmd
    fuzzing.check_command(argv, output, tmp_path_factory.mktemp("cli"), run_main, device=device_spec)
