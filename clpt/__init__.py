"""clpt: an OpenCL path tracer with caustic photon mapping, scripted from Python.

    import clpt
    img = clpt.render("cornell_box", spp=64)        # float32 H x W x 3, linear RGB
    clpt.save_image("cbox.png", img)
"""

# Before any OpenCL call: the runtimes installed with clpt join the ICD loader's list (clpt/runtimes.py).
from .runtimes import register as _register_runtimes

_register_runtimes()

from .adaptive import AdaptiveSettings  # noqa: E402
from .denoise import FilterSettings, OidnSettings  # noqa: E402
from .device import list_devices  # noqa: E402
from .errors import DeviceError, KernelBuildError, SceneError, SettingsError  # noqa: E402
from .features import Features, scene_features  # noqa: E402
from .image import load_image, save_image  # noqa: E402
from .loading import load_scene  # noqa: E402
from .photons import PhotonSettings  # noqa: E402
from .program import clear_cache  # noqa: E402
from .render import Renderer, RenderUpdate, render, resume as render_resume  # noqa: E402
from .resources import shipped_scenes  # noqa: E402
from .result import RenderResult, RenderStats  # noqa: E402
from .scene import (Box, Camera, DirectionalLight, EnvironmentLight, Material, Mesh, PixelFilter, Plane, PointLight, Quad, RenderSettings, Scene,  # noqa: E402
                    Sphere, SpotLight, Triangle, parse_scene)
from .version import __version__  # noqa: E402

__all__ = [
    "AdaptiveSettings", "FilterSettings", "OidnSettings", "PhotonSettings",
    "Box", "Camera", "DeviceError", "Features", "KernelBuildError", "Material", "Mesh", "PixelFilter", "Plane", "Quad", "RenderResult",
    "RenderSettings", "RenderStats", "RenderUpdate", "Renderer", "Scene", "SceneError", "SettingsError", "Sphere", "Triangle", "clear_cache", "PointLight", "SpotLight", "DirectionalLight", "EnvironmentLight",
    "list_devices", "load_image", "load_scene", "parse_scene", "render", "render_resume", "save_image", "scene_features",
    "shipped_scenes",
]
