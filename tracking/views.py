"""What the tracker is given: camera views and 2D worker detections.

A :class:`CameraView` is a pose, intrinsics, optional distortion and optional pose uncertainty;
a :class:`WorkerDetection` is the feet and head-top pixels of one worker with their noise.

Conventions are :mod:`localization.geometry`'s: ``cam_from_world`` 4x4, OpenCV camera frame,
integer pixel centres. A view's optional ``pose_covariance`` is a 6x6 covariance in the
parameterization of :class:`localization.PoseEstimate` (camera centre [m], then a world-frame
rotation vector [rad]); the tracker propagates it to pixels at each point (``J Sigma J^T`` with
:func:`localization.pose.covariance.pose_jacobian`) and adds it to the detector noise, so cameras localized
with decimetre errors are weighted and gated by what their pose really knows.
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from localization.geometry.transforms import check_intrinsics, check_transform

__all__ = ["CameraView", "WorkerDetection"]

# OpenCV's default (5 fixed iterations) leaves ~0.1 px at the image corners of a strong lens.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


def _uv(name: str, value: ArrayLike) -> NDArray[np.float64]:
    arr = np.asarray(value)
    if arr.dtype == object or not np.issubdtype(arr.dtype, np.number):
        raise TypeError(f"{name} must be a numeric (2,) pixel position, got dtype {arr.dtype}")
    if arr.shape != (2,):
        raise ValueError(f"{name} must have shape (2,) (u, v in px), got {arr.shape}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


@dataclass(frozen=True, eq=False)
class WorkerDetection:
    """One worker seen in one image: where its feet and the top of its head appear.

    Attributes:
        feet_uv: (2,) pixel position of the feet (the ground contact point), px.
        head_uv: (2,) pixel position of the head top, px.
        sigma_px: isotropic detector noise of both points, px (> 0).
        label: anything identifying the true worker, for scoring only (a simulated detector
            knows it; a real one leaves None). The tracker never reads it.
    """

    feet_uv: NDArray[np.float64]
    head_uv: NDArray[np.float64]
    sigma_px: float = 2.0
    label: Hashable | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "feet_uv", _uv("feet_uv", self.feet_uv))
        object.__setattr__(self, "head_uv", _uv("head_uv", self.head_uv))
        object.__setattr__(self, "sigma_px", check_number("sigma_px", self.sigma_px, 0.0, lo_open=True))

    @property
    def points_uv(self) -> NDArray[np.float64]:
        """(2, 2): row 0 feet, row 1 head top (the order of every (2, 3) worker array)."""
        return np.stack([self.feet_uv, self.head_uv])


@dataclass(frozen=True, eq=False)
class CameraView:
    """A calibrated camera at a known (or estimated) pose.

    Attributes:
        name: the camera's name (an agent name), unique among the views given together.
        cam_from_world: (4, 4) pose.
        K: (3, 3) intrinsics.
        distortion: OpenCV (Brown-Conrady) coefficients ``(k1, k2, p1, p2[, k3])`` or None for an
            ideal pinhole; detections are undistorted with ``cv2.undistortPoints`` first.
        pose_covariance: (6, 6) covariance of the pose (module docstring) or None (exact pose).
    """

    name: str
    cam_from_world: NDArray[np.float64]
    K: NDArray[np.float64]
    distortion: NDArray[np.float64] | None = None
    pose_covariance: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise TypeError(f"name must be a non-empty str, got {self.name!r}")
        object.__setattr__(self, "cam_from_world", check_transform("cam_from_world", self.cam_from_world))
        object.__setattr__(self, "K", check_intrinsics("K", self.K))
        if self.distortion is not None:
            d = np.asarray(self.distortion, dtype=np.float64).reshape(-1)
            if d.size not in (4, 5, 8) or not np.all(np.isfinite(d)):
                raise ValueError(
                    f"distortion must be 4, 5 or 8 finite OpenCV coefficients (k1, k2, p1, p2[, k3...]), "
                    f"got {np.asarray(self.distortion).tolist()}"
                )
            object.__setattr__(self, "distortion", d)
        if self.pose_covariance is not None:
            c = np.asarray(self.pose_covariance, dtype=np.float64)
            if c.shape != (6, 6) or not np.all(np.isfinite(c)):
                raise ValueError(
                    f"pose_covariance must be a finite (6, 6) array (camera centre m, rotation rad), "
                    f"got shape {c.shape}{'' if c.shape != (6, 6) else ' with non-finite entries'}"
                )
            if np.min(np.linalg.eigvalsh(0.5 * (c + c.T))) < -1e-12:
                raise ValueError("pose_covariance must be positive semi-definite")
            object.__setattr__(self, "pose_covariance", 0.5 * (c + c.T))

    def undistort(self, uv: ArrayLike) -> NDArray[np.float64]:
        """(N, 2) ideal-pinhole pixel positions of observed (distorted) pixels ``uv`` (N, 2)."""
        pts = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if self.distortion is None or not np.any(self.distortion) or len(pts) == 0:
            return pts.copy()
        out = cv2.undistortPoints(
            pts.reshape(-1, 1, 2), self.K, self.distortion, None, None, self.K, _UNDISTORT_CRITERIA
        )
        return out.reshape(-1, 2)

    def replace_pose(self, cam_from_world: ArrayLike, pose_covariance: Any = None) -> CameraView:
        """The same camera at another pose (for example the localizer's estimate)."""
        return CameraView(self.name, np.asarray(cam_from_world), self.K, self.distortion, pose_covariance)
