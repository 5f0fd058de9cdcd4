"""Compiled kernels (numba) of gated assignment and of the refine / re-assign rounds.

- :func:`assign_one` / :func:`assign_rounds` / :func:`assign_many` -- the greedy mutual-nearest-
  neighbour assignment of detections to projected landmarks within a gate, for one layout or a
  stack of them;
- :func:`candidates` and :func:`project_into` -- the landmarks in front of a pose and near the
  image, with their projections;
- :func:`refine_reassign` -- rounds of Levenberg-Marquardt (:func:`localization.pose.lm.lm_one`)
  and gated re-association of a batch of hypotheses until their assignments are stable;
- :func:`assignment_costs` and :func:`assignment_rows` -- the cost matrix of
  :func:`localization.associate.paper.assign` and the assignment read back from scipy's
  ``linear_sum_assignment``.

Compiled and cached like :mod:`localization.geometry.kernels`. A constant handed to another
kernel goes as ``np.int64(...)`` / ``np.bool_(...)``: a bare ``3`` or ``False`` would be typed as
a literal and compile that kernel a second time beside its Python callers' ``int64`` / ``bool``.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from localization.geometry.kernels import MIN_DEPTH, camera_point, kernel_array
from localization.pose.lm import lm_one

__all__ = [
    "assign_many",
    "assign_one",
    "assign_rounds",
    "assignment_costs",
    "assignment_rows",
    "candidates",
    "pair_sq",
    "project_into",
    "refine_reassign",
    "sq_to",
]


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
def sq_to(det: NDArray, i: int, u: float, v: float) -> float:
    """Squared pixel distance of detection ``i`` of ``det`` (N, 2) to the point ``(u, v)``."""
    du = det[i, 0] - u
    dv = det[i, 1] - v
    return du * du + dv * dv


@njit(cache=True, nogil=True)
def _gated_pairs(det: NDArray, proj: NDArray, gate_sq: float) -> tuple[NDArray, NDArray, NDArray]:
    """The (detection, projection) pairs within the gate ``gate_sq`` (squared), in (i, j) order.

    Returns ``(i (P,), j (P,), squared distance (P,))``; NaN rows and columns give no pair.
    """
    n, m = det.shape[0], proj.shape[0]
    cap = 0  # counted first, so that no (N, M) buffer is needed
    for i in range(n):
        for j in range(m):
            if sq_to(det, i, proj[j, 0], proj[j, 1]) <= gate_sq:  # NaN is never within
                cap += 1
    pi = np.empty(cap, dtype=np.int64)
    pj = np.empty(cap, dtype=np.int64)
    pd = np.empty(cap)
    q = 0
    for i in range(n):
        for j in range(m):
            d = sq_to(det, i, proj[j, 0], proj[j, 1])
            if d <= gate_sq:
                pi[q], pj[q], pd[q] = i, j, d
                q += 1
    return pi, pj, pd


@njit(cache=True, nogil=True)
def assign_one(det: NDArray, proj: NDArray, gate_sq: float, rounds: int, out: NDArray) -> None:
    """Greedy mutual-nearest-neighbour assignment of ``det`` (N, 2) to ``proj`` (M, 2).

    Into ``out`` (N,) (-1: unassigned), as :func:`assign_many` defines it: each pass pairs every
    detection and projection that are each other's nearest (the first of equal distances, in
    index order) among those still free within the gate. The passes run over the gated pairs
    only (:func:`_gated_pairs`), so a pass costs the pairs within the gate, not ``N x M``.
    """
    n, m = det.shape[0], proj.shape[0]
    out[:] = -1
    if n == 0 or m == 0:
        return
    pi, pj, pd = _gated_pairs(det, proj, gate_sq)
    row_free = np.ones(n, dtype=np.bool_)
    col_free = np.ones(m, dtype=np.bool_)
    jn = np.empty(n, dtype=np.int64)
    inn = np.empty(m, dtype=np.int64)
    best_row = np.empty(n)
    best_col = np.empty(m)
    for _ in range(rounds):
        jn[:] = -1
        inn[:] = -1
        best_row[:] = np.inf
        best_col[:] = np.inf
        for q in range(pi.size):  # (i, j) order: strict < keeps the first of equals both ways
            i, j, d = pi[q], pj[q], pd[q]
            if row_free[i] and col_free[j]:
                if d < best_row[i]:
                    best_row[i], jn[i] = d, j
                if d < best_col[j]:
                    best_col[j], inn[j] = d, i
        paired = False
        for i in range(n):
            j = jn[i]
            if j >= 0 and inn[j] == i:
                out[i] = j
                row_free[i] = False
                col_free[j] = False
                paired = True
        if not paired:
            break


@njit(cache=True, nogil=True)
def assign_rounds(det: NDArray, proj: NDArray, gate_px: float, rounds: int) -> NDArray:
    """(H, N) :func:`assign_one` of ``det`` (N, 2) to each layout of ``proj`` (H, M, 2)."""
    out = np.empty((proj.shape[0], det.shape[0]), dtype=np.int64)
    for k in range(proj.shape[0]):
        assign_one(det, proj[k], gate_px * gate_px, rounds, out[k])
    return out


@njit(cache=True, nogil=True)
def project_into(
    K: NDArray, R: NDArray, t: NDArray, L: NDArray, width: int, height: int, margin: float, out: NDArray
) -> None:
    """Projections (M, 2) of landmarks ``L`` into ``out`` at one pose.

    NaN where behind the camera or more than ``margin`` px outside the image (as
    :func:`localization.associate.hypotheses.candidate_projections`).
    """
    for j in range(L.shape[0]):
        x, y, z = camera_point(R, t, L, j)
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
    """Rounds of PnP and gated re-association of H hypotheses, until their assignments are stable.

    The batch of :meth:`localization.associate.robust.RobustSearch.refine`.

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
            cost = lm_one(K, R[k], t[k], X, uv, w0, 3 if it == 0 else 2, robust * robust, 1e-6)
            if not np.isfinite(cost):
                alive[k] = False
            project_into(K, R[k], t[k], L, width, height, margin, proj)
            assign_one(dg, proj, step_gate * step_gate, np.int64(3), local)
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
            if not np.isfinite(lm_one(K, R[k], t[k], X, uv, w0, np.int64(3), 0.0, 1e-6)):
                alive[k] = False
    return a, R, t, alive


#: The squared distance of a pair with a NaN or infinite coordinate (in :func:`assignment_costs`).
_BIG = 1e12


@njit(cache=True, nogil=True)
def candidates(
    K: NDArray, T: NDArray, L: NDArray, width: int, height: int, margin: float
) -> tuple[NDArray, NDArray]:
    """``(idx (k,), uv (k, 2))``: the landmarks ``L`` (M, 3) in front of ``T`` and near the image.

    In front: depth above ``MIN_DEPTH``; near: within ``margin`` px of the image rectangle
    ``[-0.5, width - 0.5] x [-0.5, height - 0.5]`` (:func:`localization.associate.paper.candidate_landmarks`).
    """
    m = L.shape[0]
    idx = np.empty(m, dtype=np.int64)
    uv = np.empty((m, 2))
    k = 0
    for j in range(m):
        x = L[j, 0] * T[0, 0] + L[j, 1] * T[0, 1] + L[j, 2] * T[0, 2] + T[0, 3]
        y = L[j, 0] * T[1, 0] + L[j, 1] * T[1, 1] + L[j, 2] * T[1, 2] + T[1, 3]
        z = L[j, 0] * T[2, 0] + L[j, 1] * T[2, 1] + L[j, 2] * T[2, 2] + T[2, 3]
        if not z > MIN_DEPTH:
            continue
        xs, ys = x / z, y / z
        u = xs * K[0, 0] + ys * K[0, 1] + K[0, 2]
        v = xs * K[1, 0] + ys * K[1, 1] + K[1, 2]
        if not (np.isfinite(u) and np.isfinite(v)):
            continue
        if -0.5 - margin <= u <= width - 0.5 + margin and -0.5 - margin <= v <= height - 0.5 + margin:
            idx[k] = j
            uv[k, 0] = u
            uv[k, 1] = v
            k += 1
    return idx[:k].copy(), uv[:k].copy()


@njit(cache=True, nogil=True)
def assignment_costs(det: NDArray, model: NDArray, gate_sq: float, gated: bool) -> NDArray:
    """(N, M) costs of pairing detections ``det`` (N, 2) with projections ``model`` (M, 2).

    The squared distance (``_BIG`` where not finite); ``gated``: that minus ``gate_sq``, capped
    at 0 (:func:`localization.associate.paper.assign` says why).
    """
    cost = pair_sq(det, model)
    for i in range(cost.shape[0]):
        for j in range(cost.shape[1]):
            d2 = cost[i, j] if np.isfinite(cost[i, j]) else _BIG
            cost[i, j] = min(d2 - gate_sq, 0.0) if gated else d2
    return cost


@njit(cache=True, nogil=True)
def assignment_rows(cost: NDArray, rows: NDArray, cols: NDArray, gated: bool) -> NDArray:
    """(N,) the column paired with each row of ``cost`` (N, M), -1 for none, from an assignment.

    ``rows``, ``cols``: ``linear_sum_assignment(cost)``; ``gated``: a pair of cost 0 (beyond the
    gate) is no pair.
    """
    out = np.full(cost.shape[0], -1, dtype=np.int64)
    for k in range(rows.size):
        if not gated or cost[rows[k], cols[k]] < 0.0:
            out[rows[k]] = cols[k]
    return out


def assign_many(
    det: NDArray[np.float64], proj: NDArray[np.float64], gate_px: float, rounds: int = 3
) -> NDArray[np.int64]:
    """(H, N) gated one-to-one assignments of detections (N, 2) to each layout ``proj`` (H, M, 2).

    Greedy by mutual nearest neighbours: a detection and a projection are paired when each is
    the other's nearest and they are within ``gate_px``; paired rows and columns leave, and
    ``rounds`` such passes run. Each pass pairs the globally closest remaining pair, so with
    separated points the result is the minimum-cost assignment
    (:func:`localization.associate.paper.assign`); NaN detections or projections never pair. -1
    marks an unassigned detection.
    """
    f64 = np.float64
    det, proj = kernel_array(det, dtype=f64), kernel_array(proj, dtype=f64)
    if det.ndim != 2 or det.shape[1] != 2 or proj.ndim != 3 or proj.shape[2] != 2:
        raise ValueError(f"assign_many needs det (N, 2) and proj (H, M, 2); got {det.shape} and {proj.shape}")
    return assign_rounds(det, proj, float(gate_px), int(rounds))
