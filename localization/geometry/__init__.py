"""Conventions and camera geometry: transforms, projection, attitude, lens distortion, the paper camera.

- :mod:`~localization.geometry.transforms` -- 4x4 rigid transforms named ``b_from_a``,
  projection with K, input checks for points, transforms and intrinsics, SO(3) maps (its names
  are this package's: ``from localization.geometry import invert, look_at, project``);
- :mod:`~localization.geometry.attitude` -- roll / pitch / yaw of a camera UAV and back;
- :mod:`~localization.geometry.distortion` -- OpenCV's five-coefficient lens model;
- :mod:`~localization.geometry.camera` -- the paper's camera (``PAPER_K``, ``PAPER_IMAGE_SIZE``);
- :mod:`~localization.geometry.kernels` -- the compiled forms of the per-pose maths.
"""

from localization.geometry import transforms
from localization.geometry.transforms import *  # noqa: F403  (the conventions are this package's names)

__all__ = list(transforms.__all__)
