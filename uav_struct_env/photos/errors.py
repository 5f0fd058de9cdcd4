"""The photo package's one error: a photo, camera file or georeferencing that cannot be used."""

from __future__ import annotations

from uav_struct_env.errors import UavStructError

__all__ = ["PhotoError"]


class PhotoError(UavStructError, ValueError):
    """A photo, calibration file, prior or georeferencing that cannot be used; the message says why."""
