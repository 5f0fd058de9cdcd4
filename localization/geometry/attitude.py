"""The attitude convention: camera position + (roll, pitch, yaw) <-> ``world_from_cam``.

Documented once here and in docs/environment.md (Conventions), tested in
``tests/sim/test_attitude.py``. It lives in the bottom layer (pure numpy / scipy) so the
localization package's synthetic data shares it; ``uav_struct_env.sim.attitude`` re-exports it.

* The camera *body* frame is FLU: x forward along the optical axis, y left, z up in the image.
* ``world_from_body = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (intrinsic Z-Y'-X'', scipy ``"ZYX"``).
  Yaw is measured in the project frame from +x towards +y (counter-clockwise seen from above).
  With y pointing left, **positive pitch tilts the optical axis down**: a camera looking 30 deg
  below the horizon has ``pitch = +0.5236``. Positive roll turns the image clockwise as seen by
  the camera (left side up).
* The OpenCV camera frame is fixed to the body: ``x_cam = -y_body`` (right), ``y_cam = -z_body``
  (down), ``z_cam = x_body`` (forward).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from localization.checks import as_floats

__all__ = ["BODY_FROM_CAM", "attitude_from_world_from_cam", "world_from_cam_from_attitude"]


#: Rotation taking OpenCV camera axes to FLU body axes (columns: camera x, y, z in the body frame).
BODY_FROM_CAM = np.array(
    [
        [0.0, 0.0, 1.0],
        [-1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
    ]
)


def world_from_cam_from_attitude(position: ArrayLike, attitude: ArrayLike) -> NDArray[np.float64]:
    """4x4 ``world_from_cam`` of a camera at ``position`` (3,) with ``attitude`` (roll, pitch, yaw)."""
    roll, pitch, yaw = as_floats("attitude", attitude, 3)
    # Rz(yaw) @ Ry(pitch) @ Rx(roll) @ BODY_FROM_CAM, written out on Python floats (scipy's
    # from_euler("ZYX") gives the same matrix at several times the cost, and the env builds
    # several per agent-step); BODY_FROM_CAM only permutes and negates columns, so the product
    # is exact: camera x = -body y, camera y = -body z, camera z = body x
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    x, y, z = as_floats("position", position, 3)
    return np.array([
        [-(cy * sp * sr - sy * cr), -(cy * sp * cr + sy * sr), cy * cp, x],
        [-(sy * sp * sr + cy * cr), -(sy * sp * cr - cy * sr), sy * cp, y],
        [-(cp * sr), -(cp * cr), -sp, z],
        [0.0, 0.0, 0.0, 1.0],
    ])


def attitude_from_world_from_cam(
    world_from_cam: ArrayLike,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Inverse of :func:`world_from_cam_from_attitude`: ``(position (3,), (roll, pitch, yaw) (3,))``.

    Yaw is in (-pi, pi], pitch in [-pi/2, pi/2]; at pitch = +-pi/2 (gimbal lock) roll is set to 0.
    """
    T = np.asarray(world_from_cam, dtype=np.float64)
    world_from_body = T[:3, :3] @ BODY_FROM_CAM.T
    yaw, pitch, roll = Rotation.from_matrix(world_from_body).as_euler("ZYX")
    return T[:3, 3].copy(), np.array([roll, pitch, yaw])
