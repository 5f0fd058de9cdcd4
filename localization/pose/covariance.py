"""Pose uncertainty: the prior's sigmas, the covariance from the projections, Mahalanobis distances.

:class:`PriorSigmas` states the rough onboard pose's uncertainty; :func:`pose_covariance` is the
6x6 covariance of a PnP pose (Gauss-Newton: the inverse of ``J^T J / sigma^2`` of the
projections' Jacobian in ``(camera centre, rotation vector)``); :func:`pose_difference` and
:func:`prior_mahalanobis_sq` measure a pose against a reference in the same parameters. The
compiled kernels :func:`covariance` and :func:`prior_distance_sq` carry the arithmetic that
every localization (and every hypothesis of robust association) runs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from localization.geometry.kernels import kernel_array
from localization.geometry.transforms import camera_center, so3_log

__all__ = [
    "PriorSigmas",
    "covariance",
    "pose_covariance",
    "pose_difference",
    "pose_jacobian",
    "prior_distance_sq",
    "prior_mahalanobis_sq",
]


#: Information matrices whose column-scaled condition number exceeds this are singular.
MAX_CONDITION = 1e12


@njit(cache=True, nogil=True)
def prior_distance_sq(
    R: NDArray, t: NDArray, prior_R: NDArray, prior_C: NDArray, sigmas: NDArray
) -> tuple[float, bool]:
    """Squared Mahalanobis distance of ``cam_from_world`` (R, t) from a prior, and whether it is far.

    The pose difference of :func:`localization.pose.batch.pose_difference_many` (camera centre, then
    the world-frame rotation vector ``log(R_wc R_wc_prior^T)``) over ``sigmas`` (6,). ``far``:
    the rotation is within about 8 degrees of pi from the prior's, where the skew part loses the
    axis; the caller recomputes those with the exact logarithm.
    """
    # camera centre C = -R^T t
    d0 = -(R[0, 0] * t[0] + R[1, 0] * t[1] + R[2, 0] * t[2]) - prior_C[0]
    d1 = -(R[0, 1] * t[0] + R[1, 1] * t[1] + R[2, 1] * t[2]) - prior_C[1]
    d2 = -(R[0, 2] * t[0] + R[1, 2] * t[1] + R[2, 2] * t[2]) - prior_C[2]
    # Q = R^T prior_R (R_wc R_wc_prior^T), its rotation vector
    Q = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            Q[r, c] = R[0, r] * prior_R[0, c] + R[1, r] * prior_R[1, c] + R[2, r] * prior_R[2, c]
    w0 = Q[2, 1] - Q[1, 2]
    w1 = Q[0, 2] - Q[2, 0]
    w2 = Q[1, 0] - Q[0, 1]
    cos = min(max((Q[0, 0] + Q[1, 1] + Q[2, 2] - 1.0) / 2.0, -1.0), 1.0)
    s = 0.5 * np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    k = 0.5 if s < 1e-12 else np.arctan2(s, cos) / (2.0 * s)
    q = (d0 / sigmas[0]) ** 2 + (d1 / sigmas[1]) ** 2 + (d2 / sigmas[2]) ** 2
    q += (w0 * k / sigmas[3]) ** 2 + (w1 * k / sigmas[4]) ** 2 + (w2 * k / sigmas[5]) ** 2
    return q, cos <= -0.99


@njit(cache=True, nogil=True, error_model="numpy")
def covariance(K: NDArray, R: NDArray, C: NDArray, X: NDArray, pixel_sigma: float) -> NDArray:
    """6x6 covariance ``sigma^2 (J^T J)^-1`` of a pose in ``(C, dtheta)``; all inf when singular.

    Args:
        K: (3, 3) intrinsics.
        R: (3, 3) ``cam_from_world`` rotation.
        C: (3,) camera centre.
        X: (N, 3) landmarks.
        pixel_sigma: isotropic pixel noise, px.

    The Jacobian of :func:`localization.pose.covariance.pose_jacobian` (``p = R (X - C)``; ``dp/dC = -R``,
    ``dp/dtheta = R [X - C]x``) summed point by point into the information matrix ``J^T J``; the
    columns scaled to unit diagonal before judging the conditioning (position in m and angle in
    rad are not comparable); singular (all inf) when not finite or its condition number exceeds
    :data:`MAX_CONDITION`.
    """
    fx, s, fy = K[0, 0], K[0, 1], K[1, 1]
    info = np.zeros((6, 6))
    ju = np.empty(6)
    jv = np.empty(6)
    Rax = np.empty((3, 3))
    for i in range(X.shape[0]):
        a0, a1, a2 = X[i, 0] - C[0], X[i, 1] - C[1], X[i, 2] - C[2]
        x = R[0, 0] * a0 + R[0, 1] * a1 + R[0, 2] * a2
        y = R[1, 0] * a0 + R[1, 1] * a1 + R[1, 2] * a2
        z = R[2, 0] * a0 + R[2, 1] * a1 + R[2, 2] * a2
        # d(u, v) / dp: u row (pu0, pu1, pu2), v row (0, pv1, pv2)
        pu0, pu1, pu2 = fx / z, s / z, -(fx * x + s * y) / z**2
        pv1, pv2 = fy / z, -fy * y / z**2
        # dp/dtheta = R [a]x, whose columns are R (0, a2, -a1), R (-a2, 0, a0), R (a1, -a0, 0)
        for r in range(3):
            Rax[r, 0] = R[r, 1] * a2 - R[r, 2] * a1
            Rax[r, 1] = -R[r, 0] * a2 + R[r, 2] * a0
            Rax[r, 2] = R[r, 0] * a1 - R[r, 1] * a0
        for k in range(3):  # J = d(u, v)/dp [-R | R [a]x]
            ju[k] = -(pu0 * R[0, k] + pu1 * R[1, k] + pu2 * R[2, k])
            jv[k] = -(pv1 * R[1, k] + pv2 * R[2, k])
            ju[3 + k] = pu0 * Rax[0, k] + pu1 * Rax[1, k] + pu2 * Rax[2, k]
            jv[3 + k] = pv1 * Rax[1, k] + pv2 * Rax[2, k]
        for p in range(6):
            for q in range(6):
                info[p, q] += ju[p] * ju[q] + jv[p] * jv[q]
    out = np.full((6, 6), np.inf)
    if not np.all(np.isfinite(info)):
        return out
    d = np.empty(6)
    for p in range(6):
        d[p] = np.sqrt(max(info[p, p], 1e-300))
    scaled = np.empty((6, 6))
    for p in range(6):
        for q in range(6):
            scaled[p, q] = info[p, q] / (d[p] * d[q])
    if np.linalg.cond(scaled) > MAX_CONDITION:
        return out
    inv = np.linalg.inv(scaled)
    for p in range(6):
        for q in range(6):
            out[p, q] = pixel_sigma**2 * 0.5 * (inv[p, q] / (d[p] * d[q]) + inv[q, p] / (d[q] * d[p]))
    return out


@dataclass(frozen=True)
class PriorSigmas:
    """Standard deviations of the prior (onboard GNSS + attitude) pose error.

    Attributes:
        position_m: (3,) std of the camera position along project x, y, z, metres.
        rotation_rad: (3,) std of the rotation error about the project x, y (tilt: roll and pitch)
            and z (yaw) axes, radians. Defaults: the paper's 3 m and 2, 2, 5 degrees.
    """

    position_m: tuple[float, float, float] = (3.0, 3.0, 3.0)
    rotation_rad: tuple[float, float, float] = tuple(np.radians([2.0, 2.0, 5.0]).tolist())

    def as_array(self) -> NDArray[np.float64]:
        """(6,) sigmas in the package's pose parameterization ``(C, dtheta)``."""
        return np.array((*self.position_m, *self.rotation_rad), dtype=np.float64)


def pose_jacobian(
    K: ArrayLike, cam_from_world: ArrayLike, points_xyz: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Projection Jacobian ``(2N, 6)`` w.r.t. ``(C, dtheta)`` (module docstring) and the (N, 2) uv.

    Row ``2i`` is d u_i, row ``2i+1`` is d v_i.
    """
    K = np.asarray(K, dtype=np.float64)
    T = np.asarray(cam_from_world, dtype=np.float64)
    R_wc = T[:3, :3].T
    C = camera_center(T)
    X = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    return _jacobian(K, R_wc, C, X)


def _project(K: NDArray, R_wc: NDArray, C: NDArray, X: NDArray) -> tuple[NDArray, NDArray]:
    p = (X - C) @ R_wc  # rows: R_wc.T @ (X - C), camera frame
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * p[:, 0] / z + K[0, 1] * p[:, 1] / z + K[0, 2]
        v = K[1, 1] * p[:, 1] / z + K[1, 2]
    return np.column_stack([u, v]), p


def _jacobian(K: NDArray, R_wc: NDArray, C: NDArray, X: NDArray) -> tuple[NDArray, NDArray]:
    n = X.shape[0]
    uv, p = _project(K, R_wc, C, X)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    fx, fy, s = K[0, 0], K[1, 1], K[0, 1]
    # d(u, v) / d p_cam, (N, 2, 3)
    dproj = np.zeros((n, 2, 3))
    dproj[:, 0, 0] = fx / z
    dproj[:, 0, 1] = s / z
    dproj[:, 0, 2] = -(fx * x + s * y) / z**2
    dproj[:, 1, 1] = fy / z
    dproj[:, 1, 2] = -fy * y / z**2
    Rt = R_wc.T
    a = X - C
    # d p_cam / d dtheta = R_wc.T [a]x ;  d p_cam / d C = -R_wc.T
    ax = np.zeros((n, 3, 3))
    ax[:, 0, 1], ax[:, 0, 2] = -a[:, 2], a[:, 1]
    ax[:, 1, 0], ax[:, 1, 2] = a[:, 2], -a[:, 0]
    ax[:, 2, 0], ax[:, 2, 1] = -a[:, 1], a[:, 0]
    dp = np.empty((n, 3, 6))
    dp[:, :, :3] = -Rt
    dp[:, :, 3:] = Rt @ ax
    J = dproj @ dp  # (N, 2, 6)
    return J.reshape(2 * n, 6), uv


def pose_covariance(
    K: ArrayLike, cam_from_world: ArrayLike, points_xyz: ArrayLike, pixel_sigma: float = 1.0
) -> NDArray[np.float64]:
    """6x6 covariance ``sigma^2 (J^T J)^-1`` of the pose in ``(C, dtheta)`` (module docstring).

    This is the Cramér-Rao bound for isotropic Gaussian pixel noise of ``pixel_sigma`` px with
    known correspondences. Returns an all-inf matrix when the information is singular (fewer than
    three points, or a degenerate layout).
    """
    T = np.asarray(cam_from_world, dtype=np.float64)
    X = kernel_array(np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3))
    return covariance(  # compiled: the information matrix point by point (pose_jacobian's rows)
        kernel_array(K, dtype=np.float64), kernel_array(T[:3, :3]), camera_center(T), X,
        float(pixel_sigma),
    )


def pose_difference(cam_from_world: ArrayLike, reference_cam_from_world: ArrayLike) -> NDArray[np.float64]:
    """(6,) a pose minus a reference pose in the package's parameterization ``(C, dtheta)``.

    ``C`` (first 3): camera centre difference along project x, y, z [m]; ``dtheta`` (last 3): the
    world-frame rotation vector ``log(R_wc @ R_wc_ref.T)`` [rad] (module docstring).
    """
    T = np.asarray(cam_from_world, dtype=np.float64)
    P = np.asarray(reference_cam_from_world, dtype=np.float64)
    dC = camera_center(T) - camera_center(P)
    return np.concatenate([dC, so3_log(T[:3, :3].T @ P[:3, :3])])


def prior_mahalanobis_sq(
    cam_from_world: ArrayLike, prior_cam_from_world: ArrayLike, sigmas: PriorSigmas | None = None
) -> float:
    """Squared Mahalanobis distance of a pose from the prior, diagonal prior covariance.

    Position difference along project x, y, z; rotation difference as the world-frame rotation
    vector ``log(R_wc @ R_wc_prior.T)`` divided by ``sigmas.rotation_rad`` about x, y, z.
    """
    sig = (sigmas or PriorSigmas()).as_array()
    T = np.asarray(cam_from_world, dtype=np.float64)
    P = np.asarray(prior_cam_from_world, dtype=np.float64)
    q, far = prior_distance_sq(  # compiled; near pi from the prior's rotation the exact logarithm
        kernel_array(T[:3, :3]), kernel_array(T[:3, 3]), kernel_array(P[:3, :3]),
        camera_center(P), sig,
    )
    if far:
        return float(np.sum((pose_difference(T, P) / sig) ** 2))
    return float(q)
