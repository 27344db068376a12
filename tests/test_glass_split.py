"""The glass split (kernels/path.h path_glass_split): at the camera's first
vertex on smooth glass, the emission its reflection meets is taken in every
sample with the reflection's expected weight kr + F kt, and left out where
a sample's own reflection meets it again.

The scene: a glass interface at 45 degrees in front of a narrow camera, a
lamp straight above it, nothing else. Every pixel's value is the lamp
reflected, (kr + F(45 deg) kt) Le exactly (the refracted rays leave the
scene). Sampled by the coins alone, a pixel's samples would be Le kt with
probability F and 0 otherwise (kr = 0): a variance of F (1 - F) (Le kt)^2
per sample. Split, every sample carries the same value."""

import math

import numpy as np
import pytest

import clpt

LUMA = np.array([0.2126, 0.7152, 0.0722])
LE = 10.0
IOR = 1.5


def fresnel(cos_i, eta):
    """Unpolarised Fresnel reflectance of a dielectric interface (relative index eta)."""
    sin_t2 = (1 - cos_i ** 2) / eta ** 2
    cos_t = math.sqrt(1 - sin_t2)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return (rs * rs + rp * rp) / 2


def scene(kt=1.0, kr=0.0):
    a = 2 * math.sqrt(2)
    u, v = np.array([4.0, 0, 0]), np.array([0, a, -a])  # normal u x v along (0, 1, 1): towards camera and lamp
    glass = clpt.Quad(corner=tuple(-(u + v) / 2), edge_u=tuple(u), edge_v=tuple(v),
                      material=clpt.Material(kt=(kt, kt, kt), kr=(kr, kr, kr), ior=IOR))
    lamp = clpt.Quad(corner=(-3, 5, -3), edge_u=(6, 0, 0), edge_v=(0, 0, 6), material=clpt.Material(),
                     emission=(LE, LE, LE))  # facing down (-y), onto the glass
    cam = clpt.Camera(origin=(0, 0, 10), target=(0, 0, 0), fov=2, width=16, height=16)
    return clpt.Scene(camera=cam, shapes=[glass, lamp])


@pytest.mark.parametrize("kt, kr", [(1.0, 0.0), (0.5, 0.0), (0.5, 0.3)])
def test_a_lamp_reflected_in_glass_is_seen_by_every_sample(device_spec, kt, kr):
    res = clpt.Renderer(scene(kt, kr), device=device_spec, photons=False, aux=True).render(64, seed=5, max_depth=4)
    assert res.stats.nonfinite == 0
    lum = res.image @ LUMA
    # (kr + F kt) Le, F = 0.0502: the mirror lobe reflects alike (chosen by the lobe coin with kr's share);
    # the fov of 2 degrees moves F by < 2%.
    expect = (kr + fresnel(math.cos(math.pi / 4), IOR) * kt) * LE
    assert np.allclose(lum, expect, rtol=0.03), (lum.min(), lum.max(), expect)
    # Zero-one sampling would give each pixel a relative standard error of sqrt((1 - F) / (F n)) = 0.54 at
    # n = 64; split, the samples differ only as F does across a pixel.
    rel_var = res.lum_var / lum ** 2
    assert rel_var.max() < 1e-3, rel_var.max()
    # The features: every sample sees the lamp through the glass, and the emission they keep out is the image.
    assert np.all(res.aux["emitter"] == 1.0)
    assert np.allclose(res.aux["emission"] @ LUMA, lum, rtol=1e-4)
    # One more ray a camera sample.
    assert res.stats.bounce_rays >= res.stats.camera_rays
