"""clpt's error and warning classes, in one module every other can import.

Each is also importable from the module that raises it most (clpt.scene,
clpt.device, clpt.program, ...), as before.
"""

from __future__ import annotations


class SceneError(ValueError):
    """A scene is invalid. The message names the source, key path and reason."""


class SettingsError(SceneError):
    """A render setting (PhotonSettings, AdaptiveSettings, FilterSettings,
    OidnSettings, or a keyword of Renderer.render) is out of range or of the
    wrong type. A SceneError too, so one except clause catches bad input of
    either kind."""


class SceneWarning(UserWarning):
    """Part of a scene is approximated or left out; the message says which and where."""


class MeshError(SceneError):
    """A mesh file or array is missing, unreadable or malformed; the one-line
    message names it. A SceneError (and so a ValueError)."""


class CheckpointError(SceneError):
    """A checkpoint that cannot be read, or that belongs to another render."""


class DeviceError(RuntimeError):
    """No usable OpenCL device matches what was asked for."""


class DeviceWarning(UserWarning):
    """A device left out of a selection: one line naming it and why."""


class KernelBuildError(RuntimeError):
    """The OpenCL compiler rejected a kernel build."""


class ImageError(RuntimeError):
    """An image could not be written or read."""


class WorkerFailure(RuntimeError):
    """Every worker failed: the render cannot go on."""
