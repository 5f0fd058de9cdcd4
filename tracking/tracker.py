"""Multi-view worker tracking for one instant: associate detections across cameras, triangulate.

from tracking import CameraView, WorkerDetection, track_workers
result = track_workers(views, {"uav_0": [WorkerDetection(feet_uv, head_uv, 2.0)], ...})
for w in result.tracked: w.feet_xyz, w.head_xyz, w.cameras, w.feet.covariance

Steps: undistort every detection (:meth:`CameraView.undistort`), associate them across views by
reprojection consistency (:mod:`tracking.associate`), then triangulate each group's feet and
head from all its views (:func:`~tracking.triangulate.triangulate_point`: DLT + least squares,
covariance, chi-square). Detections no other camera confirms come back as failed estimates
(``"seen by 1 camera only"``), never as exceptions.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.checks import check_number
from tracking.associate import associate
from tracking.triangulate import (
    DEFAULT_MIN_RAY_ANGLE_DEG,
    PointEstimate,
    triangulate_point,
    triangulate_upright,
)
from tracking.views import CameraView, WorkerDetection

__all__ = ["TrackingResult", "WorkerEstimate", "track_workers"]


@dataclass(frozen=True, eq=False)
class WorkerEstimate:
    """One worker located (or not) from the detections of several cameras.

    Attributes:
        feet: the triangulated feet point (:class:`~tracking.triangulate.PointEstimate`).
        head: the triangulated head-top point.
        detections: ``((view name, detection index), ...)`` the detections it was made of.
        labels: the ``label`` of each of those detections (scoring only; None from a real detector).
    """

    feet: PointEstimate
    head: PointEstimate
    detections: tuple[tuple[str, int], ...]
    labels: tuple[Hashable | None, ...]

    @property
    def success(self) -> bool:
        """Both points triangulated."""
        return self.feet.success and self.head.success

    @property
    def cameras(self) -> tuple[str, ...]:
        """Names of the views that saw it."""
        return tuple(name for name, _ in self.detections)

    @property
    def feet_xyz(self) -> NDArray[np.float64]:
        """(3,) feet, world frame, m (NaN when failed)."""
        return self.feet.xyz

    @property
    def head_xyz(self) -> NDArray[np.float64]:
        """(3,) head top, world frame, m (NaN when failed)."""
        return self.head.xyz

    @property
    def points(self) -> NDArray[np.float64]:
        """(2, 3): row 0 feet, row 1 head top."""
        return np.stack([self.feet.xyz, self.head.xyz])

    @property
    def label(self) -> Hashable | None:
        """The most common label of its detections (None when they carry none)."""
        return Counter(self.labels).most_common(1)[0][0]

    @property
    def failure_reason(self) -> str | None:
        """Why a point failed, or None."""
        for name, point in (("feet", self.feet), ("head", self.head)):
            if not point.success:
                return f"{name}: {point.failure_reason}"
        return None


@dataclass(frozen=True, eq=False)
class TrackingResult:
    """Every worker the cameras saw at one instant.

    Attributes:
        workers: one :class:`WorkerEstimate` per associated group, then one (failed) per
            detection no other camera confirmed.
        n_detections: detections given, over all views.
    """

    workers: tuple[WorkerEstimate, ...]
    n_detections: int

    @property
    def tracked(self) -> tuple[WorkerEstimate, ...]:
        """The successfully triangulated workers."""
        return tuple(w for w in self.workers if w.success)

    def cameras_of(self, view: str) -> tuple[WorkerEstimate, ...]:
        """The tracked workers that ``view`` contributed to."""
        return tuple(w for w in self.tracked if view in w.cameras)


def _check_views(views: Sequence[CameraView], detections: Mapping[str, Sequence[WorkerDetection]]):
    by_name: dict[str, CameraView] = {}
    for v in views:
        if not isinstance(v, CameraView):
            raise TypeError(f"views must be CameraView objects, got {type(v).__name__}")
        if v.name in by_name:
            raise ValueError(f"view names must be unique, got {v.name!r} twice")
        by_name[v.name] = v
    unknown = sorted(set(detections) - set(by_name))
    if unknown:
        raise ValueError(f"detections name views {unknown} that are not among the views {sorted(by_name)}")
    for name, dets in detections.items():
        for d in dets:
            if not isinstance(d, WorkerDetection):
                raise TypeError(
                    f"detections[{name!r}] must hold WorkerDetection objects, got {type(d).__name__}"
                )
    return by_name


def track_workers(
    views: Sequence[CameraView],
    detections: Mapping[str, Sequence[WorkerDetection]],
    *,
    gate_probability: float = 0.999,
    min_ray_angle_deg: float = DEFAULT_MIN_RAY_ANGLE_DEG,
    height_range: tuple[float, float] | None = None,
    upright: bool = False,
) -> TrackingResult:
    """Associate worker detections across ``views`` and triangulate every worker.

    Args:
        views: the cameras (unique names), at true or estimated poses; a view's
            ``pose_covariance`` widens its gate and lowers its weight.
        detections: per view name, that camera's detections (views without any may be absent).
        gate_probability: chi-square quantile of the consistency gate (pairs and groups).
        min_ray_angle_deg: a worker whose rays are closer to parallel is degenerate.
        height_range: ``(lo, hi)`` m the head top must lie above the feet in an association
            (None: no constraint); rejects pairs that fit two views only as a giant or a dwarf.
        upright: triangulate each worker standing, head top straight above the feet
            (:func:`~tracking.triangulate.triangulate_upright`; world z up); else feet and head
            independently.

    Returns:
        A :class:`TrackingResult`.

    Raises:
        TypeError / ValueError: for views or detections of the wrong type, duplicate view names,
            detections of unknown views, or an out-of-range argument (message names it).
    """
    gate_probability = check_number(
        "gate_probability", gate_probability, 0.0, 1.0, lo_open=True, hi_open=True
    )
    min_ray_angle_deg = check_number("min_ray_angle_deg", min_ray_angle_deg, 0.0, 180.0)
    if height_range is not None:
        lo = check_number("height_range[0]", height_range[0])
        hi = check_number("height_range[1]", height_range[1], lo, lo_open=True)
        height_range = (lo, hi)
    by_name = _check_views(views, detections)
    uv: dict[str, NDArray] = {}
    sigma: dict[str, NDArray] = {}
    for name, view in by_name.items():
        dets = list(detections.get(name, ()))
        raw = np.array([d.points_uv for d in dets]).reshape(-1, 2)
        uv[name] = view.undistort(raw).reshape(-1, 2, 2)
        sigma[name] = np.array([d.sigma_px for d in dets], dtype=np.float64)
    groups = associate(
        by_name, uv, sigma, probability=gate_probability, min_ray_angle_deg=min_ray_angle_deg,
        height_range=height_range,
    )
    workers = []
    used: set[tuple[str, int]] = set()
    for group in groups:
        names = [n for n in by_name if n in group]  # the views' order
        group_views = [by_name[n] for n in names]
        obs = np.stack([uv[n][group[n]] for n in names])  # (n, 2 points, 2)
        sig = np.array([sigma[n][group[n]] for n in names])
        if upright:
            feet, head = triangulate_upright(group_views, obs, sig, min_ray_angle_deg=min_ray_angle_deg)
        else:
            feet, head = (
                triangulate_point(group_views, obs[:, k], sig, min_ray_angle_deg=min_ray_angle_deg)
                for k in (0, 1)
            )
        members = tuple((n, group[n]) for n in names)
        used.update(members)
        workers.append(WorkerEstimate(feet, head, members, tuple(detections[n][i].label for n, i in members)))
    for name, view in by_name.items():
        for i, det in enumerate(detections.get(name, ())):
            if (name, i) in used:
                continue
            points = [triangulate_point([view], uv[name][i, k][None], det.sigma_px) for k in (0, 1)]
            workers.append(WorkerEstimate(points[0], points[1], ((name, i),), (det.label,)))
    return TrackingResult(tuple(workers), sum(len(d) for d in detections.values()))
