"""A render as data: the job (scene, settings, seed), its work items, and
the photon map each item needs.

A job is frozen and picklable, so it can be hashed into a checkpoint and sent
to other processes; its `key` is a hash of the scene's content and of every
setting that changes the image (not of the time limit, which only says when
to stop).
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace

import numpy as np

from ..adaptive import AdaptiveSettings
from ..denoise import FilterSettings
from ..pack import pack_scene
from ..photons import PM_MERGE, PM_OFF, PM_OFFLINE, PM_OWNED, PhotonSettings, photon_seed
from ..scene import Scene

FORMAT = 1  # checkpoint layout; bumped when the meaning of saved state changes


def _digest(obj, h):
    """Feed obj's content to hash h: numpy arrays by their bytes (repr would
    elide a mesh's middle), dataclasses field by field."""
    if isinstance(obj, np.ndarray):
        h.update(f"array{obj.dtype.str}{obj.shape}".encode())
        h.update(np.ascontiguousarray(obj).tobytes())
    elif is_dataclass(obj) and not isinstance(obj, type):
        h.update(type(obj).__name__.encode())
        for f in fields(obj):
            h.update(f.name.encode())
            _digest(getattr(obj, f.name), h)
    elif isinstance(obj, (list, tuple)):
        h.update(f"{type(obj).__name__}{len(obj)}(".encode())
        for x in obj:
            _digest(x, h)
        h.update(b")")
    elif isinstance(obj, dict):
        _digest(sorted(obj.items(), key=lambda kv: repr(kv[0])), h)
    else:
        h.update(repr(obj).encode())
        h.update(b";")


# What the feature buffers show of mirrors and glass (the kernels' aux_specular
# is the index): "through", the first non-delta vertex seen through them;
# "surface", the mirror or glass itself (albedo kr + kt); "glass", mirrors as
# surfaces and what is seen through glass.
AUX_SPECULAR = ("through", "surface", "glass")

@dataclass(frozen=True)
class DeviceOptions:
    """How a device builds its kernels (Renderer's keywords)."""

    lanes: int | None = None
    precision: str = "float"
    kernel: str = "specialized"
    nee: bool = True
    sampler: str = "stratified"
    photons: bool | None = None
    aux: bool = False
    use_cache: bool = True
    accumulate: str = "auto"
    local_size: int | None = None
    bvh: object = "auto"
    bvh_method: str = "lbvh"

    def renderer_kwargs(self) -> dict:
        """Renderer's keywords for these options (but use_cache and the device)."""
        out = asdict(self)
        out.pop("use_cache")
        return out

    def pack(self, scene: Scene):
        """The scene packed for the kernels as these options say (clpt.pack.pack_scene)."""
        return pack_scene(scene, bvh=self.bvh, bvh_method=self.bvh_method)


@dataclass(frozen=True, eq=False)
class RenderJob:
    """Everything that decides a render's image."""

    scene: Scene
    spp: int
    seed: int
    max_depth: int
    rr_depth: int
    width: int
    height: int
    options: DeviceOptions = field(default_factory=DeviceOptions)
    photons: PhotonSettings | None = None      # None: the kernels have no photon code
    adaptive: AdaptiveSettings | None = None
    filter: object | None = None               # FilterSettings or OidnSettings
    aux_specular: str = "glass"                # what the feature buffers show of mirrors and glass (AUX_SPECULAR)
    hide_emitters: bool = False                # camera rays see no emission (RenderSettings.hide_emitters)
    moments: bool = False                      # the pilot's trial: merges estimate path tracing's second
                                               # moment in the caustic plane (builds with feature buffers)

    # --- identity ----------------------------------------------------------------
    def scene_key(self) -> str:
        """A hash of what the scene is (camera, shapes with every mesh's
        arrays, materials), not of where it was read from."""
        s = self.scene
        h = hashlib.sha256()
        _digest((s.camera, s.shapes, sorted(s.materials.items())), h)
        return h.hexdigest()[:24]

    def settings(self) -> dict:
        """The settings as plain data (what a checkpoint records and compares)."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("scene",)}
        for k in ("options", "photons", "adaptive", "filter"):
            out[k] = None if out[k] is None else asdict(out[k])
        for k in ("use_cache", "local_size"):  # where kernels come from, work-group sizes: not the image
            out["options"].pop(k, None)
        return out

    @property
    def key(self) -> str:
        text = repr((self.scene_key(), sorted(self.settings().items())))
        return hashlib.sha256(text.encode()).hexdigest()[:24]

    def __hash__(self):
        return hash(self.key)

    def __eq__(self, other):
        return isinstance(other, RenderJob) and other.key == self.key

    # --- derived -------------------------------------------------------------------
    @property
    def n_pix(self) -> int:
        return self.width * self.height

    @property
    def no_photons(self) -> bool:
        return self.photons is not None and self.photons.count == 0

    @property
    def progressive(self) -> bool:
        return self.photons is not None and self.photons.progressive and not self.no_photons

    @property
    def offline(self) -> bool:
        p = self.photons
        return p is not None and p.mode == "offline" and not self.progressive and not self.no_photons

    @property
    def pm_mode(self) -> int:
        """trace_paths' photon mode for the job's sample ranges."""
        if self.photons is None or self.no_photons:
            return PM_OFF
        return PM_OFFLINE if self.offline else PM_MERGE if self.photons.mode == "merge" else PM_OWNED

    @property
    def uniform_spp(self) -> int:
        """Samples every pixel gets before adaptive rounds (all of them without)."""
        return self.spp if self.adaptive is None else min(self.spp, self.adaptive.min_spp)

    @property
    def prepass_spp(self) -> int:
        """Samples per pixel of the offline caustic pre-pass (0: none)."""
        return min(self.photons.offline_spp, self.spp) if self.offline else 0

    @property
    def spp_per_map(self) -> int | None:
        return self.photons.spp_per_map if self.progressive else None


def kernel_photons(pset: PhotonSettings | None, length_scale: float) -> PhotonSettings | None:
    """The photon settings in the packed scene's lengths (an absolute radius
    scaled with them; clpt.pack packs extreme scenes at a power-of-two scale)."""
    if pset is not None and pset.radius_absolute and length_scale != 1.0:
        return replace(pset, radius=pset.radius * length_scale)
    return pset


def photon_plan(job: RenderJob, iteration: int, scene_size: float, length_scale: float = 1.0) -> tuple[int, float]:
    """(seed, radius in the packed scene's lengths) of the photon map that
    work items of `iteration` gather from: iteration 0 for every item unless
    progressive, where the samples [i * spp_per_map, (i + 1) * spp_per_map)
    are iteration i."""
    return photon_seed(job.seed, iteration), kernel_photons(job.photons, length_scale).radius_for(scene_size,
                                                                                                   iteration)


@dataclass(frozen=True, eq=False)
class WorkItem:
    """One unit of work: samples [s0, s0 + n) of every pixel ("samples"), the
    offline caustic pre-pass ("prepass"), or an adaptive round's part
    ("pixels": jobs[i] = (samples, max depth, first sample, 0) for pixels[i])."""

    kind: str
    s0: int = 0
    n: int = 0
    iteration: int = 0     # the photon map it gathers from
    pixels: np.ndarray | None = None
    jobs: np.ndarray | None = None
    round: int = -1

    @property
    def samples(self) -> int:
        """Samples it adds, per pixel of the image for sample ranges, in all for pixel lists."""
        return int(self.jobs[:, 0].sum()) if self.kind == "pixels" else self.n

    def describe(self) -> str:
        if self.kind == "pixels":
            return f"round {self.round}: {len(self.pixels)} pixels"
        return f"{self.kind} [{self.s0}, {self.s0 + self.n})"
