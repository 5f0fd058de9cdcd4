"""Compiled kernels (numba) of robust association's per-frame selection: candidates, starts, rivals.

With the refinement rounds (:mod:`localization.compiled`) and the bookkeeping
(:mod:`localization.compiled_scores`) compiled, a ``state`` training step's association still
spent about 0.4 of its 0.94 ms per image in the numpy code between the kernels (timed around
each call), most of it in places that run once or twice per image on 4-20 points: projecting
the landmarks to find the candidates near the image, ranking the upright two-point poses and
turning the best into distinct gated assignments, building, ranking and gating the layout's
self-translations of the rival search, and the cost matrix of the exact assignment. Here each is
one compiled function with the algorithm it replaces:

- :func:`candidates` -- ``associate.candidate_landmarks`` (and the projection of
  ``geometry.project``);
- :func:`upright_starts` -- the ranking and distinct-assignment loop of
  ``associate._upright_hypotheses``;
- :func:`rival_translations` -- ``ambiguity.translation_hypotheses`` up to its list of moved
  poses;
- :func:`assignment_costs` and :func:`assignment_rows` -- the cost matrix of
  ``associate.assign`` and the assignment read from scipy's ``linear_sum_assignment`` (which
  stays: it is 1 us of the 14 us the numpy code took).

They replace numpy code with the same arithmetic (before the commit that added this module):
with the first three, every success, assignment, failure reason and hypothesis count of the
4,000 localizations of the localizer benchmark's cases was the same and every pose
bit-identical, and the wrapped ``state`` configuration's observations, rewards and infos over
seeded runs agreed within 1e-7 relative (the comparison's tolerance);
tests/localization/test_compiled_frame.py compares each kernel with the numpy code (the
assignments exactly). Compiled and cached like :mod:`localization.compiled`.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from localization.compiled import MIN_DEPTH, _assign_one, pair_sq
from localization.compiled_scores import translation_scores

__all__ = ["assignment_costs", "assignment_rows", "candidates", "rival_translations", "upright_starts"]

#: The squared distance of a pair with a NaN or infinite coordinate (``associate.assign``'s).
_BIG = 1e12


@njit(cache=True, nogil=True)
def candidates(
    K: NDArray, T: NDArray, L: NDArray, width: int, height: int, margin: float
) -> tuple[NDArray, NDArray]:
    """``(idx (k,), uv (k, 2))``: the landmarks ``L`` (M, 3) in front of ``T`` and near the image.

    In front: depth above ``MIN_DEPTH``; near: within ``margin`` px of the image rectangle
    ``[-0.5, width - 0.5] x [-0.5, height - 0.5]`` (``associate.candidate_landmarks``).
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
def _lex_order(primary: NDArray, secondary: NDArray, tertiary: NDArray) -> NDArray:
    """``np.lexsort((tertiary, secondary, primary))``: stable, by ``primary`` first."""
    order = np.argsort(tertiary, kind="mergesort")
    order = order[np.argsort(secondary[order], kind="mergesort")]
    return order[np.argsort(primary[order], kind="mergesort")]


@njit(cache=True, nogil=True)
def upright_starts(
    det: NDArray, idx: NDArray, uv: NDArray, prior_sq: NDArray, explained: NDArray, misfit: NDArray,
    gate_px: float, min_pairs: int, keep: int, n_distinct: int,
) -> tuple[NDArray, NDArray]:
    """The distinct gated assignments of the best upright poses: ``(a (D, N), pose index (D,))``.

    Poses (the ``S`` of :func:`localization.upright.score_upright_poses`, their candidates'
    projections ``uv`` (S, m, 2)) ranked by detections ``explained`` (most first), then
    ``misfit``, then ``prior_sq``; of those explaining ``min_pairs`` or more, the best ``keep``
    give gated assignments (:func:`localization.batch.assign_many` at ``gate_px``, 3 rounds) of
    the detections ``det`` (N, 2) into landmark indices ``idx`` (m,), assigned block by block
    (the first ``n_distinct + n_distinct // 2`` poses, then the rest) until ``n_distinct``
    distinct ones with ``min_pairs`` pairs or more are found. At most ``n_distinct`` rows, best
    first.
    """
    n = det.shape[0]
    neg = np.empty(explained.size)
    for s in range(explained.size):
        neg[s] = -explained[s]
    ranked = _lex_order(neg, misfit, prior_sq)
    order = np.empty(ranked.size, dtype=np.int64)
    k = 0
    for s in ranked:
        if explained[s] >= min_pairs and k < keep:
            order[k] = s
            k += 1
    out = np.empty((max(n_distinct, 0), n), dtype=np.int64)
    pose = np.empty(max(n_distinct, 0), dtype=np.int64)
    found = 0
    local = np.empty(n, dtype=np.int64)
    a = np.empty(n, dtype=np.int64)
    gate_sq = gate_px * gate_px
    for q in range(k):
        if found == n_distinct:
            break
        s = order[q]
        _assign_one(det, uv[s], gate_sq, 3, local)
        pairs = 0
        for i in range(n):
            a[i] = idx[local[i]] if local[i] >= 0 else -1
            if a[i] >= 0:
                pairs += 1
        if pairs < min_pairs:
            continue
        seen = False
        for r in range(found):
            same = True
            for i in range(n):
                if out[r, i] != a[i]:
                    same = False
                    break
            if same:
                seen = True
                break
        if seen:
            continue
        out[found] = a
        pose[found] = s
        found += 1
    return out[:found].copy(), pose[:found].copy()


@njit(cache=True, nogil=True)
def rival_translations(
    det: NDArray, L: NDArray, K: NDArray, T: NDArray, anchors: NDArray, prior_centre: NDArray,
    sigma: NDArray, max_sq: float, gate_sq: float, need: int, limit: int,
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """The layout's self-translations that keep a moved winner near the prior, best first.

    ``ambiguity.translation_hypotheses`` up to its list: the distinct translations ``X_j -
    X_a`` (rounded to 1 mm, lexicographic order, the zero one dropped) from each landmark index
    in ``anchors`` to every landmark ``L`` (M, 3); those whose moved camera centre is within
    ``max_sq`` (squared Mahalanobis, position ``sigma`` (3,)) of ``prior_centre``; each scored
    against the finite detections ``det`` (N, 2) from the winner's pose ``T`` moved by it
    (:func:`localization.compiled_scores.translation_scores`, cap ``gate_sq``). Those explaining
    ``need`` detections or more, by ``misfit`` then prior distance, at most ``limit``.

    Returns:
        ``(t (R, 3), uv (R, M, 2), depth (R, M), centre (3,))``: the chosen translations, the
        landmarks' projections and depths from each moved camera, the winner's camera centre.
    """
    m = L.shape[0]
    R = T[:3, :3]
    centre = np.empty(3)
    for c in range(3):
        centre[c] = -(R[0, c] * T[0, 3] + R[1, c] * T[1, 3] + R[2, c] * T[2, 3])
    n_all = anchors.size * m
    raw = np.empty((n_all, 3))
    for p in range(anchors.size):
        for j in range(m):
            for c in range(3):
                raw[p * m + j, c] = np.rint((L[j, c] - L[anchors[p], c]) * 1000.0) / 1000.0  # np.round(., 3)
    order = _lex_order(raw[:, 0].copy(), raw[:, 1].copy(), raw[:, 2].copy())
    t = np.empty((n_all, 3))
    prior_sq = np.empty(n_all)
    k = 0
    for q in range(n_all):
        r = order[q]
        if q > 0:
            prev = order[q - 1]
            if raw[r, 0] == raw[prev, 0] and raw[r, 1] == raw[prev, 1] and raw[r, 2] == raw[prev, 2]:
                continue
        if not np.sqrt(raw[r, 0] ** 2 + raw[r, 1] ** 2 + raw[r, 2] ** 2) > 1e-3:
            continue
        d = 0.0
        for c in range(3):
            e = (centre[c] + raw[r, c] - prior_centre[c]) / sigma[c]
            d += e * e
        if not d <= max_sq:
            continue
        t[k] = raw[r]
        prior_sq[k] = d
        k += 1
    t = t[:k].copy()
    p = np.empty((m, 3))  # the landmarks in the winner's camera frame, and each t in it
    for j in range(m):
        for c in range(3):
            p[j, c] = (
                (L[j, 0] - centre[0]) * R[c, 0] + (L[j, 1] - centre[1]) * R[c, 1]
                + (L[j, 2] - centre[2]) * R[c, 2]
            )
    shift = np.empty((k, 3))
    for q in range(k):
        for c in range(3):
            shift[q, c] = t[q, 0] * R[c, 0] + t[q, 1] * R[c, 1] + t[q, 2] * R[c, 2]
    uv, depth, explained, misfit = translation_scores(det, p, shift, K, gate_sq)
    ranked = _lex_order(misfit, prior_sq[:k].copy(), np.zeros(k))
    chosen = np.empty(min(k, max(limit, 0)), dtype=np.int64)
    n_chosen = 0
    for q in ranked:
        if n_chosen == chosen.size:
            break
        if explained[q] >= need:
            chosen[n_chosen] = q
            n_chosen += 1
    chosen = chosen[:n_chosen]
    return t[chosen], uv[chosen], depth[chosen], centre


@njit(cache=True, nogil=True)
def assignment_costs(det: NDArray, model: NDArray, gate_sq: float, gated: bool) -> NDArray:
    """(N, M) costs of pairing detections ``det`` (N, 2) with projections ``model`` (M, 2).

    The squared distance (``_BIG`` where not finite); ``gated``: that minus ``gate_sq``, capped
    at 0 (``associate.assign`` says why).
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
