"""Compiled kernels (numba) of the conventions: camera centre, inverse, residuals, transform check.

The small computations every localization repeats on one pose -- the camera centre, the rigid
inverse, reprojection residuals, the rigid-transform check under
:func:`localization.geometry.transforms.check_transform`, the quaternion of a rotation and the
spread of detections across their best-fit line (the edge-on test) -- as compiled loops with
the numpy code's arithmetic: on 3 x 3 and 6 x 6 arrays numpy's call overhead would be their
whole cost. This module imports nothing of the package, so the geometry at the bottom of the
layers can use it.

Kernels are compiled on first use and cached beside this file (``cache=True``; numba falls back
to a user cache folder where this one is read-only).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["camera_point", "center", "inverse", "kernel_array", "minor_spread", "quat_wxyz", "residuals",
           "transform_fault"]


def kernel_array(values, dtype=None) -> NDArray:
    """``values`` as every compiled kernel of the package takes an array: C-contiguous and writable.

    ``np.ascontiguousarray`` with the writable flag added: numba compiles a kernel once per
    argument type, and a read-only array (a site's landmarks are read-only) is another type than
    a writable one, so passed as it is it would compile every kernel it reaches a second time
    (seconds each, in a user's first frames). Copied only when it is not C-contiguous, of
    ``dtype`` (when given) and writable already.
    """
    out = np.ascontiguousarray(values, dtype=dtype)
    return out if out.flags.writeable else out.copy()


#: A point at or in front of this depth (m) counts as behind the camera.
MIN_DEPTH = 1e-6


@njit(cache=True, nogil=True)
def camera_point(R: NDArray, t: NDArray, X: NDArray, i: int) -> tuple[float, float, float]:
    """Camera-frame coordinates of point ``X[i]``."""
    x = R[0, 0] * X[i, 0] + R[0, 1] * X[i, 1] + R[0, 2] * X[i, 2] + t[0]
    y = R[1, 0] * X[i, 0] + R[1, 1] * X[i, 1] + R[1, 2] * X[i, 2] + t[1]
    z = R[2, 0] * X[i, 0] + R[2, 1] * X[i, 1] + R[2, 2] * X[i, 2] + t[2]
    return x, y, z


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

    :func:`localization.geometry.transforms.check_transform`'s tests, np.allclose's (``|a - b| <= atol +
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
def minor_spread(uv: NDArray) -> float:
    """RMS distance of points ``uv`` (N, 2) from their best-fit line (0 for fewer than 3).

    The smaller eigenvalue of the centred points' 2 x 2 scatter matrix, in closed form, over N
    (the localizer's edge-on test, :meth:`localization.Localizer.localize`).
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
def quat_wxyz(m: NDArray) -> NDArray:
    """Unit quaternion (w, x, y, z), ``w >= 0``, of a rotation ``m`` (3, 3) (Shepperd's method).

    ``localization.geometry.transforms.quat_wxyz_from_matrix``: from the largest of 4 w^2, 4 x^2, 4 y^2,
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
