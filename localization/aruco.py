"""The ArUco baseline: markers with known world poses, detected in the image, give the camera pose.

OpenCV 5 removed ``cv2.aruco.estimatePoseSingleMarkers``; markers are found with
``cv2.aruco.ArucoDetector(...).detectMarkers`` and posed with ``cv2.solvePnPGeneric(...,
flags=cv2.SOLVEPNP_IPPE_SQUARE)``.

Two modes:

``average`` (the paper's)
    One IPPE_SQUARE pose per marker. IPPE returns two solutions; at UAV distances the wrong one
    wins on reprojection error in a fifth to nearly half of the views (docs/design.md), so the solution
    is chosen by ``n rmse^2 / sigma^2 + prior Mahalanobis^2`` when a prior is given. The camera
    centres are averaged arithmetically and the rotations by their chordal L2 mean
    (``scipy.spatial.transform.Rotation.mean``), never by Euler angles.
``joint`` (stronger)
    One PnP over all corners of all seen markers (IPPE in the markers' plane frame when they are
    coplanar, SQPnP otherwise, candidate chosen with the prior), refined by Levenberg-Marquardt.

A pose counts as successful with at least one known marker (the paper's rule).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from localization.checks import check_number
from localization.failure import FailureCode
from localization.geometry.distortion import check_distortion, is_pinhole, undistort_points
from localization.geometry.transforms import (
    camera_center,
    check_intrinsics,
    check_transform,
    invert,
    make_transform,
)
from localization.pipeline import PoseEstimate
from localization.pose.covariance import PriorSigmas, pose_covariance, prior_mahalanobis_sq
from localization.pose.pnp import refine_pose, reprojection_residuals, solve_pnp

__all__ = ["ARUCO_MODES", "ArucoLocalizer", "MarkerSpec", "marker_corners"]

ARUCO_MODES = ("average", "joint")


@dataclass(frozen=True, eq=False)
class MarkerSpec:
    """A marker of the map: id, side of the black square (m), pose of its frame in the world."""

    id: int
    side: float
    world_from_marker: NDArray[np.float64]


@dataclass(frozen=True)
class _Failure:
    """Why no pose: the code for grouping, the reason for people."""

    code: FailureCode
    reason: str


def _failed(
    failure: _Failure,
    fallback: NDArray[np.float64],
    assignment: NDArray[np.int64],
    timings: dict[str, float],
    t0: float,
) -> PoseEstimate:
    """The failed estimate: ``fallback`` as the pose, ``timings`` closed with the total since ``t0``."""
    timings["total"] = time.perf_counter() - t0
    return PoseEstimate(
        success=False,
        cam_from_world=fallback.copy(),
        assignment=assignment,
        failure_reason=failure.reason,
        failure_code=failure.code,
        timings=timings,
    )


def marker_corners(side: float) -> NDArray[np.float64]:
    """(4, 3) corners of a marker of side ``side`` in its own frame, in OpenCV's order.

    Top-left, top-right, bottom-right, bottom-left of the printed face: ``(-s/2, s/2, 0),
    (s/2, s/2, 0), (s/2, -s/2, 0), (-s/2, -s/2, 0)``, the order ``SOLVEPNP_IPPE_SQUARE`` requires.
    """
    h = side / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def _as_spec(m: Any, i: int) -> MarkerSpec:
    if isinstance(m, MarkerSpec):
        return m
    if all(hasattr(m, a) for a in ("id", "side", "world_from_marker")):
        mid, side, T = m.id, m.side, m.world_from_marker
    else:
        try:
            mid, side, T = m
        except (TypeError, ValueError):
            raise TypeError(
                f"markers[{i}] must be (id, side_m, world_from_marker) or have those attributes, "
                f"got {m!r}"
            ) from None
    mid = check_number(f"markers[{i}] id", mid, 0, integer=True, type_error=ValueError)
    side = check_number(f"markers[{i}] side", side, 0.0, lo_open=True)
    T = check_transform(f"markers[{i}] world_from_marker", T)
    return MarkerSpec(mid, side, T)


class ArucoLocalizer:
    """Camera pose from ArUco markers with known world poses.

    Args:
        markers: sequence of ``(id, side_m, world_from_marker)`` or objects with those attributes
            (e.g. ``uav_struct_env.site`` markers).
        K: (3, 3) intrinsics.
        mode: ``"average"`` (the paper's) or ``"joint"`` (module docstring).
        dictionary: an OpenCV predefined dictionary id, default ``cv2.aruco.DICT_4X4_50``.
        detector_parameters: ``cv2.aruco.DetectorParameters`` (default: OpenCV's, with subpixel
            corner refinement).
        dist_coeffs: the camera's OpenCV distortion coefficients ``(k1, k2, p1, p2, k3)``, or
            None for a pinhole. Detected corners are undistorted to pinhole pixels of ``K`` once
            (:func:`localization.geometry.distortion.undistort_points`, exact) on entry to
            :meth:`localize_corners`; everything after is the pinhole model.
        pixel_sigma: corner noise, px (candidate choice and covariance).
        prior_sigmas: prior uncertainty (default 3 m, 2/2/5 degrees).

    Raises:
        TypeError, ValueError: on bad arguments, naming the value.
    """

    def __init__(
        self,
        markers: Sequence[Any],
        K: ArrayLike,
        mode: str = "joint",
        *,
        dictionary: int = cv2.aruco.DICT_4X4_50,
        detector_parameters: Any = None,
        dist_coeffs: ArrayLike | None = None,
        pixel_sigma: float = 1.0,
        prior_sigmas: PriorSigmas | None = None,
    ) -> None:
        if isinstance(markers, (str, bytes)) or not isinstance(markers, Sequence):
            raise TypeError(f"markers must be a sequence, got {type(markers).__name__}")
        self.markers = tuple(_as_spec(m, i) for i, m in enumerate(markers))
        ids = [m.id for m in self.markers]
        if len(set(ids)) != len(ids):
            raise ValueError(f"marker ids must be unique, got {ids}")
        self.K = check_intrinsics("K", K)
        if mode not in ARUCO_MODES:
            raise ValueError(f"mode must be one of {ARUCO_MODES}, got {mode!r}")
        self.mode = mode
        if not (isinstance(pixel_sigma, (int, float)) and pixel_sigma > 0):
            raise ValueError(f"pixel_sigma must be a number > 0, got {pixel_sigma!r}")
        self.pixel_sigma = float(pixel_sigma)
        self.prior_sigmas = prior_sigmas or PriorSigmas()
        self.dist_coeffs = (
            None if is_pinhole(dist_coeffs) else check_distortion("dist_coeffs", dist_coeffs)
        )
        params = detector_parameters
        if params is None:
            params = cv2.aruco.DetectorParameters()
            params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self._detector = cv2.aruco.ArucoDetector(
            cv2.aruco.getPredefinedDictionary(dictionary), params
        )
        self._index = {m.id: i for i, m in enumerate(self.markers)}
        #: (4 * len(markers), 3) all marker corners in the world, marker-major, OpenCV order.
        self.corners_world = np.concatenate(
            [
                marker_corners(m.side) @ m.world_from_marker[:3, :3].T + m.world_from_marker[:3, 3]
                for m in self.markers
            ]
        ).reshape(-1, 3)

    # ----------------------------------------------------------------------------------------

    def detect(self, image: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Detect markers: ``(ids (K,), corners (K, 4, 2))`` in OpenCV's corner order.

        Raises:
            TypeError, ValueError: if ``image`` is not an (H, W) or (H, W, 3) uint8 array.
        """
        img = np.asarray(image)
        if img.dtype != np.uint8:
            raise TypeError(f"image must be uint8 (H, W) or (H, W, 3), got dtype {img.dtype}")
        if img.ndim == 3 and img.shape[2] == 3:
            img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        elif img.ndim == 3 and img.shape[2] == 4:
            img = cv2.cvtColor(img, cv2.COLOR_RGBA2GRAY)
        elif img.ndim != 2:
            raise ValueError(f"image must have shape (H, W) or (H, W, 3), got {img.shape}")
        corners, ids, _ = self._detector.detectMarkers(np.ascontiguousarray(img))
        if ids is None or len(ids) == 0:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 4, 2))
        return (
            np.asarray(ids, dtype=np.int64).reshape(-1),
            np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2),
        )

    def localize(self, image: ArrayLike, prior_cam_from_world: ArrayLike | None) -> PoseEstimate:
        """Detect the markers in ``image`` and estimate ``cam_from_world`` (see the class doc)."""
        t0 = time.perf_counter()
        ids, corners = self.detect(image)
        t_detect = time.perf_counter() - t0
        est = self.localize_corners(ids, corners, prior_cam_from_world)
        timings = {"detect": t_detect, **est.timings}
        timings["total"] = time.perf_counter() - t0
        return replace(est, timings=timings)

    def localize_corners(
        self, ids: ArrayLike, corners: ArrayLike, prior_cam_from_world: ArrayLike | None
    ) -> PoseEstimate:
        """Pose from already detected markers.

        Args:
            ids: (K,) marker ids.
            corners: (K, 4, 2) their corners in OpenCV's order, as detected (distorted pixels
                when the localizer has ``dist_coeffs``).
            prior_cam_from_world: (4, 4) rough pose choosing between IPPE solutions, or None
                (then the lowest reprojection error wins; expect flips).

        Returns:
            A :class:`~localization.pipeline.PoseEstimate`; ``assignment`` has one entry per
            corner (``4 K``, marker-major), the row of :attr:`corners_world` it corresponds to,
            -1 for corners of markers not in the map.
        """
        t0 = time.perf_counter()
        ids, c = self._check_corners(ids, corners)
        prior = (
            None
            if prior_cam_from_world is None
            else check_transform("prior_cam_from_world", prior_cam_from_world)
        )
        fallback = prior if prior is not None else np.eye(4)
        assignment, known = self._assign(ids, c)
        timings = {"associate": time.perf_counter() - t0}
        if not known:
            failure = _Failure(FailureCode.NO_MARKERS, f"no known marker detected (ids seen: {ids.tolist()})")
            return _failed(failure, fallback, assignment, timings, t0)
        m = assignment >= 0
        X = self.corners_world[assignment[m]]
        uv = c.reshape(-1, 2)[m]
        t1 = time.perf_counter()
        T = self._pose(known, c, X, uv, prior)
        if isinstance(T, _Failure):
            timings["pnp"] = time.perf_counter() - t1
            return _failed(T, fallback, assignment, timings, t0)
        res_px, depth = reprojection_residuals(self.K, T, X, uv)
        timings["pnp"] = time.perf_counter() - t1
        if not np.all(depth > 0):
            failure = _Failure(FailureCode.BEHIND_CAMERA, "the pose puts marker corners behind the camera")
            return _failed(failure, fallback, assignment, timings, t0)
        t2 = time.perf_counter()
        cov = pose_covariance(self.K, T, X, self.pixel_sigma)
        timings["covariance"] = time.perf_counter() - t2
        timings["total"] = time.perf_counter() - t0
        return PoseEstimate(
            success=True,
            cam_from_world=T,
            assignment=assignment,
            reprojection_rmse_px=float(np.sqrt(np.mean(np.sum(res_px**2, axis=1)))),
            n_inliers=int(m.sum()),
            covariance=cov,
            failure_reason=None,
            timings=timings,
            prior_mahalanobis_sq=(
                float("nan") if prior is None else prior_mahalanobis_sq(T, prior, self.prior_sigmas)
            ),
            n_hypotheses=len(known),
        )

    def _check_corners(
        self, ids: ArrayLike, corners: ArrayLike
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """``(ids (K,), corners (K, 4, 2))`` checked, the corners undistorted to pinhole pixels."""
        ids = np.asarray(ids).astype(np.int64).reshape(-1)
        c = np.asarray(corners, dtype=np.float64)
        if c.size == 0:
            c = c.reshape(0, 4, 2)
        if c.ndim != 3 or c.shape[1:] != (4, 2) or c.shape[0] != ids.shape[0]:
            raise ValueError(f"corners must have shape ({ids.shape[0]}, 4, 2), got {c.shape}")
        if self.dist_coeffs is not None:  # pinhole pixels from here on
            c = undistort_points(c.reshape(-1, 2), self.K, self.dist_coeffs).reshape(c.shape)
        return ids, c

    def _assign(
        self, ids: NDArray[np.int64], corners: NDArray[np.float64]
    ) -> tuple[NDArray[np.int64], list[tuple[int, int]]]:
        """Each corner's row of :attr:`corners_world` (-1: not in the map, or not finite).

        Returns ``(assignment (4 K,), known)``, ``known`` the ``(detection k, marker index i)``
        of every marker of the map seen with finite corners.
        """
        assignment = np.full(4 * ids.shape[0], -1, dtype=np.int64)
        known = []
        for k, mid in enumerate(ids):
            i = self._index.get(int(mid))
            if i is not None and np.all(np.isfinite(corners[k])):
                assignment[4 * k : 4 * k + 4] = 4 * i + np.arange(4)
                known.append((k, i))
        return assignment, known

    def _pose(
        self,
        known: list[tuple[int, int]],
        corners: NDArray[np.float64],
        X: NDArray[np.float64],
        uv: NDArray[np.float64],
        prior: NDArray[np.float64] | None,
    ) -> NDArray[np.float64] | _Failure:
        """The mode's ``cam_from_world`` from the known markers, or why there is none.

        ``joint``: one PnP over the corners ``X`` (world) <-> ``uv``; ``average``: the mean of the
        markers' own poses (:meth:`_average`).
        """
        if self.mode == "joint":
            res = solve_pnp(
                X,
                uv,
                self.K,
                prior,
                rule="prior" if prior is not None else "paper",
                pixel_sigma=self.pixel_sigma,
                prior_sigmas=self.prior_sigmas,
            )
            if not res.success:
                return _Failure(
                    res.failure_code or FailureCode.PNP_FAILED, res.failure_reason or "PnP failed"
                )
            return res.cam_from_world
        T = self._average(known, corners, prior)
        if T is None:
            return _Failure(FailureCode.BEHIND_CAMERA, "every marker pose puts the marker behind the camera")
        return T

    def marker_pose_candidates(
        self, marker_index: int, corners_uv: ArrayLike
    ) -> list[NDArray[np.float64]]:
        """The (up to two) IPPE_SQUARE ``cam_from_world`` candidates from one marker's corners."""
        spec = self.markers[marker_index]
        obj = marker_corners(spec.side).reshape(-1, 1, 3)
        img = np.asarray(corners_uv, dtype=np.float64).reshape(-1, 1, 2)
        try:
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                obj, img, self.K, None, flags=cv2.SOLVEPNP_IPPE_SQUARE
            )
        except cv2.error:
            return []
        marker_from_world = invert(spec.world_from_marker)
        out = []
        for r, t in zip(rvecs[:n], tvecs[:n], strict=True):
            R, _ = cv2.Rodrigues(np.asarray(r, dtype=np.float64).reshape(3, 1))
            cam_from_marker = make_transform(R, np.asarray(t, dtype=np.float64).reshape(3))
            out.append(cam_from_marker @ marker_from_world)
        return out

    def _average(
        self, known: list[tuple[int, int]], corners: NDArray, prior: NDArray | None
    ) -> NDArray[np.float64] | None:
        centres, rotations = [], []
        for k, i in known:
            uv = corners[k]
            X = self.corners_world[4 * i : 4 * i + 4]
            best = None
            for T in self.marker_pose_candidates(i, uv):
                res, depth = reprojection_residuals(self.K, T, X, uv)
                if not np.all(depth > 0):
                    continue
                score = float(np.sum(res**2)) / self.pixel_sigma**2
                if prior is not None:
                    score += prior_mahalanobis_sq(T, prior, self.prior_sigmas)
                if best is None or score < best[0]:
                    best = (score, T)
            if best is None:
                continue
            T = refine_pose(X, uv, self.K, best[1], max_iterations=10)[0]
            centres.append(camera_center(T))
            rotations.append(T[:3, :3].T)  # world_from_cam rotation
        if not centres:
            return None
        C = np.mean(centres, axis=0)
        R_wc = Rotation.from_matrix(np.array(rotations)).mean().as_matrix()
        return make_transform(R_wc.T, -R_wc.T @ C)
