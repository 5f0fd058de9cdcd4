"""DJI's gimbal angles <-> the camera's rotation in a local east-north-up (ENU) frame.

DJI writes the gimbal's absolute attitude (``drone-dji:GimbalYaw/Pitch/RollDegree``) in the
north-east-down (NED) frame as intrinsic Z-Y-X Euler angles of the camera body's
forward-right-down (FRD) axes: ``ned_from_frd = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, yaw from true
north towards east, pitch positive nose up (``-90``: looking straight down), roll positive
right side down. The OpenCV camera frame (x right, y down, z forward: the project's camera
frame) is fixed to FRD: ``x_cam = y_frd``, ``y_cam = z_frd``, ``z_cam = x_frd``. ENU is NED with x
and y swapped and z negated. So

    enu_from_cam = ENU_FROM_NED @ ned_from_frd @ FRD_FROM_CAM.

The project frame's axes are ENU rotated about z by the georeferencing's angle (and the map
projection's grid convergence): :meth:`uav_struct_env.photos.georef.Georeference.project_from_enu`
gives that rotation at the camera's position.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from localization.checks import as_floats

__all__ = ["ENU_FROM_NED", "FRD_FROM_CAM", "dji_angles_from_enu_from_cam", "enu_from_cam_from_dji"]

#: NED -> ENU axes (its own inverse).
ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: OpenCV camera axes in the FRD body frame (columns: camera x, y, z).
FRD_FROM_CAM = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def enu_from_cam_from_dji(yaw_deg: float, pitch_deg: float, roll_deg: float) -> NDArray[np.float64]:
    """(3, 3) rotation of the OpenCV camera in ENU from DJI gimbal angles (degrees, NED, Z-Y-X)."""
    yaw, pitch, roll = as_floats("DJI gimbal angles (yaw, pitch, roll)", (yaw_deg, pitch_deg, roll_deg), 3)
    ned_from_frd = Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()
    return ENU_FROM_NED @ ned_from_frd @ FRD_FROM_CAM


def dji_angles_from_enu_from_cam(enu_from_cam: ArrayLike) -> tuple[float, float, float]:
    """Inverse of :func:`enu_from_cam_from_dji`: DJI (yaw, pitch, roll), degrees.

    Yaw in (-180, 180], pitch in [-90, 90]; at pitch +-90 (gimbal lock) scipy sets roll so that
    the rotation is reproduced.
    """
    R = np.asarray(enu_from_cam, dtype=np.float64).reshape(3, 3)
    ned_from_frd = ENU_FROM_NED.T @ R @ FRD_FROM_CAM.T
    yaw, pitch, roll = Rotation.from_matrix(ned_from_frd).as_euler("ZYX", degrees=True)
    return float(yaw), float(pitch), float(roll)
