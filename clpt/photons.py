"""Caustic photon mapping: its settings, the seeds of progressive photon
maps and the pilot's choice (the device side, the photon pass and hash-grid
build, is clpt/engine/passes.py PhotonPass; kernels/photons.cl,
kernels/grid.cl, kernels/photon_grid.h).

A scene without caustic casters (purely specular objects) compiles no photon
code and allocates nothing. For the others, each device builds its own
photon map from the same seed, so every device sees the same photons.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .errors import SettingsError

RADIX_BITS = 8
GRID_CELL_RADII = 2  # grid cells are cubes of this many gather radii (kernels/photon_grid.h)
MAX_TABLE_BITS = 24
# What a trace_paths launch does with the photon map (PhotonMap.lookup turns
# a mode into the launch record's choices, kernels/path.h): none; merge at
# vertices with a non-delta part; the map owns the paths through the first
# one (x) and gathers there (online), or leaves that to a caustic buffer
# (offline); the offline pre-pass, which fills that buffer.
PM_OFF, PM_MERGE, PM_OWNED, PM_OFFLINE, PM_PREPASS = 0, 1, 2, 3, 4
MODES = ("merge", "online", "offline")


@dataclass(frozen=True)
class PhotonSettings:
    """How caustics are rendered with photons.

    count: photons emitted per photon map. radius: gather radius, a fraction
    of the scene's size (the diagonal of its geometry's bounds) unless
    radius_absolute. cone_k: Jensen's cone filter constant (>= 1).
    max_photons: most photons one gather uses (0: all within the radius; the
    paper's cap, which biases dense regions dark). budget: most photons a
    gather visits per row of three cells; denser rows are subsampled without
    bias (every s-th photon from a random offset, weighted by s).
    mode: "online" (the default) gathers in every sample; "offline" gathers in
    the offline_spp samples per pixel of a pre-pass (at most the render's spp)
    into a caustic buffer that is added to the image: cheaper, but where a
    caustic changes within a pixel, as at its focus, those few gathers leave
    noise that online mode averages away. Progressive rendering gathers online. aim: "solid_angle" picks casters by the solid angle
    they subtend from the light, "equal" gives each the same share (the
    paper). progressive: a fresh photon map every spp_per_map samples per
    pixel, with the radius shrinking as r_i^2 = r_0^2 prod (j + alpha)/(j + 1)
    (progressive photon mapping), so caustics converge instead of keeping a
    fixed blur.
    """

    count: int | None = None
    radius: float = 0.004
    budget: int = 128
    radius_absolute: bool = False
    cone_k: float = 1.1
    max_photons: int = 0
    mode: str = "merge"
    merge_vertices: int = 1 << 20
    merge_probability: float = 1.0
    aim: str = "solid_angle"
    offline_spp: int = 16
    progressive: bool | None = None
    photons_per_sample: float = 0.05
    pilot: bool = True
    min_caustic_share: float = 1e-2
    pilot_trial: bool = False
    alpha: float = 0.7
    spp_per_map: int = 8

    def check(self):
        def bad(what):
            raise SettingsError(f"photons: {what}")

        def is_int(v):
            return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))

        def is_num(v):
            return (is_int(v) or isinstance(v, (float, np.floating))) and math.isfinite(v)

        if self.count is not None and (not is_int(self.count) or not 0 <= self.count < 2 ** 31):
            bad(f"count must be an integer from 0 to 2^31 - 1 (got {self.count!r})")
        if not (is_num(self.radius) and 0 < self.radius < 3e38):
            bad(f"radius must be a number > 0 (got {self.radius!r})")
        if not (is_num(self.cone_k) and 1 <= self.cone_k < 3e38):
            bad(f"cone_k must be a number >= 1 (got {self.cone_k!r})")
        if not is_int(self.max_photons) or not 0 <= self.max_photons < 2 ** 32:
            bad(f"max_photons must be an integer from 0 to 2^32 - 1 (got {self.max_photons!r})")
        if not is_int(self.budget) or not 1 <= self.budget < 2 ** 32:
            bad(f"budget must be an integer from 1 to 2^32 - 1 (got {self.budget!r})")
        if self.mode not in MODES:
            bad(f"mode must be one of {', '.join(MODES)} (got {self.mode!r})")
        if not (is_num(self.merge_probability) and 0 < self.merge_probability <= 1):
            bad(f"merge_probability must be in (0, 1] (got {self.merge_probability!r})")
        if not is_int(self.merge_vertices) or not 1 <= self.merge_vertices < 2 ** 31:
            bad(f"merge_vertices must be an integer >= 1 (got {self.merge_vertices!r})")
        if self.aim not in ("solid_angle", "equal"):
            bad(f"aim must be 'solid_angle' or 'equal' (got {self.aim!r})")
        if not (is_num(self.photons_per_sample) and 0 < self.photons_per_sample < 1e6):
            bad(f"photons_per_sample must be > 0 (got {self.photons_per_sample!r})")
        if not isinstance(self.pilot, (bool, np.bool_)):
            bad(f"pilot must be True or False (got {self.pilot!r})")
        if not isinstance(self.pilot_trial, (bool, np.bool_)):
            bad(f"pilot_trial must be True or False (got {self.pilot_trial!r})")
        for key in ("offline_spp", "spp_per_map"):
            v = getattr(self, key)
            if not is_int(v) or not 1 <= v < 2 ** 32:
                bad(f"{key} must be an integer from 1 to 2^32 - 1 (got {v!r})")
        if not (is_num(self.alpha) and 0 < self.alpha <= 1):
            bad(f"alpha must be in (0, 1] (got {self.alpha!r})")
        if not isinstance(self.radius_absolute, (bool, np.bool_)):
            bad(f"radius_absolute must be True or False (got {self.radius_absolute!r})")
        if self.progressive is not None and not isinstance(self.progressive, (bool, np.bool_)):
            bad(f"progressive must be True, False or None (got {self.progressive!r})")
        return self

    def resolved(self, n_pixels: int) -> "PhotonSettings":
        """The settings with their automatic values filled in: merging is
        progressive unless told otherwise, and a progressive map holds
        photons_per_sample photons per camera sample of its iteration (so that
        tracing photons and building the grid stay a small share of the time,
        whatever the image size); a fixed map holds 10^6 photons."""
        progressive = self.mode == "merge" if self.progressive is None else bool(self.progressive)
        count = self.count
        if count is None:
            count = (max(1000, min(2 ** 30, int(self.photons_per_sample * n_pixels * self.spp_per_map)))
                     if progressive else 1_000_000)
        return replace(self, progressive=progressive, count=int(count))

    def check_radius(self, scene_size: float, double: bool = False):
        """The gather radius must be representable: its square above the
        smallest normal number of the kernels' real type (a smaller one finds
        nothing and divides by zero)."""
        r = self.radius_for(scene_size)
        tiny = float(np.finfo(np.float64 if double else np.float32).tiny)
        if not r * r > tiny * 4:
            raise SettingsError(f"photons: radius {r:.3g} is too small for {'double' if double else 'float'} "
                             f"precision (its square underflows); use a radius above {math.sqrt(tiny) * 2:.3g}")

    def radius_for(self, scene_size: float, iteration: int = 0) -> float:
        r = self.radius if self.radius_absolute else self.radius * scene_size
        if self.progressive:
            # r_{i+1}^2 = r_i^2 (i + alpha) / (i + 1), in closed form through lgamma
            # (Knaus and Zwicker, progressive photon mapping).
            log_ratio = (math.lgamma(iteration + self.alpha) - math.lgamma(self.alpha)
                         - math.lgamma(iteration + 1))
            r *= math.exp(0.5 * log_ratio)
        return r


def photon_seed(seed: int, iteration: int) -> int:
    """Seed of the photon map of a progressive iteration (0: the render's seed)."""
    if iteration == 0:
        return seed
    x = (seed * 0x9E3779B1 + iteration * 0x85EBCA77 + 0x165667B1) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x2C1B3C6D) & 0xFFFFFFFF
    return x ^ (x >> 12)


def pilot_choice(settings: PhotonSettings, power, max_flux: float, stored: int,
                 seconds: float) -> tuple[PhotonSettings, dict]:
    """Whether photon merging pays on this scene, from one photon map of the
    render's settings (after Grittmann et al. 2018, lightweight photon
    mapping, which falls back to path tracing where photons bring nothing):
    the share of the lights' power (max_flux, the packed scene's) that the
    stored caustic photons carry (power: their sums per RGB channel), that
    is light that reaches a diffuse surface through mirrors or glass. Below
    min_caustic_share the caustic paths are too faint to be worth a gather at
    every vertex and the render path traces alone. The threshold, 1%, lies
    between shares measured on either side at equal time: the small bulb's
    box (1.8%, the smallest share among the shipped photon scenes) and the
    caustics box (5.1%) gain 2-6x over the whole image with merging; a
    scene of twelve small lights and a glass ball (0.37%,
    tests/data/many_lights_glass.xml) lost 2-16%, merging costing 1.4x
    per sample there for a caustic path tracing already finds. Deterministic: the same
    seed and scene give the same map and the same choice (the Renderer runs
    the map's build as a job's "photons" item).
    Returns the settings to render with (count 0: path tracing) and what the
    pilot measured."""
    share = float(max(power)) / max(max_flux, 1e-300)
    use = share >= settings.min_caustic_share
    out = {"choice": "photon merging" if use else "path tracing", "caustic_share": share,
           "stored": stored, "photons": int(settings.count), "seconds": seconds}
    return (replace(settings, pilot=False) if use else replace(settings, count=0, pilot=False)), out


# The pilot's trial renders: at most this many pixels (the render's aspect),
# this many samples per pixel, with each technique.
TRIAL_PIXELS = 64 * 64
TRIAL_SPP = 8
TRIAL_ROUNDS = 3  # the pilot's trial: rounds of TRIAL_SPP per technique (Renderer._pilot_trial)
RELMSE_EPS = 1e-2  # as in relMSE: (x - ref)^2 / (ref^2 + eps), on luminance


def trial_size(width: int, height: int) -> tuple[int, int]:
    """The trial's resolution: the render's, scaled down to at most
    TRIAL_PIXELS pixels with its aspect kept."""
    scale = min(1.0, math.sqrt(TRIAL_PIXELS / (width * height)))
    return max(1, round(width * scale)), max(1, round(height * scale))


def relmse_per_sample(trials: dict) -> dict:
    """Per technique (name -> (luminance image, per-sample luminance
    variance)), the relMSE one sample per pixel leaves: the mean over pixels
    of var / (ref^2 + eps), ref the luminance of all techniques' images
    averaged (each an unbiased or nearly unbiased estimate of the same image)."""
    ref = np.mean([np.asarray(t[0], np.float64) for t in trials.values()], axis=0)
    den = ref * ref + RELMSE_EPS
    return {k: float(np.mean(np.asarray(v, np.float64) / den)) for k, (_, v) in trials.items()}


def path_variance(path_var, merge_var, moment):
    """Path tracing's per-sample luminance variance per pixel, for the pilot:
    its trial's own figure, or, where larger, merging's variance plus path
    tracing's second moment on the paths the merges took (moment, estimated
    from the merges' photons: kernels/photon_grid.h). Merging's variance
    stands for the paths both techniques make alike; on the merged paths,
    which path tracing finds only by hitting a light through mirrors and
    glass, an 8-sample trial of path tracing rarely sees the rare, bright
    samples that make its error, and the moment counts them."""
    est = np.asarray(merge_var, np.float64) + np.maximum(np.asarray(moment, np.float64), 0.0)
    return np.maximum(np.asarray(path_var, np.float64), np.where(np.isfinite(est), est, 0.0))


def weigh_cost(settings: PhotonSettings, info: dict, n_pix: int, per_sample: dict,
               seconds_per_sample: dict) -> tuple[PhotonSettings, dict]:
    """The pilot's second step, after Grittmann et al. 2018: each technique's
    error per unit of time, the relMSE one sample per pixel leaves
    (relmse_per_sample) times the seconds a sample costs (device seconds of
    its trial, photon maps included, per sample), for a render of n_pix
    pixels: the relMSE it reaches after one second. Photon merging is kept
    only where it reaches a lower figure than path tracing. The merge's
    bias (the radius' blur) is not in the figure. Returns the settings and
    info with the figures added."""
    at_1s = {k: per_sample[k] * seconds_per_sample[k] * n_pix for k in ("merge", "path")}
    use = at_1s["merge"] < at_1s["path"]
    out = dict(info, choice="photon merging" if use else "path tracing",
               relmse_per_sample=dict(per_sample), seconds_per_sample=dict(seconds_per_sample),
               predicted_relmse_1s=at_1s, predicted_gain=at_1s["path"] / max(at_1s["merge"], 1e-300))
    return (settings if use else replace(settings, count=0)), out
