"""Moved to :mod:`uav_struct_env.stack.frame` (below ``wrappers/``); re-exported here."""

from uav_struct_env.stack.frame import FrameLocalization, localize_aruco_frame, localize_frame

__all__ = ["FrameLocalization", "localize_aruco_frame", "localize_frame"]
