"""The device check's child process (clpt/probe.py): python -m clpt.probe_check,
the job as JSON on stdin; prints the image's finiteness and mean as JSON."""

from __future__ import annotations

import json
import sys
import warnings

import numpy as np
import pyopencl as cl

from .device import DeviceContext
from .probe import CHECK_SEED, CHECK_SIZE, CHECK_SPP
from .render import Renderer


def main():
    job = json.loads(sys.stdin.read())
    warnings.simplefilter("ignore")
    p = cl.get_platforms()[job["platform"]]
    d = p.get_devices()[job["device"]]
    if DeviceContext(d).identity() != job["identity"]:
        sys.exit("the device list changed while checking")
    r = Renderer("cornell_box", device=d, lanes=job["lanes"], photons=False, use_cache=False)  # no cache filled
    img = r.render(CHECK_SPP, width=CHECK_SIZE, height=CHECK_SIZE, seed=CHECK_SEED).image
    print(json.dumps({"finite": bool(np.isfinite(img).all()), "mean": float(np.nan_to_num(img).mean())}))


if __name__ == "__main__":
    main()
