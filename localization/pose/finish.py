"""Compiled kernel (numba) of the last step of a robust localization: its one pose, finished.

Once robust association has chosen its pairs, :meth:`localization.Localizer.localize` refines
the pose on them (:func:`localization.pose.pnp.refine_pose`), checks every landmark is in front of
the camera (:func:`localization.pose.pnp.reprojection_residuals`), computes the covariance
(:func:`localization.pose.covariance.pose_covariance`), the spread of the inlier detections across their
best-fit line (the edge-on test) and the distance from the prior
(:func:`localization.pose.covariance.prior_mahalanobis_sq`). Each is compiled, but each through a Python
wrapper that validates and converts its arguments: together some 60-90 us per frame, paid by
every agent at every step of a training env, more than a warm-started association itself.

:func:`finish_pose` runs the same kernels -- :func:`localization.pose.lm.lm_one` with
``refine_pose``'s iterations and tolerance, :func:`localization.geometry.kernels.residuals`,
:func:`~localization.pose.covariance.covariance`, :func:`~localization.geometry.kernels.minor_spread`,
:func:`~localization.pose.covariance.prior_distance_sq` -- in one call, so its answers are theirs
bit for bit (``tests/localization/pose/test_finish.py`` compares them). Compiled and cached
like :mod:`localization.pose.lm`.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from localization.geometry.kernels import center, minor_spread, residuals
from localization.pose.covariance import covariance, prior_distance_sq
from localization.pose.lm import lm_one

__all__ = ["finish_pose"]


@njit(cache=True, nogil=True)
def finish_pose(
    K: NDArray, T0: NDArray, landmarks: NDArray, det: NDArray, assignment: NDArray, pixel_sigma: float,
    prior_R: NDArray, prior_C: NDArray, sigmas: NDArray, iterations: int, tol: float,
) -> tuple[NDArray, float, bool, NDArray, float, bool, float]:
    """Refine ``T0`` on the assigned pairs and measure the result.

    Args:
        K: (3, 3) intrinsics.
        T0: (4, 4) ``cam_from_world`` to start from.
        landmarks: (M, 3) the model landmarks.
        det: (D, 2) the detections, pinhole pixels.
        assignment: (D,) the landmark of each detection, -1 for none; the pairs (N >= 1 of them)
            are taken in detection order, ``landmarks[assignment[m]]`` <-> ``det[m]``.
        pixel_sigma: the detector's noise, px (the covariance).
        prior_R: (3, 3) the prior's rotation.
        prior_C: (3,) the prior's camera centre.
        sigmas: (6,) the prior's sigmas (:meth:`localization.pose.covariance.PriorSigmas.as_array`).
        iterations: Levenberg-Marquardt steps (``refine_pose``'s ``10 * max_iterations``).
        tol: relative cost decrease below which the refinement stops (``refine_pose``'s).

    Returns:
        ``(T, rmse_px, in_front, covariance, prior_q, prior_far, spread_px)``: the refined pose,
        its RMSE (inf when a point is at or behind the camera), whether every point has positive
        depth, the (6, 6) covariance, the squared Mahalanobis distance from the prior and whether
        the rotation is near pi from the prior's (then recompute it exactly, as
        ``prior_mahalanobis_sq`` does), and the RMS distance of the paired detections from their
        best-fit line.
    """
    n = 0
    for i in range(assignment.shape[0]):
        if assignment[i] >= 0:
            n += 1
    X = np.empty((n, 3))
    uv = np.empty((n, 2))
    j = 0
    for i in range(assignment.shape[0]):
        if assignment[i] >= 0:
            X[j] = landmarks[assignment[i]]
            uv[j] = det[i]
            j += 1
    R = T0[:3, :3].copy()
    t = T0[:3, 3].copy()
    cost = lm_one(K, R, t, X, uv, np.ones(n), iterations, 0.0, tol)
    T = np.zeros((4, 4))
    T[:3, :3] = R
    T[:3, 3] = t
    T[3, 3] = 1.0
    rmse = np.sqrt(cost / max(n, 1))
    _, depth = residuals(K, T, X, uv)
    in_front = True
    for j in range(n):
        if not depth[j] > 0:
            in_front = False
    cov = covariance(K, R, center(T), X, pixel_sigma)
    q, far = prior_distance_sq(R, t, prior_R, prior_C, sigmas)
    return T, rmse, in_front, cov, q, far, minor_spread(uv)
