"""Checkpoints: a render's sums, its schedule's position and its job, in one
file written atomically (a temporary file beside it, fsync, rename), so a
checkpoint is either the previous one or the new one, never half of either.

Layout: a numpy .npz archive with the accumulator's planes, "meta" (JSON:
format, clpt version, scene and job hashes, settings, schedule position,
photon iteration, elapsed seconds, devices), and the RenderJob, so that
`clpt render --resume` needs nothing else: "job" (JSON of the job's
dataclasses, by name from a fixed list) and "job_array_N" (its meshes'
arrays). Nothing is unpickled on reading (a pickle can run any code): a
checkpoint is data, rebuilt through the classes' own checks.

Reading checks everything before it is used: the file is a regular file,
every member's declared size fits the file and the machine before it is
read, the job and its scene pass their checks, the planes have the job's
shape and finite, non-negative sums, and the schedule's position lies
within the job. Every problem is one CheckpointError line naming the file
and the member.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import warnings
import zipfile
from pathlib import Path

import numpy as np

from .. import hostio
from ..adaptive import AdaptiveSettings
from ..denoise import FilterSettings, OidnSettings
from ..errors import CheckpointError, SceneError
from ..hostio import open_regular_file
from ..photons import PhotonSettings
from ..scene import (Box, Camera, DirectionalLight, EnvironmentLight, Material, Mesh, PixelFilter, Plane, PointLight,
                     Quad, RenderSettings, Scene, Sphere, SpotLight, Triangle)
from ..texture import Texture
from ..version import __version__
from .accum import WIDTHS, Accumulator
from .job import FORMAT, DeviceOptions, RenderJob

JOB_ENCODING = "json-1"  # meta["job_encoding"]: how "job" is written (no pickle)


def write_checkpoint(path, job: RenderJob, sums: Accumulator, schedule_state: dict, *, elapsed: float,
                     devices=(), extra: dict | None = None) -> int:
    """Write atomically; returns the file's size in bytes."""
    path = Path(path)
    meta = {"format": FORMAT, "clpt_version": __version__, "scene_key": job.scene_key(), "job_key": job.key,
            "settings": job.settings(), "schedule": schedule_state, "elapsed": elapsed, "devices": list(devices),
            "samples": sums.samples, **(extra or {})}
    if job.spp_per_map:
        meta["photon_iteration"] = schedule_state["next"] // job.spp_per_map
    arrays = {f"plane_{k}": v for k, v in sums.planes.items()}
    job_arrays: list = []
    job_text = json.dumps(_encode(job, job_arrays))
    meta["job_encoding"] = JOB_ENCODING
    arrays["meta"] = np.frombuffer(json.dumps(meta, default=str).encode(), dtype=np.uint8)
    arrays["job"] = np.frombuffer(job_text.encode(), dtype=np.uint8)
    arrays.update({f"job_array_{i}": a for i, a in enumerate(job_arrays)})
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


# --- the job as data -------------------------------------------------------------------------


def _job_types() -> dict:
    """The classes a job is made of, by name: the only ones reading builds."""
    return {c.__name__: c for c in (RenderJob, DeviceOptions, PhotonSettings, AdaptiveSettings, FilterSettings,
                                    OidnSettings, Scene, Camera, PixelFilter, RenderSettings, Material, Sphere,
                                    Triangle, Quad, Plane, Box, Mesh, PointLight, SpotLight, DirectionalLight,
                                    EnvironmentLight, Texture)}


def _encode(obj, arrays: list):
    """obj as JSON-able data: dataclasses by class name and fields, tuples and
    dicts marked (JSON has neither), numpy arrays as indices into `arrays`."""
    if isinstance(obj, np.generic):  # before float: np.float64 is a float, with another repr (and hash)
        return {"$n": obj.dtype.str, "v": obj.item()}
    if isinstance(obj, (str, bool, int, float)) or obj is None:
        return obj
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {"$": type(obj).__name__,
                "f": {f.name: _encode(getattr(obj, f.name), arrays) for f in dataclasses.fields(obj) if f.init}}
    if isinstance(obj, tuple):
        return {"$t": [_encode(x, arrays) for x in obj]}
    if isinstance(obj, list):
        return [_encode(x, arrays) for x in obj]
    if isinstance(obj, dict):
        return {"$d": [[_encode(k, arrays), _encode(v, arrays)] for k, v in obj.items()]}
    if isinstance(obj, np.ndarray):
        arrays.append(obj)
        return {"$a": len(arrays) - 1}
    raise TypeError(f"a checkpoint cannot hold a {type(obj).__name__} ({obj!r})")


def _decode(data, arrays, types, fail):
    """The inverse of _encode, building only the classes in `types` through
    their constructors (and so their checks)."""
    if isinstance(data, (str, bool, int, float)) or data is None:
        return data
    if isinstance(data, list):
        return [_decode(x, arrays, types, fail) for x in data]
    if not isinstance(data, dict) or len(data) not in (1, 2):
        fail(f"unexpected {type(data).__name__} {str(data)[:60]!r}")
    if "$" in data:
        cls = types.get(data["$"]) if isinstance(data["$"], str) else None
        if cls is None or not isinstance(data.get("f"), dict):
            fail(f"unknown class {str(data['$'])[:40]!r}")
        names = {f.name for f in dataclasses.fields(cls) if f.init}
        extra = set(data["f"]) - names
        if extra:
            fail(f"{cls.__name__} has no field {sorted(extra)[0]!r}")
        kw = {k: _decode(v, arrays, types, fail) for k, v in data["f"].items()}
        try:
            obj = cls(**kw)
        except Exception as e:  # noqa: BLE001 - fields from a file: whatever the class refuses, it is damage
            fail(f"{cls.__name__}: {str(e).splitlines()[0] if str(e) else type(e).__name__}")
        n = kw.get("normals") if cls.__name__ == "Mesh" else None
        if n is not None and obj.normals.shape == n.shape:
            # A mesh's normals were stored normalized; normalizing them again (as the
            # constructor does) can change their last bits, and so the job's hash.
            n = np.array(n, dtype=np.float64)
            n.setflags(write=False)
            object.__setattr__(obj, "normals", n)
        return obj
    if "$t" in data and isinstance(data["$t"], list):
        return tuple(_decode(x, arrays, types, fail) for x in data["$t"])
    if "$d" in data and isinstance(data["$d"], list) and all(isinstance(kv, list) and len(kv) == 2
                                                              for kv in data["$d"]):
        out = {}
        for k, v in data["$d"]:
            k = _decode(k, arrays, types, fail)
            if not isinstance(k, (str, int, float, bool, tuple)) and k is not None:
                fail(f"a dictionary key of type {type(k).__name__}")
            out[k] = _decode(v, arrays, types, fail)
        return out
    if "$a" in data and type(data["$a"]) is int and 0 <= data["$a"] < len(arrays):
        return arrays[data["$a"]]
    if "$n" in data and isinstance(data["$n"], str) and isinstance(data.get("v"), (int, float, bool)):
        try:
            dt = np.dtype(data["$n"])
            if dt.kind not in "biuf":
                raise TypeError(dt)
            return dt.type(data["v"])
        except (TypeError, ValueError, OverflowError):
            fail(f"bad number {str(data)[:60]!r}")
    fail(f"unexpected value {str(data)[:60]!r}")


def _check_types(obj, fail):
    """A settings dataclass's fields of the type of their defaults (fields
    whose default is None, or typed `object`, may hold anything)."""
    for f in dataclasses.fields(obj):
        v, d = getattr(obj, f.name), f.default
        if d is None or d is dataclasses.MISSING or f.type == "object":
            continue
        ok = (type(v) is bool if isinstance(d, bool) else
              isinstance(v, (int, float)) and not isinstance(v, bool) if isinstance(d, float) else
              isinstance(v, int) and not isinstance(v, bool) if isinstance(d, int) else isinstance(v, type(d)))
        if not ok:
            fail(f"{type(obj).__name__}.{f.name} must be a {type(d).__name__} (got {v!r})")


def _check_job(job, fail):
    """A decoded job's own settings of the right types and in range, and its
    scene checked."""
    if not isinstance(job, RenderJob):
        fail(f"not a render job (a {type(job).__name__})")
    for name, types in (("scene", Scene), ("options", DeviceOptions), ("photons", (PhotonSettings, type(None))),
                        ("adaptive", (AdaptiveSettings, type(None))),
                        ("filter", (FilterSettings, OidnSettings, type(None))), ("aux_specular", str)):
        v = getattr(job, name)
        if not isinstance(v, types):
            fail(f"{name} has the wrong type ({type(v).__name__} {str(v)[:40]})")
    for s in (job.options, job.photons, job.adaptive, job.filter, job.scene.render):
        if s is not None:
            _check_types(s, fail)
    if not isinstance(job.scene.materials, dict) or not all(isinstance(k, str) for k in job.scene.materials):
        fail("the scene's materials must be a table by name")
    for name, lo, hi in (("spp", 1, 2 ** 32 - 1), ("seed", 0, 2 ** 32 - 1), ("max_depth", 0, 2 ** 31 - 1),
                         ("rr_depth", 0, 2 ** 31 - 1), ("width", 1, 1 << 16), ("height", 1, 1 << 16)):
        v = getattr(job, name)
        if type(v) is not int or not lo <= v <= hi:
            fail(f"{name} must be an integer from {lo} to {hi} (got {v!r})")
    for s in (job.photons, job.adaptive, job.filter):
        if s is not None and hasattr(s, "check"):
            try:
                s.check()
            except Exception as e:  # noqa: BLE001 - settings from a file: any failure of their check is damage
                fail(str(e).splitlines()[0] if str(e) else type(e).__name__)
    try:
        job.scene.check()
    except Exception as e:  # noqa: BLE001 - a scene from a file: any failure of its check is damage
        fail(f"its scene: {str(e).splitlines()[0] if str(e) else type(e).__name__}")


# --- reading ------------------------------------------------------------------------------------


class _Archive:
    """The checkpoint's members, each checked before it is read: declared
    sizes within the file and the machine, a plain numeric array whose
    header agrees with its size."""

    def __init__(self, path: Path, f):
        self.path = path
        self.zip = zipfile.ZipFile(f)
        self.infos = {i.filename[:-4]: i for i in self.zip.infolist() if i.filename.endswith(".npy")}
        total = sum(i.file_size for i in self.infos.values())
        avail = hostio.available_host_bytes()
        if avail is not None and total > avail:
            raise CheckpointError(f"{path}: its members need {total / 2**30:.1f} GiB of memory and "
                                  f"{avail / 2**30:.1f} GiB are available")

    def fail(self, name, reason):
        raise CheckpointError(f"{self.path}: member '{name}': {reason}")

    def array(self, name) -> np.ndarray:
        info = self.infos.get(name)
        if info is None:
            raise CheckpointError(f"{self.path}: not a clpt checkpoint or damaged (no member '{name}')")
        with self.zip.open(info) as f:
            version = np.lib.format.read_magic(f)
            header = np.lib.format.read_array_header_1_0 if version == (1, 0) else \
                np.lib.format.read_array_header_2_0
            shape, fortran, dtype = header(f)
            if dtype.hasobject or dtype.kind not in "biuf" or dtype.fields is not None or dtype.subdtype:
                self.fail(name, f"holds {dtype}, not numbers")
            size = math.prod(shape) * dtype.itemsize
            if size != info.file_size - f.tell():
                self.fail(name, f"its header says {shape} of {dtype} ({size} bytes), it has "
                                f"{info.file_size - f.tell()} bytes")
            data = f.read(size + 1)  # to the end, so the member's CRC is checked
        if len(data) != size:
            self.fail(name, f"ends after {len(data)} of its {size} bytes")
        return np.frombuffer(data, dtype).reshape(shape, order="F" if fortran else "C")

    def json(self, name):
        a = self.array(name)
        if a.dtype != np.uint8 or a.ndim != 1:
            self.fail(name, "is not text")
        try:
            return json.loads(a.tobytes().decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
            self.fail(name, f"is not JSON ({str(e)[:80]})")


# Everything reading a damaged zip file, or a member of one, can raise.
_DAMAGE = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, NotImplementedError, RuntimeError,
           zipfile.LargeZipFile, OverflowError, TypeError)


class Checkpoint:
    """A checkpoint read back: job, sums, schedule position and meta."""

    def __init__(self, path):
        self.path = Path(path)
        try:
            f = open_regular_file(self.path, path, "checkpoint")
        except SceneError as e:
            raise CheckpointError(str(e)) from None
        with f:
            if os.fstat(f.fileno()).st_size == 0:
                raise CheckpointError(f"{path}: the file is empty, not a clpt checkpoint")
            try:
                z = _Archive(path, f)
                self.meta = m = z.json("meta")
                if not isinstance(m, dict):
                    z.fail("meta", "is not a JSON object")
                if m.get("format") != FORMAT or m.get("clpt_version") != __version__:
                    raise CheckpointError(f"{path}: written by clpt {m.get('clpt_version')} (checkpoint format "
                                          f"{m.get('format')}); this is clpt {__version__} (format {FORMAT}): it "
                                          f"cannot continue it")
                if m.get("job_encoding") != JOB_ENCODING:
                    z.fail("job", "not in the JSON encoding of this clpt (older checkpoints pickled the job, "
                                  "which clpt no longer loads: a pickle can run any code)")
                job_data = z.json("job")
                arrays = []
                while f"job_array_{len(arrays)}" in z.infos:
                    arrays.append(z.array(f"job_array_{len(arrays)}"))
                planes = {k[6:]: z.array(k) for k in z.infos if k.startswith("plane_")}
            except CheckpointError:
                raise
            except _DAMAGE as e:
                raise CheckpointError(f"{path}: not a clpt checkpoint or damaged "
                                      f"({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None

        def job_fail(reason):
            z.fail("job", reason)

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a mesh's degenerate triangles were dropped (and warned) at its load
            try:
                self.job: RenderJob = _decode(job_data, arrays, _job_types(), job_fail)
            except RecursionError:
                job_fail("nested too deep")
        _check_job(self.job, job_fail)
        if self.job.key != m.get("job_key"):
            raise CheckpointError(f"{path}: its job does not match its own hash (damaged, or another clpt)")
        self.sums = self._sums(planes, z.fail)
        self.schedule = _checked_schedule(m.get("schedule"), self.job, lambda r: z.fail("meta", f"schedule: {r}"))
        e = m.get("elapsed", 0.0)
        if type(e) not in (int, float) or not (math.isfinite(e) and e >= 0):
            z.fail("meta", f"elapsed must be a number of seconds >= 0 (got {e!r})")

    def _sums(self, planes, fail) -> Accumulator:
        """The planes as an Accumulator: each of the job's shape, the sums
        (less their Kahan compensations) finite and not negative."""
        n = self.job.n_pix
        for k, v in planes.items():
            want = (n, WIDTHS.get(k, -1)) if WIDTHS.get(k) else (n,)
            if k not in WIDTHS or v.shape != want:
                fail(f"plane_{k}", f"shape {v.shape} does not fit the job's image ({want})")
            if not np.isfinite(v).all():
                fail(f"plane_{k}", "holds values that are not finite")
        for p in ("", "c_"):  # the image's sums always, the caustic buffer's if any of it is there
            if p == "" or any(p + k in planes for k in ("sum", "sq", "comp")):
                for need in (p + "sum", p + "sq"):
                    if need not in planes:
                        raise CheckpointError(f"{self.path}: not a clpt checkpoint or damaged (no member "
                                              f"'plane_{need}')")
        acc = Accumulator.__new__(Accumulator)
        acc.n_pix = n
        acc.planes = {k: v.astype(np.float64) for k, v in planes.items()}
        for p in ("", "c_"):
            if p + "sum" in acc.planes:
                s, sq = acc._value(p)
                if (s < -1e-6 * (np.abs(acc.planes[p + "sum"]) + 1)).any() or \
                        (sq < -1e-6 * (np.abs(acc.planes[p + "sq"]) + 1)).any():
                    fail(f"plane_{p}sum", "holds negative sums")
        return acc

    def check_against(self, job: RenderJob):
        """Refuse to continue this checkpoint as `job` unless they are the same render."""
        if job.scene_key() != self.job.scene_key():
            raise CheckpointError(f"{self.path}: the checkpoint is of another scene (scene hash "
                                  f"{self.job.scene_key()}, this one {job.scene_key()})")
        a, b = self.job.settings(), job.settings()
        diff = [f"{k}: {a[k]!r} in the checkpoint, {b.get(k)!r} here" for k in a if a[k] != b.get(k)]
        if diff:
            raise CheckpointError(f"{self.path}: the checkpoint has other settings ({'; '.join(diff)})")


def _checked_schedule(st, job: RenderJob, fail) -> dict:
    """The schedule's position (Schedule.state()) if it lies within the job."""
    if not isinstance(st, dict):
        fail("missing")
    for k in ("next", "rounds"):
        if type(st.get(k)) is not int or st[k] < 0:
            fail(f"{k} must be an integer >= 0 (got {st.get(k)!r})")
    if "maps" in st and (type(st["maps"]) is not int or st["maps"] < 0):  # absent in older checkpoints
        fail(f"maps must be an integer >= 0 (got {st['maps']!r})")
    if st["next"] > job.uniform_spp:
        fail(f"next {st['next']} is past the job's {job.uniform_spp} samples")
    for k in ("prepass_done", "adaptive_over"):
        if type(st.get(k)) is not bool:
            fail(f"{k} must be true or false (got {st.get(k)!r})")
    if not isinstance(st.get("redo"), list):
        fail("redo must be a list")
    for i, d in enumerate(st["redo"]):
        if not isinstance(d, dict) or d.get("kind") not in ("samples", "prepass", "pixels"):
            fail(f"redo[{i}] is not a work item")
        for k in ("s0", "n", "iteration"):
            if type(d.get(k)) is not int or not 0 <= d[k] <= job.spp:
                fail(f"redo[{i}].{k} must be an integer from 0 to {job.spp} (got {d.get(k)!r})")
        if type(d.get("round")) is not int:
            fail(f"redo[{i}].round must be an integer")
        if d["kind"] == "pixels":
            try:
                px = np.array(d["pixels"], dtype=np.int64)
                jb = np.array(d["jobs"], dtype=np.int64)
            except (KeyError, ValueError, TypeError, OverflowError):
                fail(f"redo[{i}] has no list of pixels and their jobs")
            if px.ndim != 1 or jb.shape != (len(px), 4) or (len(px) and (px.min() < 0 or px.max() >= job.n_pix)) \
                    or (jb.size and (jb.min() < 0 or jb.max() > 2 ** 32 - 1)):
                fail(f"redo[{i}]: pixels must be indices into the image, each with a job of 4 integers")
    return st
