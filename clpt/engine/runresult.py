"""What running one work item on a worker reports."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class RunResult:
    """One work item done.

    seconds: device time of its launch (the host's where the queue has no
    profiling); wall: host seconds of the launch; first: the worker's first
    launch (its time may include a lazy device compile); stats: ray counts
    (non-finite samples, camera, bounce, shadow); photon_maps: info of each
    photon map built for it; launches, kernel_seconds: launches and device
    seconds per kernel, its own and those of work between items (the
    filter). Executors whose workers do not keep the sums return them in
    `sums`, with the worker's `label` and `host`.
    """

    seconds: float
    wall: float = 0.0
    first: bool = False
    stats: np.ndarray = field(default_factory=lambda: np.zeros(4, np.uint64))
    photon_maps: list = field(default_factory=list)
    launches: dict = field(default_factory=dict)
    kernel_seconds: dict = field(default_factory=dict)
    sums: object | None = None    # an Accumulator
    label: str | None = None
    host: str | None = None
