"""Compiled kernels (numba) of the steps of robust association whose cost was Python overhead.

Robust association (:mod:`localization.associate`) refines tens of pose hypotheses per image in
rounds of Levenberg-Marquardt and gated re-association. As batched numpy code each round was
some hundred small array calls, and with 10-20 poses of 4-20 points the call overhead, not the
arithmetic, was the cost (3.6-4.2 ms per column-top image, half of it in these rounds). Here
the same algorithms run as one compiled loop per hypothesis:

- :func:`lm_many` -- Levenberg-Marquardt on many poses (normal equations accumulated point by
  point, the damped 6x6 system solved by Cholesky), behind :func:`localization.batch.refine_many`;
- :func:`assign_rounds` -- the greedy mutual-nearest-neighbour assignment of
  :func:`localization.batch.assign_many`;
- :func:`refine_reassign` -- the refine / re-project / re-assign rounds of a batch of
  hypotheses until their assignments are stable;
- :func:`shift_votes` -- the Hough vote for image shifts of the layout hypotheses.

They replace batched numpy code (before commit c535233) with the same algorithms: on the 800
images of ``benchmarks/localizer.py`` (four landmark sets, clean and with misses + clutter, both
association modes) every success, assignment and failure reason is the same, and poses agree to
2e-5 m. :func:`lm_many` also runs :func:`localization.pnp.refine_pose`. The kernels are compiled
on first use and cached beside this file (``cache=True``; numba falls back to a user cache folder
where this one is read-only): the first process after an install pays the compilation (about
20 s on the 2-core VM, 45 s under load), later ones about 0.3 s to load them.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["assign_rounds", "lm_many", "pair_sq", "refine_reassign", "shift_votes"]

#: A point at or in front of this depth (m) counts as behind the camera.
MIN_DEPTH = 1e-6


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
def _point(R: NDArray, t: NDArray, X: NDArray, i: int) -> tuple[float, float, float]:
    """Camera-frame coordinates of point ``X[i]``."""
    x = R[0, 0] * X[i, 0] + R[0, 1] * X[i, 1] + R[0, 2] * X[i, 2] + t[0]
    y = R[1, 0] * X[i, 0] + R[1, 1] * X[i, 1] + R[1, 2] * X[i, 2] + t[1]
    z = R[2, 0] * X[i, 0] + R[2, 1] * X[i, 1] + R[2, 2] * X[i, 2] + t[2]
    return x, y, z


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
        x, y, z = _point(R, t, X, i)
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
        x, y, z = _point(R, t, X, i)
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
        x, y, z = _point(R, t, X, i)
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
def _lm_one(
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
        cost[k] = _lm_one(K, Rout[k], tout[k], X[k], uv[k], w0, iterations, robust_sq, tol)
    return Rout, tout, cost


@njit(cache=True, nogil=True)
def pair_sq(det: NDArray, proj: NDArray) -> NDArray:
    """(N, M) squared pixel distances of detections ``det`` (N, 2) to projections ``proj`` (M, 2)."""
    d2 = np.empty((det.shape[0], proj.shape[0]))
    for i in range(det.shape[0]):
        for j in range(proj.shape[0]):
            du = det[i, 0] - proj[j, 0]
            dv = det[i, 1] - proj[j, 1]
            d2[i, j] = du * du + dv * dv
    return d2


@njit(cache=True, nogil=True)
def _assign_one(det: NDArray, proj: NDArray, gate_sq: float, rounds: int, out: NDArray) -> None:
    """Greedy mutual-nearest-neighbour assignment of ``det`` (N, 2) to ``proj`` (M, 2).

    Into ``out`` (N,) (-1: unassigned), as :func:`localization.batch.assign_many` defines it.
    """
    n, m = det.shape[0], proj.shape[0]
    out[:] = -1
    if n == 0 or m == 0:
        return
    d2 = pair_sq(det, proj)
    for i in range(n):
        for j in range(m):
            if not d2[i, j] <= gate_sq:  # NaN too
                d2[i, j] = np.inf
    jn = np.empty(n, dtype=np.int64)
    inn = np.empty(m, dtype=np.int64)
    ok = np.empty(n, dtype=np.bool_)
    for _ in range(rounds):
        for i in range(n):  # nearest projection of each detection (first of equals)
            best, jb = d2[i, 0], 0
            for j in range(1, m):
                if d2[i, j] < best:
                    best, jb = d2[i, j], j
            jn[i] = jb
        for j in range(m):  # nearest detection of each projection
            best, ib = d2[0, j], 0
            for i in range(1, n):
                if d2[i, j] < best:
                    best, ib = d2[i, j], i
            inn[j] = ib
        anyok = False
        for i in range(n):
            ok[i] = inn[jn[i]] == i and d2[i, jn[i]] < np.inf
            anyok = anyok or ok[i]
        if not anyok:
            break
        for i in range(n):
            if ok[i]:
                j = jn[i]
                out[i] = j
                d2[i, :] = np.inf
                d2[:, j] = np.inf


@njit(cache=True, nogil=True)
def assign_rounds(det: NDArray, proj: NDArray, gate_px: float, rounds: int) -> NDArray:
    """(H, N) :func:`_assign_one` of ``det`` (N, 2) to each layout of ``proj`` (H, M, 2)."""
    out = np.empty((proj.shape[0], det.shape[0]), dtype=np.int64)
    for k in range(proj.shape[0]):
        _assign_one(det, proj[k], gate_px * gate_px, rounds, out[k])
    return out


@njit(cache=True, nogil=True)
def _candidates(
    K: NDArray, R: NDArray, t: NDArray, L: NDArray, width: int, height: int, margin: float, out: NDArray
) -> None:
    """Projections (M, 2) of landmarks ``L`` into ``out`` at one pose.

    NaN where behind the camera or more than ``margin`` px outside the image (as
    ``associate._candidate_projections``).
    """
    for j in range(L.shape[0]):
        x, y, z = _point(R, t, L, j)
        out[j, 0] = np.nan
        out[j, 1] = np.nan
        if not z > MIN_DEPTH:
            continue
        u = (K[0, 0] * x + K[0, 1] * y) / z + K[0, 2]
        v = K[1, 1] * y / z + K[1, 2]
        if -0.5 - margin <= u <= width - 0.5 + margin and -0.5 - margin <= v <= height - 0.5 + margin:
            out[j, 0] = u
            out[j, 1] = v


@njit(cache=True, nogil=True)
def _pairs(a: NDArray, L: NDArray, det: NDArray, X: NDArray, uv: NDArray, w0: NDArray) -> None:
    """The padded pairs of assignment ``a`` (N,): points ``X``, pixels ``uv``, weights ``w0``."""
    for i in range(a.size):
        paired = a[i] >= 0
        w0[i] = 1.0 if paired else 0.0
        X[i] = L[max(a[i], 0)]
        uv[i, 0] = det[i, 0] if paired else 0.0
        uv[i, 1] = det[i, 1] if paired else 0.0


@njit(cache=True, nogil=True)
def refine_reassign(
    K: NDArray, L: NDArray, det: NDArray, good: NDArray, a: NDArray, R: NDArray, t: NDArray,
    width: int, height: int, margin: float, gate: float, coarse_gate: float,
    max_iterations: int, need: int, first_robust: bool,
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Rounds of PnP and gated re-association of H hypotheses (``associate._Problem.refine``).

    Args:
        K: (3, 3) intrinsics.
        L: (M, 3) landmarks.
        det: (N, 2) detections.
        good: (G,) the finite rows of ``det``.
        a: (H, N) coarse assignments (landmark index or -1).
        R: (H, 3, 3) start rotations of ``cam_from_world``.
        t: (H, 3) start translations.
        width: image width, px.
        height: image height, px.
        margin: how far outside the image a projection stays a candidate, px.
        gate: the final gate, px.
        coarse_gate: the coarse gate, px (the gate of round ``i`` is ``coarse_gate / 4^(i+1)``
            until it reaches ``gate``).
        max_iterations: most rounds.
        need: fewest pairs a hypothesis may keep.
        first_robust: Cauchy weights in the first round and the final gate from the start.

    Returns:
        ``(a, R, t, alive)``: assignments, poses and which hypotheses survived (``need`` pairs
        or more, every paired point in front of the camera).
    """
    h, n = a.shape
    a = a.copy()
    R = R.copy()
    t = t.copy()
    alive = np.ones(h, dtype=np.bool_)
    X = np.zeros((n, 3))
    uv = np.zeros((n, 2))
    w0 = np.zeros(n)
    proj = np.empty((L.shape[0], 2))
    dg = np.empty((good.size, 2))
    for i in range(good.size):
        dg[i] = det[good[i]]
    local = np.empty(good.size, dtype=np.int64)
    for k in range(h):
        moving = True
        for it in range(max_iterations + 1):
            pairs = 0
            for i in range(n):
                if a[k, i] >= 0:
                    pairs += 1
            if pairs < need:
                alive[k] = False
            if not (alive[k] and moving) or it == max_iterations:
                break
            step_gate = gate if first_robust else max(gate, coarse_gate / 4.0 ** (it + 1))
            _pairs(a[k], L, det, X, uv, w0)
            robust = max(gate, coarse_gate / 4.0) if (it == 0 and first_robust) else 0.0
            cost = _lm_one(K, R[k], t[k], X, uv, w0, 3 if it == 0 else 2, robust * robust, 1e-6)
            if not np.isfinite(cost):
                alive[k] = False
            _candidates(K, R[k], t[k], L, width, height, margin, proj)
            _assign_one(dg, proj, step_gate * step_gate, 3, local)
            stable = step_gate == gate
            new_pairs = np.full(n, -1, dtype=np.int64)
            for i in range(good.size):
                new_pairs[good[i]] = local[i]
            for i in range(n):
                if new_pairs[i] != a[k, i]:
                    stable = False
                a[k, i] = new_pairs[i]
            if stable:
                moving = False
        if alive[k] and moving:  # not yet refined on its final pairs
            _pairs(a[k], L, det, X, uv, w0)
            if not np.isfinite(_lm_one(K, R[k], t[k], X, uv, w0, 3, 0.0, 1e-6)):
                alive[k] = False
    return a, R, t, alive


#: Most cells of the dense vote grid; a sparser spread of cells is voted by binary search.
_MAX_GRID = 1 << 20


@njit(cache=True, nogil=True)
def _neighbour_votes(ux: NDArray, uy: NDArray, cnt: NDArray) -> NDArray:
    """Per distinct cell ``(ux, uy)`` (sorted by x, then y) the counts of its 3 x 3 neighbourhood."""
    nu = ux.size
    votes = np.zeros(nu, dtype=np.int64)
    x0, y0, y1 = ux[0], uy.min(), uy.max()
    gw, gh = ux[nu - 1] - x0 + 3, y1 - y0 + 3
    if gw * gh <= _MAX_GRID:  # a dense grid with a border of empty cells
        grid = np.zeros((gw, gh), dtype=np.int64)
        for c in range(nu):
            grid[ux[c] - x0 + 1, uy[c] - y0 + 1] = cnt[c]
        for c in range(nu):
            gx, gy = ux[c] - x0 + 1, uy[c] - y0 + 1
            for di in range(-1, 2):
                for dj in range(-1, 2):
                    votes[c] += grid[gx + di, gy + dj]
        return votes
    for c in range(nu):
        for di in range(-1, 2):
            for dj in range(-1, 2):
                tx, ty = ux[c] + di, uy[c] + dj
                lo, hi = 0, nu  # binary search of (tx, ty)
                while lo < hi:
                    mid = (lo + hi) // 2
                    if ux[mid] < tx or (ux[mid] == tx and uy[mid] < ty):
                        lo = mid + 1
                    else:
                        hi = mid
                if lo < nu and ux[lo] == tx and uy[lo] == ty:
                    votes[c] += cnt[lo]
    return votes


@njit(cache=True, nogil=True)
def shift_votes(det: NDArray, proj: NDArray, vote_px: float, k: int) -> tuple[NDArray, NDArray]:
    """The ``k`` best-voted image shifts of each layout ``proj`` (L, M, 2) onto ``det`` (N, 2).

    ``associate._shift_votes``' vote: every (detection, projection) pair proposes a shift, binned
    in cells of ``vote_px`` (cell ``floor(shift / vote_px)``); a cell's vote is the number of
    proposals in it and its eight neighbours. Per layout the ``k`` cells of most votes (ties: the
    lower cell, x then y), each giving the mean of the layout's proposals within ``vote_px`` of
    its own proposals' mean (or that mean if none). NaN projections propose nothing.

    Returns:
        ``(layout index (S,), shift (S, 2))``, each layout's best first.
    """
    nl, m, n = proj.shape[0], proj.shape[1], det.shape[0]
    out_l = np.empty(nl * k, dtype=np.int64)
    out_s = np.empty((nl * k, 2))
    q = 0
    sx = np.empty(n * m)
    sy = np.empty(n * m)
    cx = np.empty(n * m, dtype=np.int64)
    cy = np.empty(n * m, dtype=np.int64)
    for lay in range(nl):
        p = 0
        for i in range(n):
            for j in range(m):
                u = det[i, 0] - proj[lay, j, 0]
                v = det[i, 1] - proj[lay, j, 1]
                if np.isfinite(u) and np.isfinite(v):
                    sx[p], sy[p] = u, v
                    cx[p] = np.int64(np.floor(u / vote_px))
                    cy[p] = np.int64(np.floor(v / vote_px))
                    p += 1
        if p == 0:
            continue
        # distinct cells in (x, y) order, their proposal counts and coordinate sums (in input order)
        order = np.argsort(cx[:p] * (np.int64(1) << 32) + cy[:p])  # equal keys: one cell, any order
        ux = np.empty(p, dtype=np.int64)
        uy = np.empty(p, dtype=np.int64)
        cnt = np.zeros(p, dtype=np.int64)
        cell = np.empty(p, dtype=np.int64)
        nu = 0
        for r in range(p):
            e = order[r]
            if nu == 0 or cx[e] != ux[nu - 1] or cy[e] != uy[nu - 1]:
                ux[nu], uy[nu] = cx[e], cy[e]
                nu += 1
            cell[e] = nu - 1
            cnt[nu - 1] += 1
        sumx = np.zeros(nu)
        sumy = np.zeros(nu)
        for e in range(p):
            sumx[cell[e]] += sx[e]
            sumy[cell[e]] += sy[e]
        votes = _neighbour_votes(ux[:nu], uy[:nu], cnt[:nu])
        best = np.argsort((-votes[:nu]) * nu + np.arange(nu))  # most votes, then the lower cell
        for r in range(min(k, nu)):
            c = best[r]
            mx, my = sumx[c] / cnt[c], sumy[c] / cnt[c]
            ax, ay, na = 0.0, 0.0, 0
            for e in range(p):
                du, dv = sx[e] - mx, sy[e] - my
                if du * du + dv * dv <= vote_px * vote_px:
                    ax += sx[e]
                    ay += sy[e]
                    na += 1
            out_l[q] = lay
            if na > 0:
                out_s[q, 0], out_s[q, 1] = ax / na, ay / na
            else:
                out_s[q, 0], out_s[q, 1] = mx, my
            q += 1
    return out_l[:q], out_s[:q]
