"""Compiled kernels (numba) of robust association's bookkeeping: checks, scores, anchors, rivals.

After the refinement rounds were compiled (:mod:`localization.compiled`), what remained of
robust association's cost was about a hundred small numpy calls per image that test, score
and rank the hypotheses (1.2 ms median per image in the ``state`` training configuration, most
of it call overhead on arrays of 4-20 points). Here the same computations run as one loop each:

- :func:`check_many` -- each refined hypothesis' squared Mahalanobis distance from the prior
  (:func:`localization.compiled_pose.prior_distance_sq`) and
  the chi-square of its pairs (``associate._Problem.prior_sq`` and ``chi_sq`` before);
- :func:`missed_many` -- the landmarks each hypothesis predicts inside the image that it left
  unmatched (the miss term of the score);
- :func:`anchor_pairs` -- the spread-out detections of the two-point hypotheses
  (``associate._anchor_pairs``);
- :func:`translation_scores` -- the winner's pose moved by each of the layout's
  self-translations, scored against the detections (``ambiguity.translation_hypotheses``);
- :func:`association_counts` -- an assignment's correct, assigned and true detections
  (:func:`localization.metrics.association_scores`, scored for every agent at every step);
- :func:`warm_hypothesis` -- the warm start's whole hypothesis in one call: the predicted pose's
  gated assignment, its refinement with re-association (:func:`~localization.compiled.refine_reassign`),
  its checks and misses (``associate._warm_association``).

They replace numpy code with the same arithmetic (before the commit that added this module):
on the 2,400 localizations of the localizer benchmark's images and 606 association calls
captured in the ``state`` training configuration, every success, assignment and failure reason
is the same. Compiled and cached like :mod:`localization.compiled`.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from localization.compiled import MIN_DEPTH, _assign_one, _candidates, _point, refine_reassign
from localization.compiled_pose import prior_distance_sq

__all__ = [
    "anchor_pairs",
    "association_counts",
    "check_many",
    "missed_many",
    "translation_scores",
    "warm_hypothesis",
]

#: A projection behind the camera counts as this pixel (``np.nan_to_num(nan=1e6)`` before).
_BEHIND_PX = 1e6
#: A projection behind the camera lies this far off every detection (``batch._FAR_PX``).
_FAR_PX = 1e9


@njit(cache=True, nogil=True)
def check_many(
    K: NDArray, L: NDArray, det: NDArray, a: NDArray, R: NDArray, t: NDArray,
    prior_R: NDArray, prior_C: NDArray, sigmas: NDArray,
) -> tuple[NDArray, NDArray, NDArray]:
    """Prior distance and fit of H hypotheses: ``(prior_sq (H,), chi (H,), far (H,))``.

    Args:
        K: (3, 3) intrinsics.
        L: (M, 3) landmarks.
        det: (N, 2) detections (assigned rows are finite).
        a: (H, N) landmark of each detection, -1 when unassigned.
        R: (H, 3, 3) the hypotheses' ``cam_from_world`` rotations.
        t: (H, 3) their translations.
        prior_R: (3, 3) the prior's rotation.
        prior_C: (3,) the prior's camera centre.
        sigmas: (6,) the prior's sigmas (position m, rotation rad).

    ``prior_sq`` and ``far`` are :func:`localization.compiled_pose.prior_distance_sq`'s. ``chi`` is
    the sum of squared residuals of the pairs, px^2 (a point at or behind the camera counts as
    projecting at (1e6, 1e6) px).
    """
    h_n, n = a.shape
    prior_sq = np.empty(h_n)
    chi = np.empty(h_n)
    far = np.zeros(h_n, dtype=np.bool_)
    for h in range(h_n):
        Rh = R[h]
        th = t[h]
        prior_sq[h], far[h] = prior_distance_sq(Rh, th, prior_R, prior_C, sigmas)
        total = 0.0
        for i in range(n):
            j = a[h, i]
            if j < 0:
                continue
            x, y, z = _point(Rh, th, L, j)
            if z > MIN_DEPTH:
                u = (K[0, 0] * x + K[0, 1] * y) / z + K[0, 2]
                v = K[1, 1] * y / z + K[1, 2]
            else:
                u = _BEHIND_PX
                v = _BEHIND_PX
            total += (u - det[i, 0]) ** 2 + (v - det[i, 1]) ** 2
        chi[h] = total
    return prior_sq, chi, far


@njit(cache=True, nogil=True)
def missed_many(
    K: NDArray, L: NDArray, a: NDArray, R: NDArray, t: NDArray, width: int, height: int
) -> NDArray:
    """(H,) landmarks each hypothesis projects inside the image (in front) and leaves unassigned."""
    h_n, n = a.shape
    out = np.zeros(h_n, dtype=np.int64)
    uv = np.empty((L.shape[0], 2))
    hit = np.zeros(L.shape[0], dtype=np.bool_)
    for h in range(h_n):
        _candidates(K, R[h], t[h], L, width, height, 0.0, uv)
        hit[:] = False
        for i in range(n):
            if a[h, i] >= 0:
                hit[a[h, i]] = True
        for j in range(L.shape[0]):
            if not np.isnan(uv[j, 0]) and not hit[j]:
                out[h] += 1
    return out


@njit(cache=True, nogil=True)
def anchor_pairs(det: NDArray, k: int) -> NDArray:
    """(P, 2) every pair among ``k`` spread-out detections (N, 2) of the dense part of the image.

    The algorithm of ``associate._anchor_pairs`` (whose docstring says why): detections whose
    median squared distance to the others is at most the median of that (at least ``k`` of
    them, the least spread out), then farthest-point selection starting from the one with the
    largest sum of squared distances; pairs in selection order.
    """
    n = det.shape[0]
    if n < 2:
        return np.empty((0, 2), dtype=np.int64)
    d2 = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            du = det[i, 0] - det[j, 0]
            dv = det[i, 1] - det[j, 1]
            d2[i, j] = du * du + dv * dv
    if n > k:
        spread = np.empty(n)
        for i in range(n):
            spread[i] = np.median(d2[i])
        pool = np.flatnonzero(spread <= np.median(spread))
        if pool.size < k:
            pool = np.argsort(spread, kind="mergesort")[:k]
    else:
        pool = np.arange(n)
    p = pool.size
    sub = np.empty((p, p))
    for i in range(p):
        for j in range(p):
            sub[i, j] = d2[pool[i], pool[j]]
    chosen = np.empty(min(k, p), dtype=np.int64)
    chosen[0] = np.argmax(sub.sum(axis=1))
    dmin = sub[chosen[0]].copy()
    for c in range(1, chosen.size):
        chosen[c] = np.argmax(dmin)
        for j in range(p):
            dmin[j] = min(dmin[j], sub[chosen[c], j])
    m = chosen.size
    out = np.empty((m * (m - 1) // 2, 2), dtype=np.int64)
    r = 0
    for i in range(m):
        for j in range(i + 1, m):
            out[r, 0] = pool[chosen[i]]
            out[r, 1] = pool[chosen[j]]
            r += 1
    return out


@njit(cache=True, nogil=True)
def translation_scores(
    det: NDArray, p: NDArray, shift: NDArray, K: NDArray, cap_sq: float
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """The layout seen from T moved cameras, scored against the detections.

    Args:
        det: (N, 2) finite detections.
        p: (M, 3) camera-frame landmarks at the winner's pose.
        shift: (T, 3) each translation in the camera frame (``t R^T``).
        K: (3, 3) intrinsics.
        cap_sq: squared gate.

    Returns:
        ``(uv (T, M, 2), depth (T, M), explained (T,), misfit (T,))``: projections (NaN at or
        behind the camera) and depths after each move; how many detections have a projection
        within the gate; and the sum over detections of the squared distance to the nearest
        projection, capped at ``cap_sq`` (as ``batch.capped_nearest_sq``).
    """
    n_t, m = shift.shape[0], p.shape[0]
    uv = np.empty((n_t, m, 2))
    depth = np.empty((n_t, m))
    explained = np.zeros(n_t, dtype=np.int64)
    misfit = np.zeros(n_t)
    for q in range(n_t):
        for j in range(m):
            x = p[j, 0] - shift[q, 0]
            y = p[j, 1] - shift[q, 1]
            z = p[j, 2] - shift[q, 2]
            depth[q, j] = z
            if z > MIN_DEPTH:
                xs, ys = x / z, y / z
                uv[q, j, 0] = xs * K[0, 0] + ys * K[0, 1] + K[0, 2]
                uv[q, j, 1] = xs * K[1, 0] + ys * K[1, 1] + K[1, 2]
            else:
                uv[q, j, 0] = np.nan
                uv[q, j, 1] = np.nan
        for i in range(det.shape[0]):
            best = np.inf
            for j in range(m):
                if np.isnan(uv[q, j, 0]):
                    du = det[i, 0] - _FAR_PX
                    dv = det[i, 1] - _FAR_PX
                else:
                    du = det[i, 0] - uv[q, j, 0]
                    dv = det[i, 1] - uv[q, j, 1]
                d = du * du + dv * dv
                if d < best:
                    best = d
            best = min(best, cap_sq)
            if best < cap_sq:
                explained[q] += 1
            misfit[q] += best
    return uv, depth, explained, misfit


@njit(cache=True, nogil=True)
def warm_hypothesis(
    K: NDArray, L: NDArray, det: NDArray, good: NDArray, R0: NDArray, t0: NDArray,
    width: int, height: int, margin: float, gate: float, coarse_gate: float, max_iterations: int,
    need: int, prior_R: NDArray, prior_C: NDArray, sigmas: NDArray,
) -> tuple[NDArray, NDArray, NDArray, bool, float, bool, float, int]:
    """One hypothesis from a predicted pose ``R0`` (3, 3), ``t0`` (3,), refined and checked.

    The landmarks projected at the prediction are paired with the finite detections ``good``
    within ``coarse_gate / 4`` (mutual nearest neighbours), then refined and re-associated as
    :func:`~localization.compiled.refine_reassign` does without robust weights.

    Returns:
        ``(a (N,), R, t, alive, prior_sq, far, chi, missed)``: the assignment, the pose, whether
        it survived the refinement, :func:`check_many`'s prior distance, far flag and chi-square
        (px^2), and :func:`missed_many`'s count.
    """
    n = det.shape[0]
    proj = np.empty((L.shape[0], 2))
    _candidates(K, R0, t0, L, width, height, margin, proj)
    dg = np.empty((good.size, 2))
    for i in range(good.size):
        dg[i] = det[good[i]]
    local = np.empty(good.size, dtype=np.int64)
    _assign_one(dg, proj, (coarse_gate / 4.0) ** 2, 3, local)
    a0 = np.full((1, n), -1, dtype=np.int64)
    for i in range(good.size):
        a0[0, good[i]] = local[i]
    R1 = np.empty((1, 3, 3))
    R1[0] = R0
    t1 = np.empty((1, 3))
    t1[0] = t0
    a, R, t, alive = refine_reassign(
        K, L, det, good, a0, R1, t1, width, height, margin, gate, coarse_gate, max_iterations, need, False
    )
    prior_sq, chi, far = check_many(K, L, det, a, R, t, prior_R, prior_C, sigmas)
    missed = missed_many(K, L, a, R, t, width, height)
    return a[0], R[0], t[0], alive[0], prior_sq[0], far[0], chi[0], missed[0]


@njit(cache=True, nogil=True)
def association_counts(a: NDArray, true_ids: NDArray, model_ids: NDArray) -> tuple[int, int, int]:
    """``(correct, assigned, true_detections)`` of assignment ``a`` (N,) (model index or -1).

    ``true_ids`` (N,) the true landmark id of each detection (-1: clutter); ``model_ids`` (M,)
    the id of each model index. A pair is correct when its model id is the detection's true id.
    """
    correct = 0
    assigned = 0
    true_det = 0
    for i in range(a.size):
        if true_ids[i] >= 0:
            true_det += 1
        if a[i] >= 0:
            assigned += 1
            if true_ids[i] >= 0 and model_ids[a[i]] == true_ids[i]:
                correct += 1
    return correct, assigned, true_det
