"""Signals during `clpt render`: SIGTERM and SIGHUP end a render as Ctrl-C
does, the image so far is written (atomically: never a truncated file), and
the exit status says which signal it was."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from clpt.image import load_image, read_metadata


def _start(tmp_path, out, *extra):
    env = dict(os.environ)
    return subprocess.Popen([sys.executable, "-m", "clpt", "render", "cornell_box", "--width", "32", "--height", "32",
                             "--spp", "100000000", "--progress", "-o", str(out), *extra],
                            stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)


@pytest.mark.skipif(not hasattr(signal, "SIGTERM"), reason="no SIGTERM on this platform")
@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 128 + signal.SIGTERM), (signal.SIGINT, 130)])
def test_a_signal_mid_render_writes_the_image_so_far(tmp_path, sig, code):
    out = tmp_path / "out.exr"
    p = _start(tmp_path, out)
    # Wait until samples are being added (the progress bar shows spp).
    deadline = time.time() + 120
    seen = ""
    while time.time() < deadline:
        line = p.stderr.read(1)
        seen += line
        if "spp" in seen and "Msamples/s" in seen:
            break
    time.sleep(0.5)
    p.send_signal(sig)
    err = p.communicate(timeout=120)[1]
    assert p.returncode == code, err
    img = load_image(out)
    assert img.shape == (32, 32, 3) and np.isfinite(img).all() and img.mean() > 0
    meta = read_metadata(out)
    assert int(meta["clpt:interrupted"]) == 1
    assert not list(tmp_path.glob(".*.tmp*")), "a temporary file was left behind"
