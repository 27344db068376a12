"""Every kernel variant in its GPU configuration, on whatever device the
suite runs on: a device that is not a CPU gets 1 lane, work-groups of
LOCAL_SIZE_GPU, 1024 photon chunks, and float (Kahan) sums where it has no
doubles. Here a CPU device is made to look like such a GPU (DeviceContext
says it is no CPU and has no fp64), so those code paths build and run on
every machine, GPU or not. Paths are keyed by pixel and sample, so the image
must equal the CPU configuration's but for the order of float sums: Kahan
float sums against double ones, and photons gathered in another order."""

from pathlib import Path

import numpy as np
import pytest

import clpt
from clpt import device as devmod
from clpt.constants import LOCAL_SIZE_GPU
from clpt.resources import shipped_scenes


@pytest.fixture
def gpu_like(monkeypatch):
    init = devmod.DeviceContext.__init__

    def as_gpu(self, device):
        init(self, device)
        self.is_cpu = False
        self.fp64 = False

    monkeypatch.setattr(devmod.DeviceContext, "__init__", as_gpu)


# Between them these build every kind of kernel: quads, spheres, triangles, a mesh in a BVH, Phong,
# mirror and glass lobes, quad, sphere and mesh lights, photons, the filter. The others: -m slow.
CORE = ("cornell_box", "cornell_box_caustics", "fig08_phong_highlight", "fig10_sphere_light_dual_glass",
        "mesh_glass_knot", "mesh_lights")
SCENES = [pytest.param(s, marks=() if s in CORE else pytest.mark.slow) for s in shipped_scenes()] + [
    str(Path(__file__).parent / "data" / "cbox_shapes.xml")]


@pytest.mark.parametrize("name", SCENES)
def test_gpu_configuration_renders_the_cpu_image(device_spec, name, request):
    kw = dict(spp=4, width=24, height=20, seed=7)  # 480 pixels: not a multiple of the work-group size
    filt = clpt.FilterSettings()
    cpu = clpt.Renderer(name, device=device_spec, aux=True).render(filter=filt, **kw)
    request.getfixturevalue("gpu_like")
    r = clpt.Renderer(name, device=device_spec, aux=True)
    st = r.states[0]
    assert (st.features.lanes, st.local, st.features.accum_double) == (1, LOCAL_SIZE_GPU, False)
    gpu = r.render(filter=filt, **kw)
    for a, b in ((cpu.image, gpu.image), (cpu.filtered, gpu.filtered)):
        assert np.isfinite(b).all()
        # Measured on Intel's runtime: at most 4.5e-7 (a few float roundings), median 0.
        assert np.max(np.abs(a - b) / (np.abs(a) + 1e-3)) < 1e-5
