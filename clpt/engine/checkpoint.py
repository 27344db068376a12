"""Checkpoints: a render's sums, its schedule's position and its job, in one
file written atomically (a temporary file beside it, fsync, rename), so a
checkpoint is either the previous one or the new one, never half of either.

Layout: a numpy .npz archive with the accumulator's planes, "meta" (JSON:
format, clpt version, scene and job hashes, settings, schedule position,
photon iteration, elapsed seconds, devices) and "job" (the pickled RenderJob,
so `clpt render --resume` needs nothing else). A checkpoint is trusted data:
open only your own.
"""

from __future__ import annotations

import json
import os
import pickle
import zipfile
from pathlib import Path

import numpy as np

from ..scene import SceneError
from .accum import WIDTHS, Accumulator
from .job import FORMAT, RenderJob


class CheckpointError(SceneError):
    """A checkpoint that cannot be read, or that belongs to another render."""


def _version() -> str:
    from .. import __version__
    return __version__


def write_checkpoint(path, job: RenderJob, sums: Accumulator, schedule_state: dict, *, elapsed: float,
                     devices=(), extra: dict | None = None) -> int:
    """Write atomically; returns the file's size in bytes."""
    path = Path(path)
    meta = {"format": FORMAT, "clpt_version": _version(), "scene_key": job.scene_key(), "job_key": job.key,
            "settings": job.settings(), "schedule": schedule_state, "elapsed": elapsed, "devices": list(devices),
            "samples": sums.samples, **(extra or {})}
    if job.spp_per_map:
        meta["photon_iteration"] = schedule_state["next"] // job.spp_per_map
    arrays = {f"plane_{k}": v for k, v in sums.planes.items()}
    arrays["meta"] = np.frombuffer(json.dumps(meta, default=str).encode(), dtype=np.uint8)
    arrays["job"] = np.frombuffer(pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL), dtype=np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    try:  # the rename itself survives a power cut once the directory is synced
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError:  # a directory that cannot be opened or fsynced (some filesystems): the rename stands
        pass
    return path.stat().st_size


class Checkpoint:
    """A checkpoint read back: job, sums, schedule position and meta."""

    def __init__(self, path):
        self.path = Path(path)
        try:
            with np.load(self.path, allow_pickle=False) as z:
                self.meta = json.loads(bytes(z["meta"]).decode())
                job_bytes = bytes(z["job"])
                planes = {k[6:]: z[k].astype(np.float64) for k in z.files if k.startswith("plane_")}
        except FileNotFoundError:
            raise CheckpointError(f"{path}: no such checkpoint") from None
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as e:
            raise CheckpointError(f"{path}: not a clpt checkpoint or damaged ({e})") from None
        m = self.meta
        if m.get("format") != FORMAT or m.get("clpt_version") != _version():
            raise CheckpointError(f"{path}: written by clpt {m.get('clpt_version')} (checkpoint format "
                                  f"{m.get('format')}); this is clpt {_version()} (format {FORMAT}): it cannot "
                                  f"continue it")
        try:
            self.job: RenderJob = pickle.loads(job_bytes)
        except Exception as e:  # noqa: BLE001 - any unpickling failure means the same
            raise CheckpointError(f"{path}: its render job cannot be read ({e})") from None
        if self.job.key != m.get("job_key"):
            raise CheckpointError(f"{path}: its job does not match its own hash (damaged, or another clpt)")
        n = self.job.n_pix
        acc = Accumulator.__new__(Accumulator)
        acc.n_pix = n
        acc.planes = planes
        for k, v in planes.items():
            want = (n, WIDTHS.get(k, -1)) if WIDTHS.get(k) else (n,)
            if k not in WIDTHS or v.shape != want:
                raise CheckpointError(f"{path}: plane {k!r} of shape {v.shape} does not fit the job's image")
        self.sums = acc
        self.schedule = m["schedule"]

    def check_against(self, job: RenderJob):
        """Refuse to continue this checkpoint as `job` unless they are the same render."""
        if job.scene_key() != self.job.scene_key():
            raise CheckpointError(f"{self.path}: the checkpoint is of another scene (scene hash "
                                  f"{self.job.scene_key()}, this one {job.scene_key()})")
        a, b = self.job.settings(), job.settings()
        diff = [f"{k}: {a[k]!r} in the checkpoint, {b.get(k)!r} here" for k in a if a[k] != b.get(k)]
        if diff:
            raise CheckpointError(f"{self.path}: the checkpoint has other settings ({'; '.join(diff)})")
