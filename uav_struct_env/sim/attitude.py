"""The attitude convention, re-exported where the simulator's users look for it.

The definitions live in :mod:`localization.geometry.attitude` (the bottom layer, so that the pure
localization package and its synthetic-data helpers share the one convention).
"""

from localization.geometry.attitude import (
    BODY_FROM_CAM,
    attitude_from_world_from_cam,
    world_from_cam_from_attitude,
)

__all__ = ["BODY_FROM_CAM", "attitude_from_world_from_cam", "world_from_cam_from_attitude"]
