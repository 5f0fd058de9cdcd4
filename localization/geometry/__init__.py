"""Conventions and camera geometry: transforms, projection, attitude, lens distortion, the paper camera.

- :mod:`~localization.geometry.transforms` -- 4x4 rigid transforms named ``b_from_a``,
  projection with K, input checks for points, transforms and intrinsics, SO(3) maps (its names
  are this package's: ``from localization.geometry import invert, look_at, project``);
- :mod:`~localization.geometry.attitude` -- roll / pitch / yaw of a camera UAV and back;
- :mod:`~localization.geometry.distortion` -- OpenCV's five-coefficient lens model;
- :mod:`~localization.geometry.camera` -- the paper's camera (``PAPER_K``, ``PAPER_IMAGE_SIZE``);
- :mod:`~localization.geometry.kernels` -- the compiled forms of the per-pose maths.
"""

from localization.geometry.transforms import (
    as_points,
    camera_center,
    check_intrinsics,
    check_transform,
    inverse_intrinsics,
    invert,
    look_at,
    make_transform,
    matrix_from_quat_wxyz,
    project,
    quat_wxyz_from_matrix,
    rotation_angle_deg,
    skew,
    so3_exp,
    so3_log,
    transform_points,
)

__all__ = [
    "as_points",
    "camera_center",
    "check_intrinsics",
    "check_transform",
    "inverse_intrinsics",
    "invert",
    "look_at",
    "make_transform",
    "matrix_from_quat_wxyz",
    "project",
    "quat_wxyz_from_matrix",
    "rotation_angle_deg",
    "skew",
    "so3_exp",
    "so3_log",
    "transform_points",
]
