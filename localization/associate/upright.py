"""The upright two-point pose solver: with the camera's tilt known, two correspondences fix the pose.

An onboard attitude sensor measures roll and pitch (the tilt, the direction of gravity in the
camera) far better than yaw and position. With the tilt taken from the prior, the pose has four
unknowns -- the yaw and the camera centre -- and two 2D-3D correspondences (four equations) fix
it in closed form (the "upright" or "up2p" minimal problem, solved as in Kukelova et al.,
"Closed-form solutions to minimal absolute pose problems with known vertical direction", ACCV
2010, and PoseLib's ``up2p``). Robust association (:mod:`localization.associate`) draws its
hypotheses this way: every pair of landmarks for a few pairs of detections, all solved at once.

Derivation. Let ``d_k = R_wc0 K^-1 (u_k, 1)`` be the world direction of detection ``k`` under
the prior's attitude. The pose is the prior's attitude turned by ``psi`` about the world z axis,
``R_wc = Rz(psi) R_wc0``, and the centre ``C``, so ``X_k = C + l_k Rz(psi) d_k`` with depths
``l_k > 0``. The difference ``X_1 - X_2 = Rz(psi) (l_1 d_1 - l_2 d_2)`` removes ``C``; ``Rz``
keeps the z component and the horizontal length, which gives one linear and one quadratic
equation in ``(l_1, l_2)``:

    l_1 d_1z - l_2 d_2z = dZ,      |l_1 d_1xy - l_2 d_2xy|^2 = |dXY|^2.

On the line of the first, the second is a quadratic in one unknown: up to two solutions. ``psi``
is then the angle from ``l_1 d_1xy - l_2 d_2xy`` to ``dXY``, and ``C = X_1 - l_1 Rz(psi) d_1``.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from localization.geometry.kernels import MIN_DEPTH, kernel_array

__all__ = ["score_samples", "score_upright_poses", "upright_two_point"]


@njit(cache=True, nogil=True)
def _solve(d1: NDArray, d2: NDArray, X1: NDArray, X2: NDArray, sign: float, C: NDArray) -> tuple[float, bool]:
    """One root (``sign`` +1 or -1) of the upright two-point problem: ``(psi, valid)``, centre into ``C``."""
    dx, dy, dz = X1[0] - X2[0], X1[1] - X2[1], X1[2] - X2[2]
    a0, a1 = d1[2], -d2[2]  # a . (l1, l2) = dZ
    na2 = a0 * a0 + a1 * a1
    ok = na2 > 1e-12 and dx * dx + dy * dy + dz * dz > 1e-12
    if not ok:
        na2 = 1.0
    lp0, lp1 = a0 * (dz / na2), a1 * (dz / na2)  # the point of the line nearest the origin
    nrm = np.sqrt(na2)
    n0, n1 = a1 / nrm, -a0 / nrm  # the line's direction
    q11 = d1[0] * d1[0] + d1[1] * d1[1]  # |l1 d1xy - l2 d2xy|^2 = l^T Q l
    q22 = d2[0] * d2[0] + d2[1] * d2[1]
    q12 = -(d1[0] * d2[0] + d1[1] * d2[1])
    A = q11 * n0 * n0 + q12 * (n0 * n1 + n1 * n0) + q22 * n1 * n1
    B = 2.0 * (q11 * lp0 * n0 + q12 * (lp0 * n1 + lp1 * n0) + q22 * lp1 * n1)
    Cc = q11 * lp0 * lp0 + q12 * (lp0 * lp1 + lp1 * lp0) + q22 * lp1 * lp1 - (dx * dx + dy * dy)
    disc = B * B - 4.0 * A * Cc
    ok = ok and disc >= 0.0 and A > 1e-15
    root = np.sqrt(max(disc, 0.0))
    if not ok:
        A = 1.0
    s = (-B + sign * root) / (2.0 * A)
    l1, l2 = lp0 + s * n0, lp1 + s * n1  # depths along d1, d2
    ok = ok and l1 > 0.0 and l2 > 0.0
    v0, v1 = l1 * d1[0] - l2 * d2[0], l1 * d1[1] - l2 * d2[1]
    psi = np.arctan2(v0 * dy - v1 * dx, v0 * dx + v1 * dy)
    c, sn = np.cos(psi), np.sin(psi)
    C[0] = X1[0] - l1 * (c * d1[0] - sn * d1[1])
    C[1] = X1[1] - l1 * (sn * d1[0] + c * d1[1])
    C[2] = X1[2] - l1 * d1[2]
    return psi, ok


@njit(cache=True, nogil=True)
def _solve_many(d1: NDArray, d2: NDArray, X1: NDArray, X2: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Both roots of every sample: :func:`upright_two_point`'s ``(psi, C, valid)`` layout."""
    s = d1.shape[0]
    psi = np.empty(2 * s)
    C = np.empty((2 * s, 3))
    ok = np.empty(2 * s, dtype=np.bool_)
    for r in range(2):
        for k in range(s):
            psi[r * s + k], ok[r * s + k] = _solve(d1[k], d2[k], X1[k], X2[k], 1.0 - 2.0 * r, C[r * s + k])
    return psi, C, ok


def upright_two_point(
    d1: NDArray[np.float64], d2: NDArray[np.float64], X1: NDArray[np.float64], X2: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Yaw corrections and camera centres that put two world points on two viewing directions.

    Args:
        d1: (S, 3) world direction of the first detection under the prior's attitude
            (``R_wc0 K^-1 (u, 1)``; any positive length).
        d2: (S, 3) the same for the second detection.
        X1: (S, 3) the landmark each sample assigns to the first detection.
        X2: (S, 3) the landmark each sample assigns to the second.

    Returns:
        ``(psi (2S,), C (2S, 3), valid (2S,))``: for each sample its two solutions (rows ``s``
        and ``S + s``): ``psi`` the rotation about the world z axis to apply to the prior's
        ``world_from_cam`` rotation (``R_wc = Rz(psi) R_wc0``) and ``C`` the camera centre;
        ``valid`` is False where the solution does not exist (complex roots, a depth not
        positive, both directions horizontal, or the two points at one place).
    """
    f64 = np.float64
    d1, d2, X1, X2 = (kernel_array(v, dtype=f64).reshape(-1, 3) for v in (d1, d2, X1, X2))
    return _solve_many(d1, d2, X1, X2)


@njit(cache=True, nogil=True)
def _similar_pairs(
    det: NDArray, i1: NDArray, i2: NDArray, idx: NDArray, proj: NDArray
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Every anchor pair x ordered landmark pair whose prior image looks like the detection pair's.

    Within a factor 3 in length and 45 degrees in direction. Returns ``(s1, s2, t1, t2)`` (S,):
    the two detections and the two landmarks (indices into ``L``) of each sample.
    """
    m = idx.size
    ns = 0
    cap = i1.size * m * (m - 1)
    s1 = np.empty(cap, dtype=np.int64)
    s2 = np.empty(cap, dtype=np.int64)
    t1 = np.empty(cap, dtype=np.int64)
    t2 = np.empty(cap, dtype=np.int64)
    for p in range(i1.size):
        vdx, vdy = det[i2[p], 0] - det[i1[p], 0], det[i2[p], 1] - det[i1[p], 1]
        nd = vdx * vdx + vdy * vdy
        for j1 in range(m):
            for j2 in range(m):
                if j1 == j2:
                    continue
                vpx, vpy = proj[j2, 0] - proj[j1, 0], proj[j2, 1] - proj[j1, 1]
                dot = vdx * vpx + vdy * vpy
                npp = vpx * vpx + vpy * vpy
                if nd <= 9.0 * npp and npp <= 9.0 * nd and dot > 0.0 and 2.0 * dot * dot >= nd * npp:
                    s1[ns], s2[ns], t1[ns], t2[ns] = i1[p], i2[p], idx[j1], idx[j2]
                    ns += 1
    return s1[:ns], s2[:ns], t1[:ns], t2[:ns]


@njit(cache=True, nogil=True)
def _solve_samples(
    rays: NDArray, L: NDArray, s1: NDArray, s2: NDArray, t1: NDArray, t2: NDArray, C0: NDArray,
    sigma_pos: NDArray, sigma_yaw: float, max_prior_sq: float,
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Both roots of every sample: ``(psi (2S,), C (2S, 3), prior_sq (2S,), keep (2S,))``.

    All "+" roots first, then all "-" roots; ``keep``: the root exists and is within
    ``max_prior_sq`` of the prior (yaw ``sigma_yaw``, centre ``C0`` with ``sigma_pos``).
    """
    ns = s1.size
    psi = np.empty(2 * ns)
    C = np.empty((2 * ns, 3))
    keep = np.zeros(2 * ns, dtype=np.bool_)
    psq = np.empty(2 * ns)
    for r in range(2):
        for k in range(ns):
            q = r * ns + k
            psi[q], ok = _solve(rays[s1[k]], rays[s2[k]], L[t1[k]], L[t2[k]], 1.0 - 2.0 * r, C[q])
            d = (psi[q] / sigma_yaw) ** 2
            for c in range(3):
                d += ((C[q, c] - C0[c]) / sigma_pos[c]) ** 2
            psq[q] = d
            keep[q] = ok and d <= max_prior_sq
    return psi, C, psq, keep


@njit(cache=True, nogil=True)
def _upright_pose(R0: NDArray, psi: float, C: NDArray, R: NDArray, t: NDArray) -> None:
    """Into ``R`` (3, 3), ``t`` (3,): the ``cam_from_world`` of ``R0`` turned by ``psi``, centre ``C``."""
    c, sn = np.cos(psi), np.sin(psi)
    for a in range(3):  # R = R0 Rz(psi)^T
        R[a, 0] = R0[a, 0] * c - R0[a, 1] * sn
        R[a, 1] = R0[a, 0] * sn + R0[a, 1] * c
        R[a, 2] = R0[a, 2]
    for a in range(3):
        t[a] = -(R[a, 0] * C[0] + R[a, 1] * C[1] + R[a, 2] * C[2])


@njit(cache=True, nogil=True)
def _project_candidates(K: NDArray, R: NDArray, t: NDArray, L: NDArray, idx: NDArray, uv: NDArray) -> None:
    """Into ``uv`` (m, 2): the projections of the candidates ``L[idx]`` at ``R``, ``t`` (NaN behind)."""
    for j in range(idx.size):
        X = L[idx[j]]
        x = R[0, 0] * X[0] + R[0, 1] * X[1] + R[0, 2] * X[2] + t[0]
        y = R[1, 0] * X[0] + R[1, 1] * X[1] + R[1, 2] * X[2] + t[1]
        z = R[2, 0] * X[0] + R[2, 1] * X[1] + R[2, 2] * X[2] + t[2]
        if z > MIN_DEPTH:
            uv[j, 0] = (K[0, 0] * x + K[0, 1] * y) / z + K[0, 2]
            uv[j, 1] = K[1, 1] * y / z + K[1, 2]
        else:
            uv[j, 0] = np.nan
            uv[j, 1] = np.nan


@njit(cache=True, nogil=True)
def _explain(det: NDArray, uv: NDArray, gate_sq: float) -> tuple[int, float]:
    """``(explained, misfit)`` of projections ``uv`` (m, 2): as :func:`score_upright_poses` returns."""
    explained = 0
    misfit = 0.0
    for i in range(det.shape[0]):
        best = gate_sq
        for j in range(uv.shape[0]):
            du = det[i, 0] - uv[j, 0]
            dv = det[i, 1] - uv[j, 1]
            d2 = du * du + dv * dv
            if d2 < best:  # False for NaN
                best = d2
        misfit += best
        if best < gate_sq:
            explained += 1
    return explained, misfit


@njit(cache=True, nogil=True)
def score_upright_poses(
    det: NDArray, rays: NDArray, i1: NDArray, i2: NDArray, idx: NDArray, proj: NDArray, L: NDArray,
    K: NDArray, R0: NDArray, C0: NDArray, sigma_pos: NDArray, sigma_yaw: float, max_prior_sq: float,
    gate_sq: float,
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Upright two-point poses of every anchor pair x ordered landmark pair, each scored.

    For anchor pair ``(i1[p], i2[p])`` of detections and ordered pair ``(j1, j2)`` of distinct
    candidate landmarks ``idx`` whose prior projections ``proj`` are within a factor 3 in length
    and 45 degrees in direction of the detection pair's, both roots of the upright problem
    (detection directions ``rays`` under the prior's attitude ``R0``, a ``cam_from_world``
    rotation); roots within ``max_prior_sq`` of the prior (yaw ``sigma_yaw``, centre ``C0`` with
    ``sigma_pos``) are kept, all "+" roots first, then all "-" roots, each in sample order.

    Returns:
        ``(R (S, 3, 3), t (S, 3), uv (S, m, 2), prior_sq (S,), explained (S,), misfit (S,))``:
        the poses (``cam_from_world``), the candidates' projections (NaN behind the camera), the
        squared prior distance, the detections within ``sqrt(gate_sq)`` of a projection and the
        sum of squared distances to the nearest projection capped at ``gate_sq``.
    """
    s1, s2, t1, t2 = _similar_pairs(det, i1, i2, idx, proj)
    return score_samples(det, rays, s1, s2, t1, t2, idx, L, K, R0, C0, sigma_pos, sigma_yaw, max_prior_sq,
                         gate_sq)


@njit(cache=True, nogil=True)
def score_samples(
    det: NDArray, rays: NDArray, s1: NDArray, s2: NDArray, t1: NDArray, t2: NDArray, idx: NDArray,
    L: NDArray, K: NDArray, R0: NDArray, C0: NDArray, sigma_pos: NDArray, sigma_yaw: float,
    max_prior_sq: float, gate_sq: float,
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Upright two-point poses of given samples, each scored: :func:`score_upright_poses`' outputs.

    Sample ``k`` puts landmark ``t1[k]`` on detection ``s1[k]`` and ``t2[k]`` on ``s2[k]``
    (directions ``rays`` under the attitude ``R0``, whose yaw the prior term measures from);
    the rest as :func:`score_upright_poses`.
    """
    psi, C, psq, keep = _solve_samples(rays, L, s1, s2, t1, t2, C0, sigma_pos, sigma_yaw, max_prior_sq)
    sel = np.flatnonzero(keep)
    S = sel.size
    R = np.empty((S, 3, 3))
    t = np.empty((S, 3))
    uv = np.empty((S, idx.size, 2))
    prior_sq = psq[sel]
    explained = np.zeros(S, dtype=np.int64)
    misfit = np.zeros(S)
    for q in range(S):
        _upright_pose(R0, psi[sel[q]], C[sel[q]], R[q], t[q])
        _project_candidates(K, R[q], t[q], L, idx, uv[q])
        explained[q], misfit[q] = _explain(det, uv[q], gate_sq)
    return R, t, uv, prior_sq, explained, misfit
