"""The last step of a robust localization: its one pose, refined, checked and measured in one call.

Once robust association has chosen its pairs, :meth:`localization.Localizer.localize` refines
the pose on them (:func:`localization.pose.pnp.refine_pose`), checks every landmark is in front of
the camera (:func:`localization.pose.pnp.reprojection_residuals`), computes the covariance
(:func:`localization.pose.covariance.pose_covariance`), the spread of the inlier detections across
their best-fit line (the edge-on test) and the distance from the prior
(:func:`localization.pose.covariance.prior_mahalanobis_sq`). Each of those is compiled, but each
behind a Python wrapper that validates and converts its arguments, and together the wrappers
would cost more than a warm-started association, on every agent at every step of a training env.

:func:`finish_pose` takes a :class:`FinishInputs` and runs the same kernels --
:func:`localization.pose.lm.lm_one` with ``refine_pose``'s iterations and tolerance,
:func:`localization.geometry.kernels.residuals`, :func:`~localization.pose.covariance.covariance`,
:func:`~localization.geometry.kernels.minor_spread`,
:func:`~localization.pose.covariance.prior_distance_sq` -- in one compiled call
(:func:`finish_kernel`), so its answers are theirs bit for bit
(``tests/localization/pose/test_finish.py`` compares them); it returns a :class:`FinishedPose`.
Compiled and cached like :mod:`localization.pose.lm`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from localization.geometry.kernels import center, kernel_array, minor_spread, residuals
from localization.geometry.transforms import camera_center
from localization.pose.covariance import PriorSigmas, covariance, prior_distance_sq, prior_mahalanobis_sq
from localization.pose.lm import lm_one

__all__ = ["REFINE_ITERATIONS", "REFINE_TOL", "FinishInputs", "FinishedPose", "finish_kernel", "finish_pose"]


#: Levenberg-Marquardt steps of the refinement: ``refine_pose``'s ``10 * max_iterations`` (20).
REFINE_ITERATIONS = 200


#: Relative cost decrease below which the refinement stops (``refine_pose``'s ``tol``).
REFINE_TOL = 1e-8


@dataclass(frozen=True, eq=False)
class FinishInputs:
    """One pose to finish: the chosen pairs, the pose to start from and the prior to measure against.

    Attributes:
        K: (3, 3) intrinsics, float64.
        start_cam_from_world: (4, 4) the association's ``cam_from_world`` to refine.
        landmarks_xyz: (M, 3) the model landmarks, project frame, metres.
        detections_uv: (D, 2) the detections, pinhole pixels.
        assignment: (D,) int64, the landmark of each detection, -1 for none; the pairs (at least
            one) are taken in detection order, ``landmarks_xyz[assignment[m]]`` <-> ``detections_uv[m]``.
        pixel_sigma: the detector's noise, px (the covariance).
        prior_cam_from_world: (4, 4) the frame's prior pose.
        prior_sigmas: the prior's uncertainty.
        iterations: Levenberg-Marquardt steps.
        tol: relative cost decrease below which the refinement stops.
    """

    K: NDArray[np.float64]
    start_cam_from_world: NDArray[np.float64]
    landmarks_xyz: NDArray[np.float64]
    detections_uv: NDArray[np.float64]
    assignment: NDArray[np.int64]
    pixel_sigma: float
    prior_cam_from_world: NDArray[np.float64]
    prior_sigmas: PriorSigmas
    iterations: int = REFINE_ITERATIONS
    tol: float = REFINE_TOL


@dataclass(frozen=True, eq=False)
class FinishedPose:
    """A refined pose and its measures.

    Attributes:
        cam_from_world: (4, 4) the refined pose.
        rmse_px: reprojection RMSE over the pairs, px (inf when a point is at or behind the camera).
        in_front: every paired landmark has positive depth at the refined pose.
        covariance: (6, 6) pose covariance in ``(C [m], dtheta [rad])`` (:mod:`localization.pose.pnp`),
            all inf when singular.
        prior_mahalanobis_sq: squared Mahalanobis distance of the pose from the prior (6 dof,
            dimensionless), exactly as :func:`~localization.pose.covariance.prior_mahalanobis_sq`
            gives it.
        spread_px: RMS distance of the paired detections from their best-fit line, px.
    """

    cam_from_world: NDArray[np.float64]
    rmse_px: float
    in_front: bool
    covariance: NDArray[np.float64]
    prior_mahalanobis_sq: float
    spread_px: float


def finish_pose(inputs: FinishInputs) -> FinishedPose:
    """Refine ``inputs.start_cam_from_world`` on the assigned pairs and measure the result.

    One call of :func:`finish_kernel`; when the refined rotation is near pi from the prior's, the
    distance from the prior is taken again with the exact logarithm, as ``prior_mahalanobis_sq``
    does.
    """
    prior = inputs.prior_cam_from_world
    T, rmse, in_front, cov, q, far, spread = finish_kernel(
        inputs.K, inputs.start_cam_from_world, inputs.landmarks_xyz, inputs.detections_uv,
        inputs.assignment, inputs.pixel_sigma, kernel_array(prior[:3, :3]), camera_center(prior),
        inputs.prior_sigmas.as_array(), inputs.iterations, inputs.tol,
    )
    if far:
        q = prior_mahalanobis_sq(T, prior, inputs.prior_sigmas)
    return FinishedPose(T, rmse, in_front, cov, q, spread)


@njit(cache=True, nogil=True)
def finish_kernel(
    K: NDArray, T0: NDArray, landmarks: NDArray, det: NDArray, assignment: NDArray, pixel_sigma: float,
    prior_R: NDArray, prior_C: NDArray, sigmas: NDArray, iterations: int, tol: float,
) -> tuple[NDArray, float, bool, NDArray, float, bool, float]:
    """The compiled body of :func:`finish_pose`.

    Args:
        K: (3, 3) intrinsics.
        T0: (4, 4) ``cam_from_world`` to start from.
        landmarks: (M, 3) the model landmarks, m.
        det: (D, 2) the detections, pinhole pixels.
        assignment: (D,) the landmark of each detection, -1 for none; the pairs (N >= 1 of them)
            are taken in detection order, ``landmarks[assignment[m]]`` <-> ``det[m]``.
        pixel_sigma: the detector's noise, px (the covariance).
        prior_R: (3, 3) the prior's rotation.
        prior_C: (3,) the prior's camera centre, m.
        sigmas: (6,) the prior's sigmas (:meth:`localization.pose.covariance.PriorSigmas.as_array`).
        iterations: Levenberg-Marquardt steps.
        tol: relative cost decrease below which the refinement stops.

    Returns:
        ``(T, rmse_px, in_front, covariance, prior_q, prior_far, spread_px)``: as
        :class:`FinishedPose`, except that ``prior_q`` is the kernel's distance and ``prior_far``
        says the rotation is near pi from the prior's (then recompute it exactly).
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
