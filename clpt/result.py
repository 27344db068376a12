"""What a render returns: RenderResult (the image, its per-pixel counts and
variances, feature images, settings) and its RenderStats."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .adaptive import AdaptiveSettings
from . import image as image_files
from .features import Features
from .photons import PhotonSettings
from .version import __version__


@dataclass
class RenderStats:
    nonfinite: int = 0       # samples dropped because they were NaN or infinite
    camera_rays: int = 0
    bounce_rays: int = 0
    shadow_rays: int = 0
    build_seconds: float = 0.0
    cache_hits: int = 0
    first_launch_seconds: float = 0.0  # includes a lazy device compile (PoCL)
    render_seconds: float = 0.0
    passes: list = field(default_factory=list)  # (device label, first sample, samples, seconds)
    photon_maps: list = field(default_factory=list)  # per build: stored, radius, trace/grid device seconds
    adaptive_rounds: int = 0
    photon_pilot: dict | None = None  # what the pilot measured and chose (PhotonSettings.pilot)
    launches: dict = field(default_factory=dict)  # kernel name -> launches, all devices
    kernel_seconds: dict = field(default_factory=dict)  # kernel name -> device seconds per launch (profiling)
    failures: list = field(default_factory=list)  # (worker, error) of workers dropped mid-render
    checkpoints: list = field(default_factory=list)  # (seconds the render waited, seconds to write, bytes) each

    @property
    def rays(self) -> int:
        return self.camera_rays + self.bounce_rays + self.shadow_rays


@dataclass
class RenderResult:
    image: np.ndarray          # H x W x 3 float32, linear RGB
    sample_count: np.ndarray   # H x W samples per pixel
    lum_var: np.ndarray        # H x W variance of one sample's luminance (lum_var / count: of the mean)
    spp: int
    seed: int
    max_depth: int
    rr_depth: int
    devices: list
    features: Features
    stats: RenderStats
    photons: PhotonSettings | None = None
    caustic_image: np.ndarray | None = None  # offline photon mapping: the caustic buffer (part of image)
    aux: dict | None = None                  # feature images: normal, albedo, depth, emission, emitter,
                                             # caustic (Renderer(aux=True))
    filtered: np.ndarray | None = None       # the denoiser's output (render(filter=...)): cone filter or OIDN
    adaptive: AdaptiveSettings | None = None
    interrupted: bool = False    # stopped by Ctrl-C (KeyboardInterrupt)
    time_limited: bool = False   # stopped by time_limit before the samples asked for
    scene_source: str | None = None
    scene_sha256: str | None = None

    @property
    def samples(self) -> int:
        return int(self.sample_count.sum())

    def __repr__(self):
        h, w = self.image.shape[:2]
        spp = f"{self.sample_count.mean():.4g} spp on average" if self.stats.adaptive_rounds else f"{self.spp} spp"
        return (f"<RenderResult {w}x{h}, {spp}, seed {self.seed}, {self.stats.render_seconds:.2f} s"
                f"{', filtered' if self.filtered is not None else ''}{', interrupted' if self.interrupted else ''}>")

    def metadata(self, exposure: float | None = None) -> dict:
        """What the image files record of the render (clpt:* keys)."""
        count = self.sample_count
        meta = {"clpt:version": __version__,
                "clpt:spp": round(float(count.mean()), 4) if count.size else 0.0,
                "clpt:spp_min": int(count.min()) if count.size else 0,
                "clpt:spp_max": int(count.max()) if count.size else 0,
                "clpt:seed": self.seed, "clpt:max_depth": self.max_depth,
                "clpt:rr_depth": self.rr_depth, "clpt:device": "; ".join(self.devices),
                "clpt:render_seconds": round(self.stats.render_seconds, 4),
                "clpt:kernel": self.features.describe(), "clpt:interrupted": int(self.interrupted),
                "clpt:time_limited": int(self.time_limited)}
        if self.scene_source is not None:
            meta["clpt:scene"] = self.scene_source
        if self.scene_sha256 is not None:
            meta["clpt:scene_sha256"] = self.scene_sha256
        if exposure is not None:
            meta["clpt:exposure"] = float(exposure)
        if self.stats.photon_pilot is not None:
            pl = self.stats.photon_pilot
            meta["clpt:photon_choice"] = pl["choice"]
            if "predicted_relmse_1s" in pl:
                e = pl["predicted_relmse_1s"]
                meta["clpt:photon_pilot"] = (f"caustic share {pl['caustic_share']:.4g}; predicted relMSE after 1 s: "
                                             f"merging {e['merge']:.4g}, path tracing {e['path']:.4g}")
        if self.photons is not None:
            p = self.photons
            meta["clpt:photons"] = (f"{p.count} photons, radius {p.radius}{'' if p.radius_absolute else ' x size'}, "
                                    f"k {p.cone_k}, {p.mode}{', progressive alpha %g' % p.alpha if p.progressive else ''}"
                                    f", budget {p.budget}, max {p.max_photons or 'all'}, aim {p.aim}")
        if self.adaptive is not None:
            a = self.adaptive
            meta["clpt:adaptive"] = (f"{a.scheme}, min spp {a.min_spp}, threshold {a.threshold:g}, "
                                     f"pass spp {a.pass_spp}, {self.stats.adaptive_rounds} rounds")
        return meta

    def save(self, path, exposure: float = 0.0):
        image_files.save_image(path, self.image, metadata=self.metadata(exposure), exposure=exposure)

    def _repr_png_(self) -> bytes:
        """Notebooks show a result as its image, tone-mapped as save() writes a PNG."""
        return image_files.png_bytes(self.image)
