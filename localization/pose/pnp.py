"""Stage 3, pose: 2D-3D correspondences in, ``cam_from_world`` out.

* Coplanar landmark sets go through IPPE (``cv2.SOLVEPNP_IPPE``). OpenCV 5.0.0 returns a wrong
  pose for about half of all point orderings when the plane is not z = 0 (docs/design.md, "Facts
  measured"), so the points are first expressed in their own plane frame (z = 0 there) and the
  pose is mapped back: ``cam_from_world = cam_from_plane @ plane_from_world``.
* Other sets go through SQPnP (``cv2.SOLVEPNP_SQPNP``).
* Each candidate keeps only poses with every point in front of the camera; the paper's rule picks
  the lowest reprojection RMSE and breaks ties with the prior camera position. The ``"prior"``
  rule instead scores ``n * rmse^2 / sigma^2 + prior Mahalanobis^2`` (used by robust association,
  where four coplanar points fit any assignment and only the prior can tell).
* The winner is refined by Levenberg-Marquardt on all inliers (own implementation, analytic
  Jacobian), which also gives the covariance.

Pose parameterization used for the Jacobian, the LM update and every 6x6 covariance in this
package: ``(C, dtheta)`` where ``C`` (first 3) is the camera centre in the project frame [m] and
``dtheta`` (last 3) a small rotation vector [rad] in the world frame perturbing ``world_from_cam``:
``R_world_from_cam' = exp([dtheta]x) @ R_world_from_cam``. So ``sqrt(diag(cov))[:3]`` are the
position standard deviations along the project x, y, z axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.failure import FailureCode
from localization.geometry.kernels import kernel_array, residuals
from localization.geometry.transforms import (
    as_points,
    camera_center,
    check_intrinsics,
    check_transform,
    invert,
    make_transform,
)
from localization.pose.batch import refine_many, to_transforms
from localization.pose.covariance import PriorSigmas, prior_mahalanobis_sq

__all__ = [
    "PnPResult",
    "is_collinear",
    "is_coplanar",
    "ippe_candidates",
    "plane_from_world",
    "planar_points",
    "pnp_candidates",
    "pose_from_rt",
    "refine_pose",
    "reprojection_residuals",
    "select_candidate",
    "solve_pnp",
]


@dataclass(frozen=True, eq=False)
class PnPResult:
    """Outcome of :func:`solve_pnp`.

    Attributes:
        success: a pose with every inlier in front of the camera was found.
        cam_from_world: (4, 4) the pose; the prior (or identity) when not successful.
        rmse_px: reprojection RMSE over the inliers, px (inf when not successful).
        inliers: (N,) bool mask of the correspondences used in the final refinement.
        failure_reason: why not, or None.
        failure_code: the :class:`~localization.failure.FailureCode` of ``failure_reason``.
        candidates: every candidate pose considered (before refinement).
    """

    success: bool
    cam_from_world: NDArray[np.float64]
    rmse_px: float
    inliers: NDArray[np.bool_]
    failure_reason: str | None = None
    candidates: tuple[NDArray[np.float64], ...] = field(default=(), repr=False)
    failure_code: FailureCode | None = field(default=None, kw_only=True)


def is_coplanar(points_xyz: ArrayLike, rel_tol: float = 1e-3) -> bool:
    """True when the points' out-of-plane spread is below ``rel_tol`` times their extent.

    Three or fewer points are always coplanar.
    """
    X = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    if X.shape[0] <= 3:
        return True
    s = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    return bool(s[0] > 0 and s[2] <= rel_tol * s[0])


def is_collinear(points_xyz: ArrayLike, rel_tol: float = 1e-3) -> bool:
    """True when the points' spread across their best-fit line is below ``rel_tol`` x their extent.

    Two or fewer points, or all in one place, are always collinear. A pose from collinear
    landmarks is undetermined: any rotation about the line fits them.
    """
    X = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    if X.shape[0] <= 2:
        return True
    s = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    return bool(s[1] <= rel_tol * s[0])


def plane_from_world(points_xyz: ArrayLike) -> NDArray[np.float64]:
    """4x4 rigid ``plane_from_world``: z = 0 is the best-fit plane, origin at the centroid."""
    X = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    centroid = X.mean(axis=0)
    _, _, vt = np.linalg.svd(X - centroid)
    e1, e2 = vt[0], vt[1]
    n = np.cross(e1, e2)
    world_from_plane = make_transform(np.column_stack([e1, e2, n]), centroid)
    return invert(world_from_plane)


def reprojection_residuals(
    K: ArrayLike, cam_from_world: ArrayLike, points_xyz: ArrayLike, uv: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(residuals (N, 2) = projected - observed, depth (N,))`` of correspondences."""
    f64 = np.float64
    K, T = kernel_array(K, dtype=f64), kernel_array(cam_from_world, dtype=f64)
    X = kernel_array(np.asarray(points_xyz, dtype=f64).reshape(-1, 3))
    u = kernel_array(np.asarray(uv, dtype=f64).reshape(-1, 2))
    if K.shape != (3, 3) or T.shape != (4, 4) or X.shape[0] != u.shape[0]:
        raise ValueError(
            f"reprojection_residuals needs a 3x3 K, a 4x4 pose and as many points as pixels; got K "
            f"{K.shape}, pose {T.shape}, {X.shape[0]} points and {u.shape[0]} pixels"
        )
    return residuals(K, T, X, u)  # compiled: the projection of pose_jacobian, one loop


def _as_cv(points: NDArray) -> NDArray:
    return kernel_array(points, dtype=np.float64).reshape(-1, 1, points.shape[1])


def pose_from_rt(rvec: NDArray, tvec: NDArray) -> NDArray:
    """(4, 4) ``cam_from_world`` of OpenCV's rotation vector and translation (``solvePnP``'s output)."""
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    return make_transform(R, np.asarray(tvec, dtype=np.float64).reshape(3))


def planar_points(points_xyz: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(plane_from_world (4, 4), points (N, 3) in that frame with z = 0)`` of coplanar points.

    The frame of :func:`plane_from_world`; z is set to exactly 0 (the OpenCV 5 IPPE workaround).
    """
    X = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    p_from_w = plane_from_world(X)
    Xp = (X @ p_from_w[:3, :3].T + p_from_w[:3, 3]).copy()
    Xp[:, 2] = 0.0
    return p_from_w, Xp


def ippe_candidates(plane_xy: ArrayLike, uv: ArrayLike, K: ArrayLike,
                    plane_from_world_: ArrayLike) -> list[NDArray[np.float64]]:
    """Candidate ``cam_from_world`` poses (unrefined) from IPPE of points given in their plane's frame.

    ``plane_xy`` (N, 3) with z = 0 and ``plane_from_world_`` as :func:`planar_points` returns them
    (one frame serves every ordering of the same points); at least 4 points; [] when the solver
    fails.
    """
    Xp = np.asarray(plane_xy, dtype=np.float64).reshape(-1, 3)
    if Xp.shape[0] < 4:
        return []
    return _generic(Xp, uv, K, cv2.SOLVEPNP_IPPE, np.asarray(plane_from_world_, dtype=np.float64))


def pnp_candidates(
    points_xyz: ArrayLike, uv: ArrayLike, K: ArrayLike, coplanar: bool | None = None
) -> list[NDArray[np.float64]]:
    """Candidate ``cam_from_world`` poses (unrefined) from IPPE (coplanar) or SQPnP.

    Needs at least 4 coplanar or 3 non-coplanar points; returns [] when the solver fails.
    """
    X = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    if coplanar is None:
        coplanar = is_coplanar(X)
    if coplanar:
        if X.shape[0] < 4:
            return []
        p_from_w, Xp = planar_points(X)
        return ippe_candidates(Xp, uv, K, p_from_w)
    if X.shape[0] < 3:
        return []
    return _generic(X, uv, K, cv2.SOLVEPNP_SQPNP, None)


def _generic(X: NDArray, uv: ArrayLike, K: ArrayLike, flag: int,
             frame_from_world: NDArray[np.float64] | None) -> list[NDArray[np.float64]]:
    """The finite poses of ``cv2.solvePnPGeneric`` (``flag``) of ``X`` given in a frame (None: the world)."""
    u = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    try:
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(_as_cv(X), _as_cv(u), np.asarray(K, dtype=np.float64), None,
                                                 flags=flag)
    except cv2.error:
        return []
    out = [pose_from_rt(r, t) for r, t in zip(rvecs[:n], tvecs[:n], strict=True)]
    if frame_from_world is not None:
        out = [T @ frame_from_world for T in out]
    return [T for T in out if np.all(np.isfinite(T))]


def refine_pose(
    points_xyz: ArrayLike,
    uv: ArrayLike,
    K: ArrayLike,
    cam_from_world: ArrayLike,
    max_iterations: int = 20,
    tol: float = 1e-8,
) -> tuple[NDArray[np.float64], float]:
    """Levenberg-Marquardt refinement of the reprojection error; returns ``(pose, rmse_px)``.

    Compiled (:func:`localization.pose.batch.refine_many` on one pose): up to ``max_iterations`` accepted
    steps (with up to ten damping increases each), stopping when the relative cost decrease falls
    below ``tol``. ``rmse_px`` is inf when the refined pose puts a point at or behind the camera.
    """
    X = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    u = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    K = np.asarray(K, dtype=np.float64)
    T = np.asarray(cam_from_world, dtype=np.float64)
    if X.shape[0] != u.shape[0] or K.shape != (3, 3) or T.shape != (4, 4):
        raise ValueError(
            f"refine_pose needs (N, 3) points, (N, 2) pixels, a 3x3 K and a 4x4 pose; got "
            f"{X.shape[0]} points, {u.shape[0]} pixels, K {K.shape}, pose {T.shape}"
        )
    R, t, cost = refine_many(
        K, T[None, :3, :3], T[None, :3, 3], X[None], u[None], np.ones((1, X.shape[0]), dtype=bool),
        iterations=10 * int(max_iterations), tol=tol,
    )
    return to_transforms(R, t)[0], float(np.sqrt(cost[0] / max(X.shape[0], 1)))


def _rmse_and_depth_ok(K: NDArray, T: NDArray, X: NDArray, u: NDArray) -> tuple[float, bool]:
    res, depth = reprojection_residuals(K, T, X, u)
    ok = bool(np.all(depth > 0))
    rmse = float(np.sqrt(np.mean(np.sum(res**2, axis=1)))) if X.shape[0] else np.inf
    return (rmse if np.isfinite(rmse) else np.inf), ok


def select_candidate(
    candidates: list[NDArray[np.float64]],
    points_xyz: ArrayLike,
    uv: ArrayLike,
    K: ArrayLike,
    prior_cam_from_world: ArrayLike | None = None,
    rule: str = "paper",
    tie_px: float = 0.5,
    pixel_sigma: float = 1.0,
    prior_sigmas: PriorSigmas | None = None,
) -> int | None:
    """Index of the chosen candidate, or None when none has every point in front of the camera.

    ``rule="paper"``: lowest RMSE; candidates within ``tie_px`` of it are a tie, broken by the
    distance of the camera centre to the prior's. ``rule="prior"``: lowest
    ``n * rmse^2 / pixel_sigma^2 + prior_mahalanobis_sq``.
    """
    X = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    u = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    K = np.asarray(K, dtype=np.float64)
    scored = []
    for i, T in enumerate(candidates):
        rmse, ok = _rmse_and_depth_ok(K, T, X, u)
        if ok and np.isfinite(rmse):
            scored.append((i, rmse))
    if not scored:
        return None
    if prior_cam_from_world is None:
        return min(scored, key=lambda s: s[1])[0]
    if rule == "prior":
        n = X.shape[0]
        return min(
            scored,
            key=lambda s: (
                n * s[1] ** 2 / pixel_sigma**2
                + prior_mahalanobis_sq(candidates[s[0]], prior_cam_from_world, prior_sigmas)
            ),
        )[0]
    if rule != "paper":
        raise ValueError(f"rule must be 'paper' or 'prior', got {rule!r}")
    best = min(s[1] for s in scored)
    tied = [s for s in scored if s[1] <= best + tie_px]
    C0 = camera_center(prior_cam_from_world)
    return min(tied, key=lambda s: float(np.linalg.norm(camera_center(candidates[s[0]]) - C0)))[0]


def solve_pnp(
    points_xyz: ArrayLike,
    uv: ArrayLike,
    K: ArrayLike,
    prior_cam_from_world: ArrayLike | None = None,
    *,
    rule: str = "paper",
    refine: bool = True,
    min_points: int = 4,
    pixel_sigma: float = 1.0,
    prior_sigmas: PriorSigmas | None = None,
    ransac: bool = False,
    ransac_threshold_px: float = 8.0,
    tie_px: float = 0.5,
) -> PnPResult:
    """Pose from correspondences: IPPE (coplanar, plane-frame workaround) or SQPnP, then LM.

    Args:
        points_xyz: (N, 3) model points, project frame, metres.
        uv: (N, 2) their pixel observations.
        K: (3, 3) intrinsics.
        prior_cam_from_world: (4, 4) rough pose breaking candidate ties (optional).
        rule: candidate choice, ``"paper"`` or ``"prior"`` (see :func:`select_candidate`).
        refine: run LM on the inliers.
        min_points: fewer correspondences fail (at least 4 recommended; never below 3).
        pixel_sigma: pixel noise used by the ``"prior"`` rule.
        prior_sigmas: prior uncertainty used by the ``"prior"`` rule.
        ransac: with at least 6 points, first reject outliers with ``cv2.solvePnPRansac``
            (AP3P minimal solver, ``ransac_threshold_px``).
        ransac_threshold_px: RANSAC inlier threshold, px.
        tie_px: RMSE tolerance of a tie under the ``"paper"`` rule.

    Returns:
        A :class:`PnPResult`; never raises on degenerate geometry.

    Raises:
        TypeError, ValueError: on arrays of the wrong type or shape.
    """
    X = as_points("points_xyz", points_xyz, 3)
    u = as_points("uv", uv, 2)
    K = check_intrinsics("K", K)
    if X.shape[0] != u.shape[0]:
        raise ValueError(
            f"points_xyz and uv must have the same length, got {X.shape[0]} and {u.shape[0]}"
        )
    prior = (
        None
        if prior_cam_from_world is None
        else check_transform("prior_cam_from_world", prior_cam_from_world)
    )
    fallback = prior if prior is not None else np.eye(4)
    n = X.shape[0]
    inliers = np.ones(n, dtype=bool)
    inliers &= np.isfinite(X).all(axis=1) & np.isfinite(u).all(axis=1)
    need = max(min_points, 3)
    if inliers.sum() < need:
        return _failed(
            fallback,
            n,
            FailureCode.TOO_FEW_CORRESPONDENCES,
            f"too few correspondences: {int(inliers.sum())} usable, need {need}",
        )
    if ransac and inliers.sum() >= 6:
        inliers = _ransac_inliers(X, u, K, inliers, need, ransac_threshold_px)
    Xi, ui = X[inliers], u[inliers]
    if is_collinear(Xi):
        return _failed(
            fallback,
            n,
            FailureCode.DEGENERATE_GEOMETRY,
            f"degenerate geometry: the {Xi.shape[0]} landmarks lie on a line, so any rotation "
            "about it fits them",
        )
    cands = pnp_candidates(Xi, ui, K, coplanar=is_coplanar(Xi))
    if not cands:
        return _failed(fallback, n, FailureCode.PNP_FAILED, "PnP solver found no pose (degenerate layout)")
    k = select_candidate(
        cands, Xi, ui, K, prior, rule=rule, tie_px=tie_px, pixel_sigma=pixel_sigma, prior_sigmas=prior_sigmas
    )
    if k is None:
        return _failed(
            fallback, n, FailureCode.BEHIND_CAMERA, "every PnP candidate puts landmarks behind the camera"
        )
    T = cands[k]
    if refine:
        T, _ = refine_pose(Xi, ui, K, T)
    rmse, ok = _rmse_and_depth_ok(K, T, Xi, ui)
    if not ok or not np.isfinite(rmse):
        return _failed(
            fallback, n, FailureCode.BEHIND_CAMERA, "refined pose puts landmarks behind the camera"
        )
    return PnPResult(True, T, rmse, inliers, None, tuple(cands))


def _failed(fallback: NDArray[np.float64], n: int, code: FailureCode, reason: str) -> PnPResult:
    """The failed :class:`PnPResult` of ``n`` correspondences: ``fallback``'s pose, no inliers."""
    return PnPResult(False, fallback.copy(), np.inf, np.zeros(n, dtype=bool), reason, failure_code=code)


def _ransac_inliers(
    X: NDArray[np.float64],
    u: NDArray[np.float64],
    K: NDArray[np.float64],
    usable: NDArray[np.bool_],
    need: int,
    threshold_px: float,
) -> NDArray[np.bool_]:
    """The (N,) inliers of ``cv2.solvePnPRansac`` (AP3P) among the ``usable`` pairs.

    ``usable`` itself when RANSAC fails or keeps fewer than ``need`` pairs.
    """
    idx = np.flatnonzero(usable)
    try:
        ok, _, _, ransac_in = cv2.solvePnPRansac(
            _as_cv(X[idx]),
            _as_cv(u[idx]),
            K,
            None,
            reprojectionError=float(threshold_px),
            iterationsCount=100,
            flags=cv2.SOLVEPNP_AP3P,
        )
    except cv2.error:
        ok, ransac_in = False, None
    if not (ok and ransac_in is not None and len(ransac_in) >= need):
        return usable
    keep = np.zeros(X.shape[0], dtype=bool)
    keep[idx[np.asarray(ransac_in).reshape(-1)]] = True
    return keep
