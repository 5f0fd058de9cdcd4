"""ArUco markers on the ground as plain data: a printed square with its id, pose and quiet zone.

A :class:`~uav_struct_env.site.Site` carries its markers beside its elements; the landmarks
(:mod:`uav_struct_env.site.landmarks`), the textures and the meshes read them from here. Units are
metres, the frame is the project frame (right-handed, z up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.checks import check_number
from uav_struct_env.errors import SiteGeometryError
from uav_struct_env.site.elements import check_length, check_points

__all__ = ["ARUCO_DICTIONARY_SIZES", "MAX_MARKER_SIDE", "MAX_QUIET_ZONE", "ArucoMarker"]

#: Bounds of a marker's side (m) and of its quiet zone (times the side).
MAX_MARKER_SIDE = 10.0
MAX_QUIET_ZONE = 10.0

#: Number of markers in each supported OpenCV ArUco dictionary.
ARUCO_DICTIONARY_SIZES = {"DICT_4X4_50": 50, "DICT_4X4_100": 100, "DICT_5X5_50": 50}


@dataclass(frozen=True)
class ArucoMarker:
    """A printed ArUco marker lying flat on the ground, facing up.

    The marker frame is OpenCV's: x right and y up on the printed face, z out of the face (world
    +z here). ``yaw`` turns it about the world z axis. ``side`` is the black square's side length;
    a white quiet zone of ``quiet_zone`` times the side surrounds it.
    """

    id: int
    side: float
    center: tuple[float, float, float]
    yaw: float = 0.0
    dictionary: str = "DICT_4X4_50"
    quiet_zone: float = 0.25

    def __post_init__(self) -> None:
        check_length(f"marker {self.id} side", self.side, MAX_MARKER_SIDE)
        if not isinstance(self.dictionary, str) or self.dictionary not in ARUCO_DICTIONARY_SIZES:
            raise SiteGeometryError(
                f"marker {self.id} dictionary must be one of {sorted(ARUCO_DICTIONARY_SIZES)}, "
                f"got {self.dictionary!r}"
            )
        n = ARUCO_DICTIONARY_SIZES[self.dictionary]
        if not isinstance(self.id, (int, np.integer)) or not 0 <= self.id < n:
            raise SiteGeometryError(
                f"marker id must be an int in [0, {n}) for {self.dictionary}, got {self.id!r}"
            )
        check_number(f"marker {self.id} quiet_zone", self.quiet_zone, 0.0, MAX_QUIET_ZONE,
                     error=SiteGeometryError, type_error=SiteGeometryError)
        check_number(f"marker {self.id} yaw (rad)", self.yaw, error=SiteGeometryError,
                     type_error=SiteGeometryError)
        object.__setattr__(self, "center", check_points(f"marker {self.id} center", self.center, 3))

    @property
    def world_from_marker(self) -> NDArray[np.float64]:
        """4x4 pose of the marker frame in the project frame."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        out = np.eye(4)
        out[:2, :2] = [[c, -s], [s, c]]
        out[:3, 3] = self.center
        return out

    @property
    def corners_marker(self) -> NDArray[np.float64]:
        """(4, 3) corners in the marker frame, OpenCV order (TL, TR, BR, BL as printed)."""
        h = self.side / 2
        return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])

    @property
    def corners_world(self) -> NDArray[np.float64]:
        """(4, 3) corners in the project frame, OpenCV order."""
        T = self.world_from_marker
        return self.corners_marker @ T[:3, :3].T + T[:3, 3]

    @property
    def footprint_half_extent(self) -> float:
        """Half side of the printed sheet including its quiet zone."""
        return self.side * (0.5 + self.quiet_zone)
