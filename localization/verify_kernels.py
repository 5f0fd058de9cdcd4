"""Compiled kernels (numba) of the verification's rival searches (:mod:`localization.verify`).

- :func:`offset_votes` -- the common image offsets from a set of points to another, voted in
  cells and ranked by the points that agree (the twins' and the offset starts' offsets);
- :func:`lattice_hits` -- the translations that carry a landmark set's paired landmarks onto
  other landmarks (the periods of a layout);
- :func:`leave_one_out` -- each pair's residual against the pose the other pairs give, and how
  far leaving it out moves the camera centre (linearized);
- :func:`predictions` -- the landmarks a pose projects into the image.

The rivals' scores use the association's own kernels
(:mod:`localization.associate.hypothesis_kernels`).

``tests/localization/test_verify_kernels.py`` holds them to plain-numpy references. Compiled
and cached like :mod:`localization.geometry.kernels`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from localization.geometry.kernels import camera_point

__all__ = ["lattice_hits", "leave_one_out", "offset_votes", "predictions"]

#: Relative margin within which :func:`_within` asks ``np.hypot`` rather than the squared length.
_NEAR = 1e-9


@njit(cache=True, nogil=True)
def _within(dx: float, dy: float, r: float) -> bool:
    """``np.hypot(dx, dy) <= r``, decided from ``dx^2 + dy^2`` unless within :data:`_NEAR` of ``r``.

    The squared length is a few ulp from the exact one; ``np.hypot`` costs ten times more.
    """
    d2 = dx * dx + dy * dy
    if d2 < (r * (1.0 - _NEAR)) ** 2:
        return True
    if d2 > (r * (1.0 + _NEAR)) ** 2:
        return False
    return np.hypot(dx, dy) <= r


@njit(cache=True, nogil=True)
def _offsets(
    pair_uv: NDArray, free_uv: NDArray, tol: float, radius: float
) -> tuple[NDArray, NDArray, NDArray]:
    """``(vx, vy, vp)``: the offsets longer than ``tol`` and at most ``radius``, pair-major.

    ``vp``: the pair each starts from.
    """
    n_pairs, n_free = pair_uv.shape[0], free_uv.shape[0]
    vx = np.empty(n_pairs * n_free)
    vy = np.empty(n_pairs * n_free)
    vp = np.empty(n_pairs * n_free, dtype=np.int64)
    n = 0
    for p in range(n_pairs):
        for f in range(n_free):
            ox = free_uv[f, 0] - pair_uv[p, 0]
            oy = free_uv[f, 1] - pair_uv[p, 1]
            if _within(ox, oy, radius) and not _within(ox, oy, tol):
                vx[n], vy[n], vp[n] = ox, oy, p
                n += 1
    return vx[:n], vy[:n], vp[:n]


@njit(cache=True, nogil=True)
def _cell_votes(key: NDArray, vp: NDArray, n_pairs: int, span: int) -> tuple[NDArray, NDArray]:
    """``(cells, votes)``: the occupied cells (ascending) and the pairs around each.

    ``votes``: the distinct pairs in each cell's 3 x 3 neighbourhood (cell ``key = row * span +
    column``).
    """
    n = key.size
    cell_pair = np.sort(key * n_pairs + vp)
    cells = np.empty(n, dtype=np.int64)
    per_cell = np.zeros(n, dtype=np.int64)
    n_c = 0
    for i in range(n):
        if i > 0 and cell_pair[i] == cell_pair[i - 1]:
            continue  # the same pair again in the same cell
        c = cell_pair[i] // n_pairs
        if n_c == 0 or cells[n_c - 1] != c:
            cells[n_c] = c
            n_c += 1
        per_cell[n_c - 1] += 1
    cells, per_cell = cells[:n_c], per_cell[:n_c]
    votes = np.zeros(n_c, dtype=np.int64)
    for di in range(-1, 2):
        for dj in range(-1, 2):
            shift = di * span + dj
            at = 0  # cells + shift ascend too: one merge per shift
            for c in range(n_c):
                want = cells[c] + shift
                while at < n_c - 1 and cells[at] < want:
                    at += 1
                if cells[at] == want:
                    votes[c] += per_cell[at]
    return cells, votes


@njit(cache=True, nogil=True)
def _agreeing(vx: NDArray, vy: NDArray, vp: NDArray, first: int, tol: float) -> tuple[float, float, int]:
    """``(mean x, mean y, pairs)`` of the offsets within ``tol`` of offset ``first``.

    ``pairs``: the distinct pairs with an offset within ``tol`` of that mean (``vp`` ascending).
    """
    fx, fy = vx[first], vy[first]
    sx, sy, m = 0.0, 0.0, 0
    for i in range(vx.size):
        if _within(vx[i] - fx, vy[i] - fy, tol):
            sx += vx[i]
            sy += vy[i]
            m += 1
    cx, cy = sx / m, sy / m
    agree, last = 0, -1
    for i in range(vx.size):  # vp ascends, so a new pair is a new value
        if vp[i] != last and _within(vx[i] - cx, vy[i] - cy, tol):
            agree += 1
            last = vp[i]
    return cx, cy, agree


@njit(cache=True, nogil=True)
def offset_votes(
    pair_uv: NDArray, free_uv: NDArray, tol: float, radius: float, n_cells: int, n_out: int
) -> NDArray:
    """Candidate common offsets from ``pair_uv`` (P, 2) to ``free_uv`` (F, 2), most pairs agreeing first.

    The offsets longer than ``tol`` and at most ``radius`` are binned in ``tol`` cells; the
    ``n_cells`` cells whose 3 x 3 neighbourhoods hold the most distinct pairs (ties: lower cell
    first) each give a candidate: the mean of the offsets within ``tol`` of the cell's first
    offset (in pair-major order), with the number of distinct pairs that have an offset within
    ``tol`` of that mean. Returns (C, 3), C <= ``n_out``: offset (2), agreeing pairs; sorted by
    agreeing pairs, descending (ties keep the cells' order).
    """
    vx, vy, vp = _offsets(pair_uv, free_uv, tol, radius)
    if vx.size == 0:
        return np.zeros((0, 3))
    span = int(2 * radius / tol) + 4  # cells per axis, with room for the neighbourhood
    half = span // 2
    key = np.empty(vx.size, dtype=np.int64)
    for i in range(vx.size):
        key[i] = (np.int64(np.floor(vx[i] / tol)) + half) * span + (np.int64(np.floor(vy[i] / tol)) + half)
    cells, votes = _cell_votes(key, vp, pair_uv.shape[0], span)
    ranked = np.argsort(-votes, kind="mergesort")[:n_cells]
    out = np.empty((ranked.size, 3))
    for r in range(ranked.size):
        first = 0
        while key[first] != cells[ranked[r]]:
            first += 1
        out[r, 0], out[r, 1], out[r, 2] = _agreeing(vx, vy, vp, first, tol)
    order = np.argsort(-out[:, 2], kind="mergesort")[:n_out]
    return out[order]


@njit(cache=True, nogil=True)
def _nearest_within(
    landmarks_xyz: NDArray, order: NDArray, xs: NDArray, qx: float, qy: float, qz: float, tol_m: float
) -> int:
    """The landmark nearest to ``(qx, qy, qz)`` when it lies within ``tol_m``, else -1.

    ``order`` sorts the landmarks by x and ``xs`` holds their sorted x: only those within
    ``tol_m`` in x are searched (any landmark within ``tol_m`` is among them).
    """
    reach = tol_m * (1.0 + 1e-9) + 1e-12
    lo = np.searchsorted(xs, qx - reach)
    hi = np.searchsorted(xs, qx + reach, side="right")
    best, bj = np.inf, -1
    for t in range(lo, hi):
        q = order[t]
        dx = qx - landmarks_xyz[q, 0]
        dy = qy - landmarks_xyz[q, 1]
        dz = qz - landmarks_xyz[q, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < best:
            best, bj = d2, q
    return bj if bj >= 0 and math.sqrt(best) <= tol_m else -1


@njit(cache=True, nogil=True)
def lattice_hits(
    landmarks_xyz: NDArray, paired_xyz: NDArray, anchors: int, tol_m: float, least: int, key_m: float
) -> tuple[NDArray, NDArray, NDArray]:
    """The translations that carry at least ``least`` of P paired landmarks onto distinct others.

    The candidates run from the first ``anchors`` paired landmarks onto every landmark:
    translation ``k = i M + m`` is ``landmarks_xyz[m] - paired_xyz[i]``; a paired landmark moved
    by it hits the landmark nearest to it when that lies within ``tol_m``. A translation is kept
    when at least ``least`` hit, no two on the same landmark, it is longer than ``tol_m``, and no
    translation kept before it rounds to the same multiple of ``key_m`` (the first of each).
    Returns ``(k (S,), hit (S, P), nearest (S, P))`` of the kept ones: their indices, which
    paired landmarks hit, and the landmark each hits (-1 for none).
    """
    n_lm, n_p = landmarks_xyz.shape[0], paired_xyz.shape[0]
    order = np.argsort(landmarks_xyz[:, 0], kind="mergesort")
    xs = landmarks_xyz[order, 0].copy()
    n_s = anchors * n_lm
    kept = np.empty(n_s, dtype=np.int64)
    keys = np.empty((n_s, 3), dtype=np.int64)
    hit = np.zeros((n_s, n_p), dtype=np.bool_)
    nearest = np.full((n_s, n_p), -1, dtype=np.int64)
    taken = np.zeros(n_lm, dtype=np.bool_)
    n_kept = 0
    for i in range(anchors):
        for m in range(n_lm):
            sx = landmarks_xyz[m, 0] - paired_xyz[i, 0]
            sy = landmarks_xyz[m, 1] - paired_xyz[i, 1]
            sz = landmarks_xyz[m, 2] - paired_xyz[i, 2]
            if math.sqrt(sx * sx + sy * sy + sz * sz) <= tol_m:
                continue
            hits, misses, distinct = 0, 0, True
            for p in range(n_p):
                bj = _nearest_within(
                    landmarks_xyz, order, xs, paired_xyz[p, 0] + sx, paired_xyz[p, 1] + sy,
                    paired_xyz[p, 2] + sz, tol_m,
                )
                if bj >= 0:
                    hit[n_kept, p] = True
                    nearest[n_kept, p] = bj
                    hits += 1
                    if taken[bj]:
                        distinct = False
                    taken[bj] = True
                else:
                    misses += 1
                    if misses > n_p - least:
                        break
            for p in range(n_p):  # clear the marks
                if nearest[n_kept, p] >= 0:
                    taken[nearest[n_kept, p]] = False
            keep = hits >= least and distinct
            if keep:
                kx, ky, kz = np.rint(sx / key_m), np.rint(sy / key_m), np.rint(sz / key_m)
                for r in range(n_kept):
                    if keys[r, 0] == kx and keys[r, 1] == ky and keys[r, 2] == kz:
                        keep = False
                        break
            if keep:
                kept[n_kept] = i * n_lm + m
                keys[n_kept, 0], keys[n_kept, 1], keys[n_kept, 2] = kx, ky, kz
                n_kept += 1
            else:
                hit[n_kept] = False
                nearest[n_kept] = -1
    return kept[:n_kept], hit[:n_kept], nearest[:n_kept]


@njit(cache=True, nogil=True)
def leave_one_out(
    K: NDArray, R: NDArray, C: NDArray, landmarks_xyz: NDArray, det: NDArray
) -> tuple[NDArray, NDArray, NDArray]:
    """Each pair's leave-one-out residual and the centre's move without it, linearized at a pose.

    ``R`` (3, 3) the ``cam_from_world`` rotation, ``C`` (3,) the camera centre, ``landmarks_xyz``
    (P, 3) and ``det`` (P, 2) the pairs. With ``J_i`` the (2, 6) projection Jacobian of pair ``i``
    w.r.t. ``(C, dtheta)`` (:func:`localization.pose.covariance.pose_jacobian`), ``N = sum J_i^T
    J_i`` and ``B_i = I - J_i N^+ J_i^T``, returns ``(q (P,), shift (P,), det_b (P,))``:
    ``q_i = e_i^T B_i^-1 e_i`` (px^2), the norm of the first three entries of ``N^+ J_i^T B_i^-1
    e_i`` (m) and ``det(B_i)``; ``q`` and ``shift`` are inf where ``det(B_i) <= 1e-12`` (a pair
    the others cannot predict).
    """
    n = landmarks_xyz.shape[0]
    J = np.zeros((n, 2, 6))
    e = np.empty((n, 2))
    fx, fy, s = K[0, 0], K[1, 1], K[0, 1]
    for i in range(n):
        a0 = landmarks_xyz[i, 0] - C[0]
        a1 = landmarks_xyz[i, 1] - C[1]
        a2 = landmarks_xyz[i, 2] - C[2]
        x = R[0, 0] * a0 + R[0, 1] * a1 + R[0, 2] * a2
        y = R[1, 0] * a0 + R[1, 1] * a1 + R[1, 2] * a2
        z = R[2, 0] * a0 + R[2, 1] * a1 + R[2, 2] * a2
        e[i, 0] = det[i, 0] - (fx * x / z + s * y / z + K[0, 2])
        e[i, 1] = det[i, 1] - (fy * y / z + K[1, 2])
        d00, d01, d02 = fx / z, s / z, -(fx * x + s * y) / (z * z)
        d11, d12 = fy / z, -fy * y / (z * z)
        # d p / d C = -R ; d p / d dtheta = R [a]x
        ax = np.array(((0.0, -a2, a1), (a2, 0.0, -a0), (-a1, a0, 0.0)))
        dp = np.empty((3, 6))
        for r in range(3):
            for c in range(3):
                dp[r, c] = -R[r, c]
                dp[r, 3 + c] = R[r, 0] * ax[0, c] + R[r, 1] * ax[1, c] + R[r, 2] * ax[2, c]
        for c in range(6):
            J[i, 0, c] = d00 * dp[0, c] + d01 * dp[1, c] + d02 * dp[2, c]
            J[i, 1, c] = d11 * dp[1, c] + d12 * dp[2, c]
    N = np.zeros((6, 6))
    for i in range(n):
        for r in range(6):
            for c in range(6):
                N[r, c] += J[i, 0, r] * J[i, 0, c] + J[i, 1, r] * J[i, 1, c]
    N_inv = np.linalg.pinv(N)
    q = np.full(n, np.inf)
    shift = np.full(n, np.inf)
    det_b = np.empty(n)
    for i in range(n):
        G = J[i] @ N_inv  # (2, 6)
        b00 = 1.0 - (G[0] * J[i, 0]).sum()
        b01 = -(G[0] * J[i, 1]).sum()
        b10 = -(G[1] * J[i, 0]).sum()
        b11 = 1.0 - (G[1] * J[i, 1]).sum()
        d = b00 * b11 - b01 * b10
        det_b[i] = d
        if not d > 1e-12:
            continue
        u, v = e[i, 0], e[i, 1]
        q[i] = (u * (b11 * u - b01 * v) + v * (b00 * v - b10 * u)) / d
        w0 = (b11 * u - b01 * v) / d  # B^-1 e
        w1 = (b00 * v - b10 * u) / d
        m = 0.0
        for r in range(3):
            g = G[0, r] * w0 + G[1, r] * w1  # (N^+ J_i^T B^-1 e)[r]; N^+ symmetric
            m += g * g
        shift[i] = np.sqrt(m)
    return q, shift, det_b


@njit(cache=True, nogil=True)
def predictions(
    K: NDArray, R: NDArray, t: NDArray, landmarks_xyz: NDArray, width: int, height: int
) -> tuple[NDArray, NDArray]:
    """``(uv (M, 2), predicted (M,))``: the landmarks' projections at ``cam_from_world`` (R, t).

    ``predicted``: in front of the camera and inside the image (pixel centres at integers, edges
    at -0.5 and ``width - 0.5``); ``uv`` NaN where the depth is 0.
    """
    n = landmarks_xyz.shape[0]
    uv = np.empty((n, 2))
    predicted = np.zeros(n, dtype=np.bool_)
    for j in range(n):
        x, y, z = camera_point(R, t, landmarks_xyz, j)
        if z == 0.0:
            uv[j, 0] = uv[j, 1] = np.nan
            continue
        u = K[0, 0] * (x / z) + K[0, 1] * (y / z) + K[0, 2]
        v = K[1, 0] * (x / z) + K[1, 1] * (y / z) + K[1, 2]
        uv[j, 0], uv[j, 1] = u, v
        predicted[j] = z > 0.0 and -0.5 <= u <= width - 0.5 and -0.5 <= v <= height - 0.5
    return uv, predicted
