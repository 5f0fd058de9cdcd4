"""Compiled kernels (numba) of the per-frame pose steps: the distance from the prior, the covariance.

Also the rigid-transform check under :func:`localization.geometry.check_transform`
(:func:`transform_fault`) and the camera centre, inverse and reprojection residuals under
:func:`~localization.geometry.camera_center`, :func:`~localization.geometry.invert` and
:func:`localization.pnp.reprojection_residuals` (:func:`center`, :func:`inverse`,
:func:`residuals`: 2-4 us of numpy each, called some fifteen times per localization; the numpy
code's ``-R.T @ t`` went through BLAS, so the loops here agree with it to rounding, not bit for
bit). This module imports nothing of the package, so the geometry module at the bottom of the
layers can use it.

Every localization ends with a few small computations on its one pose -- its squared Mahalanobis
distance from the prior (:func:`localization.pnp.prior_mahalanobis_sq`), its covariance from
the Jacobian of the projections (:func:`localization.pnp.pose_covariance`) and the spread of its
detections across their best-fit line (:func:`minor_spread`, the edge-on test); and what every
agent's info reports of it -- its error against the truth (:func:`pose_error`) and its
orientation as a quaternion (:func:`quat_wxyz`). As numpy code they
were 50-180 microseconds each, of call overhead on 3 x 3 and 6 x 6 arrays, paid by every agent at
every step of a training env. Here each is one compiled function with the numpy code's
arithmetic; :func:`prior_distance_sq` also scores robust association's hypotheses
(:func:`localization.compiled_scores.check_many`). Compiled and cached like
:mod:`localization.compiled`.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = [
    "center",
    "covariance",
    "inverse",
    "minor_spread",
    "pose_error",
    "prior_distance_sq",
    "quat_wxyz",
    "residuals",
    "transform_fault",
]

#: Information matrices whose column-scaled condition number exceeds this are singular.
MAX_CONDITION = 1e12

#: :func:`transform_fault`'s answers.
TRANSFORM_OK, TRANSFORM_NOT_FINITE, TRANSFORM_LAST_ROW, TRANSFORM_NOT_ROTATION = 0, 1, 2, 3


@njit(cache=True, nogil=True)
def center(T: NDArray) -> NDArray:
    """Camera centre ``-R^T t`` (3,) of a ``cam_from_world`` ``T`` (4, 4) (``geometry.camera_center``)."""
    out = np.empty(3)
    for c in range(3):
        s = 0.0
        for k in range(3):
            s += -T[k, c] * T[k, 3]
        out[c] = s
    return out


@njit(cache=True, nogil=True)
def inverse(T: NDArray) -> NDArray:
    """The exact inverse ``[R^T, -R^T t]`` (4, 4) of a rigid transform ``T`` (``geometry.invert``)."""
    out = np.zeros((4, 4))
    for r in range(3):
        s = 0.0
        for k in range(3):
            out[r, k] = T[k, r]
            s += -T[k, r] * T[k, 3]
        out[r, 3] = s
    out[3, 3] = 1.0
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def residuals(K: NDArray, T: NDArray, X: NDArray, uv: NDArray) -> tuple[NDArray, NDArray]:
    """``(projected - observed (N, 2), depth (N,))`` of points ``X`` (N, 3) seen at pixels ``uv``.

    ``pnp.reprojection_residuals``: each point in the camera frame as ``R (X - C)``, projected
    through ``K``; a point at depth 0 gives inf / NaN, as numpy's division does.
    """
    C = center(T)
    n = X.shape[0]
    res = np.empty((n, 2))
    depth = np.empty(n)
    for j in range(n):
        a0, a1, a2 = X[j, 0] - C[0], X[j, 1] - C[1], X[j, 2] - C[2]
        x = a0 * T[0, 0] + a1 * T[0, 1] + a2 * T[0, 2]
        y = a0 * T[1, 0] + a1 * T[1, 1] + a2 * T[1, 2]
        z = a0 * T[2, 0] + a1 * T[2, 1] + a2 * T[2, 2]
        res[j, 0] = K[0, 0] * x / z + K[0, 1] * y / z + K[0, 2] - uv[j, 0]
        res[j, 1] = K[1, 1] * y / z + K[1, 2] - uv[j, 1]
        depth[j] = z
    return res, depth


@njit(cache=True, nogil=True)
def transform_fault(T: NDArray) -> int:
    """What is wrong with a float64 (4, 4) ``T`` as a rigid transform: one of the ``TRANSFORM_*`` codes.

    :func:`localization.geometry.check_transform`'s tests, np.allclose's (``|a - b| <= atol +
    rtol |b|``, rtol 1e-5): every entry finite; the last row ``[0, 0, 0, 1]`` (atol 1e-9); the
    rotation block orthonormal (``R^T R = I``, atol 1e-6) with a non-negative determinant.
    """
    for i in range(4):
        for j in range(4):
            if not np.isfinite(T[i, j]):
                return TRANSFORM_NOT_FINITE
    for j in range(3):
        if abs(T[3, j]) > 1e-9:
            return TRANSFORM_LAST_ROW
    if abs(T[3, 3] - 1.0) > 1e-9 + 1e-5:
        return TRANSFORM_LAST_ROW
    for r in range(3):
        for c in range(3):
            g = T[0, r] * T[0, c] + T[1, r] * T[1, c] + T[2, r] * T[2, c]
            if (abs(g - 1.0) > 1e-6 + 1e-5) if r == c else (abs(g) > 1e-6):
                return TRANSFORM_NOT_ROTATION
    a, b, c = T[0, 0], T[0, 1], T[0, 2]
    d, e, f = T[1, 0], T[1, 1], T[1, 2]
    g, h, i = T[2, 0], T[2, 1], T[2, 2]
    if a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) < 0:
        return TRANSFORM_NOT_ROTATION
    return TRANSFORM_OK


@njit(cache=True, nogil=True)
def prior_distance_sq(
    R: NDArray, t: NDArray, prior_R: NDArray, prior_C: NDArray, sigmas: NDArray
) -> tuple[float, bool]:
    """Squared Mahalanobis distance of ``cam_from_world`` (R, t) from a prior, and whether it is far.

    The pose difference of :func:`localization.batch.pose_difference_many` (camera centre, then
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

    The Jacobian of :func:`localization.pnp.pose_jacobian` (``p = R (X - C)``; ``dp/dC = -R``,
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


@njit(cache=True, nogil=True)
def minor_spread(uv: NDArray) -> float:
    """RMS distance of points ``uv`` (N, 2) from their best-fit line (0 for fewer than 3).

    The smaller eigenvalue of the centred points' 2 x 2 scatter matrix, in closed form, over N
    (``localization.pipeline._minor_spread_px``).
    """
    n = uv.shape[0]
    if n < 3:
        return 0.0
    mu = 0.0
    mv = 0.0
    for i in range(n):
        mu += uv[i, 0]
        mv += uv[i, 1]
    mu /= n
    mv /= n
    a = 0.0
    b = 0.0
    c = 0.0
    for i in range(n):
        du = uv[i, 0] - mu
        dv = uv[i, 1] - mv
        a += du * du
        b += du * dv
        c += dv * dv
    smaller = 0.5 * (a + c) - np.hypot(0.5 * (a - c), b)
    return np.sqrt(max(smaller, 0.0) / n)


@njit(cache=True, nogil=True)
def pose_error(est: NDArray, gt: NDArray) -> tuple[float, float]:
    """``(camera-centre distance, rotation angle in degrees)`` of two ``cam_from_world`` (4, 4).

    ``localization.metrics.pose_errors``: the centres ``-R^T t``, and the geodesic angle
    ``acos((trace(R_est^T R_gt) - 1) / 2)`` with the cosine clipped to [-1, 1].
    """
    c_est = center(est)
    c_gt = center(gt)
    d = 0.0
    for k in range(3):
        d += (c_est[k] - c_gt[k]) ** 2
    tr = 0.0
    for r in range(3):
        for c in range(3):
            tr += est[r, c] * gt[r, c]
    cos = min(max((tr - 1.0) / 2.0, -1.0), 1.0)
    return np.sqrt(d), np.degrees(np.arccos(cos))


@njit(cache=True, nogil=True)
def quat_wxyz(m: NDArray) -> NDArray:
    """Unit quaternion (w, x, y, z), ``w >= 0``, of a rotation ``m`` (3, 3) (Shepperd's method).

    ``localization.geometry.quat_wxyz_from_matrix``: from the largest of 4 w^2, 4 x^2, 4 y^2,
    4 z^2 (the best conditioned; the first of equals), then normalized.
    """
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    k = 0
    best = tr
    for j in range(3):
        if m[j, j] > best:
            best = m[j, j]
            k = j + 1
    q = np.empty(4)
    if k == 0:
        s = 2.0 * np.sqrt(max(1.0 + tr, 0.0))
        q[0] = 0.25 * s
        q[1] = (m[2, 1] - m[1, 2]) / s
        q[2] = (m[0, 2] - m[2, 0]) / s
        q[3] = (m[1, 0] - m[0, 1]) / s
    elif k == 1:
        s = 2.0 * np.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 0.0))
        q[0] = (m[2, 1] - m[1, 2]) / s
        q[1] = 0.25 * s
        q[2] = (m[0, 1] + m[1, 0]) / s
        q[3] = (m[0, 2] + m[2, 0]) / s
    elif k == 2:
        s = 2.0 * np.sqrt(max(1.0 - m[0, 0] + m[1, 1] - m[2, 2], 0.0))
        q[0] = (m[0, 2] - m[2, 0]) / s
        q[1] = (m[0, 1] + m[1, 0]) / s
        q[2] = 0.25 * s
        q[3] = (m[1, 2] + m[2, 1]) / s
    else:
        s = 2.0 * np.sqrt(max(1.0 - m[0, 0] - m[1, 1] + m[2, 2], 0.0))
        q[0] = (m[1, 0] - m[0, 1]) / s
        q[1] = (m[0, 2] + m[2, 0]) / s
        q[2] = (m[1, 2] + m[2, 1]) / s
        q[3] = 0.25 * s
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sign = 1.0 if q[0] / n >= 0 else -1.0
    for j in range(4):
        q[j] = sign * q[j] / n
    return q
