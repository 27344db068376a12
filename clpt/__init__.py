"""clpt: an OpenCL path tracer with caustic photon mapping, scripted from Python.

    import clpt
    img = clpt.render("cornell_box", spp=64)        # float32 H x W x 3, linear RGB
    clpt.save_image("cbox.png", img)
"""

from .adaptive import AdaptiveSettings
from .denoise import FilterSettings, OidnSettings
from .device import DeviceError, list_devices
from .features import Features, scene_features
from .image import load_image, save_image
from .photons import PhotonSettings
from .program import KernelBuildError, clear_cache
from .render import RenderResult, Renderer, RenderStats, RenderUpdate, render, resume as render_resume
from .resources import shipped_scenes
from .scene import (Box, Camera, Material, Mesh, Plane, Quad, RenderSettings, Scene, SceneError, SettingsError, Sphere, Triangle,
                    load_scene, parse_scene)

__version__ = "0.1.0"

__all__ = [
    "AdaptiveSettings", "FilterSettings", "OidnSettings", "PhotonSettings",
    "Box", "Camera", "DeviceError", "Features", "KernelBuildError", "Material", "Mesh", "Plane", "Quad", "RenderResult",
    "RenderSettings", "RenderStats", "RenderUpdate", "Renderer", "Scene", "SceneError", "SettingsError", "Sphere", "Triangle", "clear_cache",
    "list_devices", "load_image", "load_scene", "parse_scene", "render", "render_resume", "save_image", "scene_features",
    "shipped_scenes",
]
