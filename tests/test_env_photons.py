"""Photons from environments (constant and envmap): emitted through a disk
across the scene's bounding sphere, perpendicular to a direction drawn from
the map's own sampling tables (kernels/lights.h env_photon_dir,
env_photon_start), with the light-side pdf (direction pdf times the disk's
density) that a camera path escaping after a merge evaluates for its
weight (env_photon_pdf), so merging and path tracing still add up to one.

- Merging with zero photons is the path tracer's image exactly.
- A glass sphere on a floor under a constant environment and under a map
  with a bright sun: merging converges to the path tracer's image, block by
  block within noise (a double-counted or missing caustic is tens of sigma).
- The same in the photon map's own modes (the map owns the paths through
  the first non-delta vertex: online, progressive online and offline with
  its caustic buffer), where path tracing leaves the environment reached
  through glass after that vertex to the photons.
- The pilot counts the environment's power (clpt.pack max_flux).
"""

import functools
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import clpt
from clpt.pack import pack_scene
from clpt.photons import PhotonSettings
from clpt.scene import Camera, EnvironmentLight, Material, Quad, Scene, Sphere

sys.path.insert(0, str(Path(__file__).resolve().parent))
from envmaps import sun_map  # noqa: E402

LUMA = np.array([0.2126, 0.7152, 0.0722])
SIZE = 24


def _scene(env):
    """A glass ball resting over a diffuse floor, seen from above at an angle, lit only by env."""
    cam = Camera(origin=(0, 2.2, 2.2), target=(0, 0, 0), up=(0, 1, 0), fov=45, width=SIZE, height=SIZE)
    floor = Quad(corner=(-2, 0, 2), edge_u=(4, 0, 0), edge_v=(0, 0, -4), material=Material(kd=(0.6, 0.6, 0.6)))
    ball = Sphere(center=(0, 0.5, 0), radius=0.45, material=Material(kt=(1, 1, 1), ior=1.5))
    return Scene(camera=cam, shapes=[floor, ball, env])


SUN_ROT = ((1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1))
ENVS = {"constant": lambda: EnvironmentLight(radiance=(1.0, 0.9, 0.8)),
        "sun": lambda: EnvironmentLight(image=sun_map(), scale=0.5, to_world=SUN_ROT)}


def test_zero_photons_gives_the_path_tracers_image_exactly(device_spec):
    scene = _scene(ENVS["sun"]())
    pt = clpt.Renderer(scene, device=device_spec, photons=False).render(8, seed=4, max_depth=6)
    off = clpt.Renderer(scene, device=device_spec).render(8, seed=4, max_depth=6, photons=PhotonSettings(count=0))
    assert np.array_equal(pt.image, off.image) and np.array_equal(pt.lum_var, off.lum_var)


@pytest.mark.parametrize("env", sorted(ENVS))
def test_merging_converges_to_the_path_tracer(device_spec, env):
    """Block means (4 x 4 blocks of 6 x 6 pixels) of merging and of plain
    path tracing within 6 sigma (as tests/test_mis.py: the merge's per-pixel
    variance misses the photon noise shared within a map)."""
    scene = _scene(ENVS[env]())
    assert "environment" in pack_scene(scene).light_kinds
    pt = clpt.Renderer(scene, device=device_spec, photons=False).render(2048, seed=1, max_depth=8)
    pm = clpt.Renderer(scene, device=device_spec).render(
        512, seed=2, max_depth=8, photons=PhotonSettings(radius=0.004, count=20000, spp_per_map=4, pilot=False))
    assert pm.stats.nonfinite == 0 and sum(m["stored"] for m in pm.stats.photon_maps) > 0

    def blocks(a):
        return a.reshape(4, 6, 4, 6, *a.shape[2:]).mean(axis=(1, 3))

    d = blocks(pm.image @ LUMA) - blocks(pt.image @ LUMA)
    var = blocks(pm.lum_var / pm.sample_count) / 36 + blocks(pt.lum_var / pt.sample_count) / 36
    z = d / np.sqrt(var)
    assert np.abs(z).max() < 6, z.round(1)
    rel = abs(pm.image.mean() / pt.image.mean() - 1)
    assert rel < 0.02, f"image means differ by {rel:.2%}"


@functools.lru_cache(maxsize=None)
def _path_traced(device_spec, env):
    return clpt.Renderer(_scene(ENVS[env]()), device=device_spec, photons=False).render(2048, seed=1, max_depth=8)


def _blocks(a):
    return a.reshape(4, 6, 4, 6, *a.shape[2:]).mean(axis=(1, 3))


# The photon map's own modes: gathers at x in every sample from one map, from a fresh map every
# 4 samples per pixel, and a caustic buffer filled by a pre-pass of 64 samples per pixel.
OWNED = {"online": PhotonSettings(mode="online", progressive=False),
         "online progressive": PhotonSettings(mode="online", progressive=True, spp_per_map=4),
         "offline": PhotonSettings(mode="offline", offline_spp=64)}


@pytest.mark.parametrize("mode", sorted(OWNED))
@pytest.mark.parametrize("env", sorted(ENVS))
def test_owned_photon_modes_converge_to_the_path_tracer(device_spec, env, mode):
    """As above, for the modes where the photon map owns E S* x D S+ L: the
    environment seen through the ball from the floor comes from the photons
    alone. Block means within 6 sigma of path tracing (each block's sigma
    from both renders' per-pixel variances; the offline caustic buffer's
    counted in), image means within 2%. A caustic missing or counted twice
    moves blocks by more than the tolerance: the offline buffer's blocks
    alone stand above 6 sigma."""
    pt = _path_traced(device_spec, env)
    settings = replace(OWNED[mode], radius=0.004, count=20000, pilot=False)
    pm = clpt.Renderer(_scene(ENVS[env]()), device=device_spec).render(512, seed=2, max_depth=8, photons=settings)
    assert pm.stats.nonfinite == 0 and sum(m["stored"] for m in pm.stats.photon_maps) > 0
    d = _blocks(pm.image @ LUMA) - _blocks(pt.image @ LUMA)
    var = _blocks(pm.lum_var / pm.sample_count) / 36 + _blocks(pt.lum_var / pt.sample_count) / 36
    z = d / np.sqrt(var)
    assert np.abs(z).max() < 6, z.round(1)
    rel = abs(pm.image.mean() / pt.image.mean() - 1)
    assert rel < 0.02, f"image means differ by {rel:.2%}"
    if mode == "offline":
        assert pm.caustic_image is not None
        assert (_blocks(pm.caustic_image @ LUMA) / np.sqrt(var)).max() > 6


def test_the_environment_counts_in_the_photon_power():
    """max_flux (the pilot's denominator) holds the environment's power: 4 pi^2 R^2 L for a constant."""
    scene = _scene(EnvironmentLight(radiance=(2.0, 2.0, 2.0)))
    packed = pack_scene(scene)
    from clpt.pack import bounding_sphere
    _, radius = bounding_sphere(scene)
    assert packed.max_flux == pytest.approx(4 * math.pi ** 2 * radius ** 2 * 2.0, rel=1e-9)
