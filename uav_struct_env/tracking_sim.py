"""The simulated 2D worker detector and the camera views the tracker is given in simulation.

Workers come from the environment's activity layer through two methods of the env:
``env.worker_points() -> {name: (2, 3)}`` (row 0 feet, row 1 head top, project frame, m) and
``env.worker_visibility(agent) -> {name: fraction}`` (ray-cast share of the worker visible from
that camera, its own airframe excluded).

:class:`SimulatedWorkerDetector` turns them into :class:`tracking.WorkerDetection` objects for one
camera, as a person-keypoint detector would: a worker is detected when at least ``min_visible``
of it is visible and both its points project into the image in front of the camera, then missed
with probability ``miss_rate``; its feet and head-top pixels get Gaussian noise of
``pixel_sigma`` (default 2 px at the paper's 1280-px width, scaled to the image width: body
keypoints are less sharp than structural corners). Projection includes the camera's lens
distortion when the env reports one (``info["distortion"]``). Every detection carries the
worker's name as its ``label`` (for scoring; the tracker never reads it).

:func:`camera_views` builds the tracker's views of one instant from the env's infos at one of three
pose sources: ``"truth"`` (the true camera poses: the floor), ``"estimated"`` (the localizer's
estimates with their covariance; cameras that failed to localize are left out) and ``"prior"``
(the onboard GNSS / attitude pose with the prior's sigmas as covariance).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_choice, check_number
from localization.geometry.transforms import invert
from localization.pose.covariance import PriorSigmas
from tracking import CameraView, WorkerDetection
from uav_struct_env.errors import ConfigError
from uav_struct_env.stack import PAPER_WIDTH_PX

__all__ = [
    "DEFAULT_WORKER_SIGMA_PX",
    "POSE_SOURCES",
    "SimulatedWorkerDetector",
    "camera_views",
    "check_worker_source",
    "truth_points",
]

#: Feet / head-top keypoint noise at the paper's 1280-px-wide camera, px.
DEFAULT_WORKER_SIGMA_PX = 2.0
#: Camera pose sources the tracker can be given.
POSE_SOURCES = ("truth", "estimated", "prior")


def check_worker_source(env: Any) -> Any:
    """The base env if it provides ``worker_points()`` and ``worker_visibility(agent)`` and has workers.

    Raises:
        ConfigError: naming the missing methods, or for an env without site activity.
    """
    base = env.unwrapped
    missing = [m for m in ("worker_points", "worker_visibility") if not callable(getattr(base, m, None))]
    if missing:
        raise ConfigError(
            f"worker tracking needs an env with workers (methods {missing} missing on "
            f"{type(base).__name__}): build it with site activity, e.g. activity='light'"
        )
    activity = getattr(getattr(base, "config", None), "activity", None)
    if activity is not None and activity.is_none:
        raise ConfigError(
            "worker tracking needs workers, but the env has no site activity (activity='none'): "
            "build it with activity='light' or 'busy'"
        )
    return base


class SimulatedWorkerDetector:
    """Project the true workers into one camera, with occlusion, misses and pixel noise.

    Args:
        pixel_sigma: noise of each keypoint coordinate, px of the env's images (None:
            :data:`DEFAULT_WORKER_SIGMA_PX` scaled by ``image_width / 1280``).
        miss_rate: probability that a detectable worker is not reported.
        min_visible: smallest visible fraction of a worker that gets it detected.
        rng: the generator of the noise and misses (re-seed with :meth:`seed`).

    Raises:
        ConfigError: for a value out of range (message names it).
    """

    def __init__(
        self,
        pixel_sigma: float | None = None,
        miss_rate: float = 0.05,
        min_visible: float = 0.5,
        rng: np.random.Generator | None = None,
    ) -> None:
        kw = {"error": ConfigError, "type_error": ConfigError}
        self.pixel_sigma = None if pixel_sigma is None else check_number(
            "pixel_sigma", pixel_sigma, 0.0, lo_open=True, **kw)
        self.miss_rate = check_number("miss_rate", miss_rate, 0.0, 1.0, **kw)
        self.min_visible = check_number("min_visible", min_visible, 0.0, 1.0, lo_open=True, **kw)
        self.rng = rng if rng is not None else np.random.default_rng()

    def seed(self, rng: np.random.Generator) -> None:
        """Draw noise and misses from ``rng`` from now on."""
        self.rng = rng

    def sigma(self, image_width: int) -> float:
        """The keypoint noise at images ``image_width`` px wide."""
        if self.pixel_sigma is not None:
            return self.pixel_sigma
        return DEFAULT_WORKER_SIGMA_PX * image_width / PAPER_WIDTH_PX

    def detect(
        self,
        points: Mapping[str, ArrayLike],
        visibility: Mapping[str, float],
        K: ArrayLike,
        cam_from_world: ArrayLike,
        image_size: tuple[int, int],
        distortion: ArrayLike | None = None,
    ) -> list[WorkerDetection]:
        """The detections of one camera, in the order of ``points`` (names sorted).

        Args:
            points: per worker name, (2, 3) true feet and head top, project frame, m.
            visibility: per worker name, the visible fraction from this camera (absent: 0).
            K: (3, 3) intrinsics.
            cam_from_world: (4, 4) the camera's true pose.
            image_size: (W, H) px.
            distortion: OpenCV coefficients of the lens, or None.
        """
        w, h = image_size
        sigma = self.sigma(w)
        K = np.asarray(K, dtype=np.float64)
        T = np.asarray(cam_from_world, dtype=np.float64)
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        dist = None if distortion is None else np.asarray(distortion, dtype=np.float64)
        out = []
        for name in sorted(points):
            if visibility.get(name, 0.0) < self.min_visible:
                continue
            pts = np.asarray(points[name], dtype=np.float64).reshape(2, 3)
            depth = pts @ T[2, :3] + T[2, 3]
            if np.any(depth <= 0):
                continue
            uv, _ = cv2.projectPoints(pts, rvec, T[:3, 3], K, dist)
            uv = uv.reshape(2, 2)
            if np.any(uv < -0.5) or np.any(uv[:, 0] > w - 0.5) or np.any(uv[:, 1] > h - 0.5):
                continue
            # both draws happen for every detectable worker, so a miss does not shift the noise
            missed = self.rng.random() < self.miss_rate
            uv = uv + self.rng.normal(0.0, sigma, (2, 2))
            if not missed:
                out.append(WorkerDetection(uv[0], uv[1], sigma, label=name))
        return out


def camera_views(
    infos: Mapping[str, Mapping[str, Any]],
    source: str,
    estimates: Mapping[str, Any] | None = None,
    prior_sigmas: PriorSigmas | None = None,
) -> list[CameraView]:
    """The tracker's views of the agents in ``infos`` at pose ``source`` (module docstring).

    Args:
        infos: per agent, the env's info (``world_from_cam``, ``prior_world_from_cam``,
            ``intrinsics``, optionally ``distortion``).
        source: one of :data:`POSE_SOURCES`.
        estimates: with ``"estimated"``, per agent a :class:`localization.PoseEstimate`; agents
            without one, or whose estimate failed, are left out.
        prior_sigmas: the prior's sigmas for ``"prior"`` (None: the paper's 3 m, 2/2/5 deg).

    Raises:
        ConfigError: for an unknown source, or ``"estimated"`` without ``estimates``.
    """
    check_choice("source", source, POSE_SOURCES, error=ConfigError)
    if source == "estimated" and estimates is None:
        raise ConfigError(
            "source='estimated' needs the localizer's estimates (a LocalizePoses wrapper below)"
        )
    sig = (prior_sigmas or PriorSigmas()).as_array()
    views = []
    for agent, info in infos.items():
        K = np.asarray(info["intrinsics"], dtype=np.float64)
        dist = info.get("distortion")
        if source == "truth":
            pose, cov = invert(info["world_from_cam"]), None
        elif source == "prior":
            pose, cov = invert(info["prior_world_from_cam"]), np.diag(sig**2)
        else:
            est = estimates.get(agent)
            if est is None or not est.success or not np.all(np.isfinite(est.covariance)):
                continue
            pose, cov = est.cam_from_world, est.covariance
        views.append(CameraView(agent, pose, K, dist, cov))
    return views


def truth_points(points: Mapping[str, ArrayLike]) -> dict[str, NDArray[np.float64]]:
    """``points`` as float64 (2, 3) arrays (the env's ``worker_points()`` for scoring)."""
    return {name: np.asarray(p, dtype=np.float64).reshape(2, 3) for name, p in points.items()}
