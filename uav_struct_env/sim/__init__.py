"""pybullet simulation: client ownership, scene loading, calibrated rendering, landmark truth.

Public names are imported lazily, so ``uav_struct_env.sim.attitude`` does not pull in pybullet.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "Camera": "uav_struct_env.sim.camera",
    "projection_matrix": "uav_struct_env.sim.camera",
    "view_matrix": "uav_struct_env.sim.camera",
    "depth_from_buffer": "uav_struct_env.sim.camera",
    "CAMERA_MODELS": "uav_struct_env.sim.lens",
    "CameraModel": "uav_struct_env.sim.lens",
    "LensView": "uav_struct_env.sim.lens",
    "Motion": "uav_struct_env.sim.lens",
    "RenderClient": "uav_struct_env.sim.client",
    "resolve_renderer": "uav_struct_env.sim.client",
    "landmark_visibility": "uav_struct_env.sim.visibility",
    "RenderResult": "uav_struct_env.sim.world",
    "SiteWorld": "uav_struct_env.sim.world",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
