"""Compiled Levenberg-Marquardt (numba) on one pose or many: the refinement step of PnP and association.

:func:`lm_one` refines one ``cam_from_world`` (``R``, ``t``) on weighted correspondences (normal
equations accumulated point by point, the damped 6x6 system solved by Cholesky, Cauchy weights
when ``robust_sq`` > 0); :func:`lm_many` runs it over a stack of poses
(:func:`localization.pose.batch.refine_many`). The update perturbs the camera frame,
``R' = exp([w]x) R``, ``t' = exp([w]x) t + d``. Compiled and cached like
:mod:`localization.geometry.kernels`.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from localization.geometry.kernels import MIN_DEPTH, camera_point

__all__ = ["lm_many", "lm_one"]


@njit(cache=True, nogil=True)
def _exp(w0: float, w1: float, w2: float, out: NDArray) -> None:
    """Rodrigues' rotation of the rotation vector ``w`` into ``out`` (3, 3); series near zero."""
    th2 = w0 * w0 + w1 * w1 + w2 * w2
    th = np.sqrt(th2)
    if th < 1e-4:
        a = 1.0 - th2 / 6.0
        b = 0.5 - th2 / 24.0
    else:
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / th2
    # I + a [w]x + b [w]x^2, with [w]x^2 = w w^T - |w|^2 I
    out[0, 0] = 1.0 + b * (w0 * w0 - th2)
    out[1, 1] = 1.0 + b * (w1 * w1 - th2)
    out[2, 2] = 1.0 + b * (w2 * w2 - th2)
    out[0, 1] = -a * w2 + b * w0 * w1
    out[1, 0] = a * w2 + b * w0 * w1
    out[0, 2] = a * w1 + b * w0 * w2
    out[2, 0] = -a * w1 + b * w0 * w2
    out[1, 2] = -a * w0 + b * w1 * w2
    out[2, 1] = a * w0 + b * w1 * w2


@njit(cache=True, nogil=True)
def _residual(K: NDArray, x: float, y: float, z: float, u: float, v: float) -> tuple[float, float]:
    """Reprojection residual (projected minus measured) of a camera-frame point in front."""
    return (K[0, 0] * x + K[0, 1] * y) / z + K[0, 2] - u, K[1, 1] * y / z + K[1, 2] - v


@njit(cache=True, nogil=True)
def _weights(
    K: NDArray, R: NDArray, t: NDArray, X: NDArray, uv: NDArray, w0: NDArray, robust_sq: float,
    out: NDArray,
) -> None:
    """This step's weights into ``out``.

    ``w0``, but 0 for points at or behind the camera and, with ``robust_sq > 0``, Cauchy weights
    ``w0 / (1 + |r|^2 / robust_sq)`` of the residuals at the pose.
    """
    for i in range(X.shape[0]):
        out[i] = 0.0
        if w0[i] == 0.0:
            continue
        x, y, z = camera_point(R, t, X, i)
        if not z > MIN_DEPTH:
            continue
        if robust_sq > 0.0:
            ru, rv = _residual(K, x, y, z, uv[i, 0], uv[i, 1])
            out[i] = w0[i] / (1.0 + (ru * ru + rv * rv) / robust_sq)
        else:
            out[i] = w0[i]


@njit(cache=True, nogil=True)
def _system(
    K: NDArray, R: NDArray, t: NDArray, X: NDArray, uv: NDArray, w: NDArray, A: NDArray, g: NDArray
) -> None:
    """Weighted normal equations ``A`` (6, 6), ``g`` (6,) of one pose, in place.

    Points of weight 0 and points at or behind the camera are left out.
    The update is ``p' = p + w x p + d`` in the camera frame: ``du/dw = p x du/dp`` and
    ``du/dd = du/dp``.
    """
    fx, s, cx = K[0, 0], K[0, 1], K[0, 2]
    fy = K[1, 1]
    A[:, :] = 0.0
    g[:] = 0.0
    ju = np.empty(6)
    jv = np.empty(6)
    for i in range(X.shape[0]):
        wi = w[i]
        if wi == 0.0:
            continue
        x, y, z = camera_point(R, t, X, i)
        if not z > MIN_DEPTH:
            continue
        ru, rv = _residual(K, x, y, z, uv[i, 0], uv[i, 1])
        iz = 1.0 / z
        ur = ru + uv[i, 0]
        a, b, c = fx * iz, s * iz, (cx - ur) * iz  # du/dp
        e = fy * iz
        f = -e * y * iz  # dv/dp = (0, e, f)
        ju[0], ju[1], ju[2] = y * c - z * b, z * a - x * c, x * b - y * a
        ju[3], ju[4], ju[5] = a, b, c
        jv[0], jv[1], jv[2] = y * f - z * e, -x * f, x * e
        jv[3], jv[4], jv[5] = 0.0, e, f
        for p in range(6):
            g[p] += wi * (ju[p] * ru + jv[p] * rv)
            for q in range(p, 6):
                A[p, q] += wi * (ju[p] * ju[q] + jv[p] * jv[q])
    for p in range(6):
        for q in range(p):
            A[p, q] = A[q, p]


@njit(cache=True, nogil=True)
def _cost(K: NDArray, R: NDArray, t: NDArray, X: NDArray, uv: NDArray, w: NDArray, depth_inf: bool) -> float:
    """Sum of ``w`` times squared residuals.

    A weighted point at or behind the camera makes it inf with ``depth_inf``, else it is left out.
    """
    cost = 0.0
    for i in range(X.shape[0]):
        if w[i] == 0.0:
            continue
        x, y, z = camera_point(R, t, X, i)
        if not z > MIN_DEPTH:
            if depth_inf:
                return np.inf
            continue
        ru, rv = _residual(K, x, y, z, uv[i, 0], uv[i, 1])
        cost += w[i] * (ru * ru + rv * rv)
    return cost


@njit(cache=True, nogil=True)
def _solve6(M: NDArray, g: NDArray, out: NDArray) -> bool:
    """``out = -M^-1 g`` for a symmetric positive definite M (6, 6) by Cholesky; False if not."""
    L = np.zeros((6, 6))
    for j in range(6):
        d = M[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, 6):
            v = M[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            L[i, j] = v / L[j, j]
    y = np.empty(6)
    for i in range(6):
        v = -g[i]
        for k in range(i):
            v -= L[i, k] * y[k]
        y[i] = v / L[i, i]
    for i in range(5, -1, -1):
        v = y[i]
        for k in range(i + 1, 6):
            v -= L[k, i] * out[k]
        out[i] = v / L[i, i]
    for i in range(6):
        if not np.isfinite(out[i]):
            return False
    return True


@njit(cache=True, nogil=True)
def lm_one(
    K: NDArray, R: NDArray, t: NDArray, X: NDArray, uv: NDArray, w0: NDArray,
    iterations: int, robust_sq: float, tol: float,
) -> float:
    """LM on one pose, ``R`` (3, 3) and ``t`` (3,) updated in place; see :func:`lm_many`.

    Returns the unweighted cost over ``w0 > 0`` (inf with such a point at or behind the camera).
    """
    A = np.empty((6, 6))
    M = np.empty((6, 6))
    g = np.empty(6)
    delta = np.empty(6)
    dR = np.empty((3, 3))
    Rn = np.empty((3, 3))
    tn = np.empty(3)
    w = np.empty(X.shape[0])
    lam = 1e-3
    moved = True
    cost = 0.0
    for _ in range(iterations):
        if moved:  # else the weights, system and cost are the last step's
            _weights(K, R, t, X, uv, w0, robust_sq, w)
            _system(K, R, t, X, uv, w, A, g)
            cost = _cost(K, R, t, X, uv, w, False)
        M[:, :] = A
        for p in range(6):
            M[p, p] += lam * max(A[p, p], 1e-12)
        if not _solve6(M, g, delta):
            delta[:] = 0.0
        _exp(delta[0], delta[1], delta[2], dR)
        for r in range(3):
            for c in range(3):
                Rn[r, c] = dR[r, 0] * R[0, c] + dR[r, 1] * R[1, c] + dR[r, 2] * R[2, c]
            tn[r] = dR[r, 0] * t[0] + dR[r, 1] * t[1] + dR[r, 2] * t[2] + delta[3 + r]
        costn = _cost(K, Rn, tn, X, uv, w, False)
        moved = costn <= cost  # False for NaN
        if moved:
            rel = (cost - costn) / max(cost, 1e-300)
            R[:, :] = Rn
            t[:] = tn
            lam = max(lam * 0.1, 1e-12)
            if rel < tol:
                break
        else:
            lam *= 10.0
            if lam >= 1e8:
                break
    U, _, Vt = np.linalg.svd(R)
    R[:, :] = U @ Vt
    return _cost(K, R, t, X, uv, w0, True)


@njit(cache=True, nogil=True)
def lm_many(
    K: NDArray, R: NDArray, t: NDArray, X: NDArray, uv: NDArray, mask: NDArray,
    iterations: int, robust_px: float, tol: float,
) -> tuple[NDArray, NDArray, NDArray]:
    """Levenberg-Marquardt on H poses, each on its own padded pairs (``refine_many``'s algorithm).

    Each step solves the damped normal equations at the current pose (with ``robust_px > 0``,
    under Cauchy weights of its residuals, held fixed for the step: iteratively reweighted least
    squares) and keeps the update if it does not raise the step's weighted cost; damping falls
    tenfold on success and rises tenfold on failure. A pose stops when its relative cost decrease
    falls below ``tol`` or its damping reaches 1e8.

    Returns ``(R (H, 3, 3), t (H, 3), cost (H,))``: rotations re-orthonormalized, and the
    unweighted sum of squared residuals over the mask (inf when a masked point is at or behind
    the camera).
    """
    Rout = R.copy()
    tout = t.copy()
    cost = np.empty(R.shape[0])
    robust_sq = robust_px * robust_px if robust_px > 0.0 else 0.0
    for k in range(R.shape[0]):
        w0 = mask[k].astype(np.float64)
        cost[k] = lm_one(K, Rout[k], tout[k], X[k], uv[k], w0, iterations, robust_sq, tol)
    return Rout, tout, cost
