"""Compiled kernels (numba) that make, check and score robust association's hypotheses.

- :func:`shift_votes` -- the Hough vote for image shifts of the layout hypotheses;
- :func:`anchor_pairs` -- the spread-out detections of the two-point hypotheses;
- :func:`upright_starts` -- ranking the upright two-point poses into distinct gated assignments;
- :func:`check_many` -- each refined hypothesis' squared Mahalanobis distance from the prior and
  the chi-square of its pairs;
- :func:`missed_many` -- the landmarks each hypothesis predicts inside the image but left
  unmatched (the miss term of the score);
- :func:`translation_scores` and :func:`rival_translations` -- the winner's pose moved by the
  layout's self-translations, scored against the detections (the rival search of
  :mod:`localization.associate.ambiguity`);
- :func:`warm_hypothesis` -- the warm start's whole hypothesis in one call.

Compiled and cached like :mod:`localization.geometry.kernels`. A constant handed to another
kernel goes as ``np.int64(...)`` / ``np.bool_(...)``: a bare ``3`` or ``False`` would be typed as
a literal and compile that kernel a second time beside its Python callers' ``int64`` / ``bool``.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from localization.associate.assign_kernels import assign_one, project_into, refine_reassign, sq_to
from localization.geometry.kernels import MIN_DEPTH, camera_point
from localization.pose.covariance import prior_distance_sq

__all__ = [
    "anchor_pairs",
    "best_cells",
    "check_many",
    "distinct_cells",
    "median_inplace",
    "MAX_GRID",
    "missed_many",
    "neighbour_votes",
    "rival_translations",
    "shift_votes",
    "translation_scores",
    "upright_starts",
    "warm_hypothesis",
]


#: Most cells of the dense vote grid; a sparser spread of cells is voted by binary search.
MAX_GRID = 1 << 20


@njit(cache=True, nogil=True)
def neighbour_votes(ux: NDArray, uy: NDArray, cnt: NDArray) -> NDArray:
    """Per distinct cell ``(ux, uy)`` (sorted by x, then y) the counts of its 3 x 3 neighbourhood."""
    nu = ux.size
    votes = np.zeros(nu, dtype=np.int64)
    x0, y0, y1 = ux[0], uy.min(), uy.max()
    gw, gh = ux[nu - 1] - x0 + 3, y1 - y0 + 3
    if gw * gh <= MAX_GRID:  # a dense grid with a border of empty cells
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
def distinct_cells(cx: NDArray, cy: NDArray, p: int) -> tuple[NDArray, NDArray, NDArray, NDArray, int]:
    """The distinct cells among the first ``p`` of ``(cx, cy)``, sorted by x, then y.

    Returns ``(ux, uy, cnt, cell, nu)``: the ``nu`` distinct cells (``ux[:nu]``, ``uy[:nu]``),
    the proposals in each (``cnt[:nu]``) and each proposal's cell index (``cell[:p]``). A
    counting sort over the cells' bounding box when it holds at most :data:`MAX_GRID` cells
    (two passes over the proposals), else a sort of the cell keys.
    """
    ux = np.empty(p, dtype=np.int64)
    uy = np.empty(p, dtype=np.int64)
    cnt = np.zeros(p, dtype=np.int64)
    cell = np.empty(p, dtype=np.int64)
    x0, x1, y0, y1 = cx[0], cx[0], cy[0], cy[0]
    for e in range(1, p):
        x0, x1 = min(x0, cx[e]), max(x1, cx[e])
        y0, y1 = min(y0, cy[e]), max(y1, cy[e])
    gw, gh = x1 - x0 + 1, y1 - y0 + 1
    nu = 0
    if gw * gh <= MAX_GRID:
        index = np.zeros(gw * gh, dtype=np.int64)  # proposals per cell, then each cell's rank + 1
        for e in range(p):
            index[(cx[e] - x0) * gh + cy[e] - y0] += 1
        for g in range(gw * gh):
            if index[g] > 0:
                ux[nu], uy[nu], cnt[nu] = x0 + g // gh, y0 + g % gh, index[g]
                nu += 1
                index[g] = nu
        for e in range(p):
            cell[e] = index[(cx[e] - x0) * gh + cy[e] - y0] - 1
        return ux, uy, cnt, cell, nu
    order = np.argsort(cx[:p] * (np.int64(1) << 32) + cy[:p])  # equal keys: one cell, any order
    for r in range(p):
        e = order[r]
        if nu == 0 or cx[e] != ux[nu - 1] or cy[e] != uy[nu - 1]:
            ux[nu], uy[nu] = cx[e], cy[e]
            nu += 1
        cell[e] = nu - 1
        cnt[nu - 1] += 1
    return ux, uy, cnt, cell, nu


@njit(cache=True, nogil=True)
def best_cells(votes: NDArray, k: int) -> NDArray:
    """The indices of the ``k`` largest ``votes`` (ties: the lower index), largest first.

    ``np.argsort(-votes * n + arange(n))[:k]`` by ``k`` passes over the votes, not a sort.
    """
    n = votes.size
    k = min(k, n)
    out = np.empty(k, dtype=np.int64)
    taken = np.zeros(n, dtype=np.bool_)
    for r in range(k):
        b = -1
        for c in range(n):
            if not taken[c] and (b < 0 or votes[c] > votes[b]):
                b = c
        out[r] = b
        taken[b] = True
    return out


@njit(cache=True, nogil=True)
def shift_votes(det: NDArray, proj: NDArray, vote_px: float, k: int) -> tuple[NDArray, NDArray]:
    """The ``k`` best-voted image shifts of each layout ``proj`` (L, M, 2) onto ``det`` (N, 2).

    The vote of :func:`localization.associate.hypotheses.layout_shift_votes`: every (detection,
    projection) pair proposes a shift, binned in cells of ``vote_px`` (cell ``floor(shift /
    vote_px)``); a cell's vote is the number of proposals in it and its eight neighbours
    (:func:`neighbour_votes`). Per layout the ``k`` cells of most votes (ties: the lower cell, x
    then y), each giving the mean of the layout's proposals within ``vote_px`` of its own
    proposals' mean (or that mean if none). NaN projections propose nothing.

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
        p = np.int64(0)
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
        ux, uy, cnt, cell, nu = distinct_cells(cx, cy, p)
        sumx = np.zeros(nu)
        sumy = np.zeros(nu)
        for e in range(p):
            sumx[cell[e]] += sx[e]
            sumy[cell[e]] += sy[e]
        votes = neighbour_votes(ux[:nu], uy[:nu], cnt[:nu])
        best = best_cells(votes[:nu], k)  # most votes, then the lower cell
        for r in range(best.size):
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

    Poses (the ``S`` of :func:`localization.associate.upright.score_upright_poses`, their candidates'
    projections ``uv`` (S, m, 2)) ranked by detections ``explained`` (most first), then
    ``misfit``, then ``prior_sq``; of those explaining ``min_pairs`` or more, the best ``keep``
    give gated assignments (:func:`~localization.associate.assign_kernels.assign_many`
    at ``gate_px``, 3 rounds) of
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
        assign_one(det, uv[s], gate_sq, np.int64(3), local)
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
def _distinct_translations(
    L: NDArray, anchors: NDArray, centre: NDArray, prior_centre: NDArray, sigma: NDArray, max_sq: float
) -> tuple[NDArray, NDArray]:
    """The distinct translations from ``anchors`` to every landmark that keep the camera near the prior.

    ``X_j - X_a`` rounded to 1 mm, in lexicographic order, the zero one dropped; kept when the
    camera ``centre`` moved by it is within ``max_sq`` (squared Mahalanobis, position ``sigma``)
    of ``prior_centre``. Returns ``(t (k, 3), prior_sq (k,))``.
    """
    m = L.shape[0]
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
    return t[:k].copy(), prior_sq[:k].copy()


@njit(cache=True, nogil=True)
def _in_camera_frame(L: NDArray, R: NDArray, centre: NDArray, t: NDArray) -> tuple[NDArray, NDArray]:
    """The landmarks ``L`` (M, 3) in the frame of camera ``R``, ``centre``, and each ``t`` (k, 3) in it."""
    m, k = L.shape[0], t.shape[0]
    p = np.empty((m, 3))
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
    return p, shift


@njit(cache=True, nogil=True)
def _first_explaining(ranked: NDArray, explained: NDArray, need: int, limit: int) -> NDArray:
    """The first (at most ``limit``) of ``ranked`` that explain ``need`` detections or more."""
    chosen = np.empty(min(ranked.size, max(limit, 0)), dtype=np.int64)
    n_chosen = 0
    for q in ranked:
        if n_chosen == chosen.size:
            break
        if explained[q] >= need:
            chosen[n_chosen] = q
            n_chosen += 1
    return chosen[:n_chosen]


@njit(cache=True, nogil=True)
def rival_translations(
    det: NDArray, L: NDArray, K: NDArray, T: NDArray, anchors: NDArray, prior_centre: NDArray,
    sigma: NDArray, max_sq: float, gate_sq: float, need: int, limit: int,
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """The layout's self-translations that keep a moved winner near the prior, best first.

    The compiled core of :func:`localization.associate.ambiguity.translation_hypotheses`: the
    distinct translations ``X_j - X_a`` (rounded to 1 mm, lexicographic order, the zero one
    dropped) from each landmark index in ``anchors`` to every landmark ``L`` (M, 3); those whose
    moved camera centre is within ``max_sq`` (squared Mahalanobis, position ``sigma`` (3,)) of
    ``prior_centre``; each scored against the finite detections ``det`` (N, 2) from the winner's
    pose ``T`` moved by it (:func:`translation_scores`, cap ``gate_sq``). Those explaining
    ``need`` detections or more, by ``misfit`` then prior distance, at most ``limit``.

    Returns:
        ``(t (R, 3), uv (R, M, 2), depth (R, M), centre (3,))``: the chosen translations, the
        landmarks' projections and depths from each moved camera, the winner's camera centre.
    """
    R = T[:3, :3]
    centre = np.empty(3)
    for c in range(3):
        centre[c] = -(R[0, c] * T[0, 3] + R[1, c] * T[1, 3] + R[2, c] * T[2, 3])
    t, prior_sq = _distinct_translations(L, anchors, centre, prior_centre, sigma, max_sq)
    p, shift = _in_camera_frame(L, R, centre, t)
    uv, depth, explained, misfit = translation_scores(det, p, shift, K, gate_sq)
    ranked = _lex_order(misfit, prior_sq, np.zeros(t.shape[0]))
    chosen = _first_explaining(ranked, explained, need, limit)
    return t[chosen], uv[chosen], depth[chosen], centre


#: A projection behind the camera counts as this pixel in the fit of :func:`check_many`.
_BEHIND_PX = 1e6


#: A projection behind the camera lies this far off every detection (:func:`translation_scores`).
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

    ``prior_sq`` and ``far`` are :func:`localization.pose.covariance.prior_distance_sq`'s. ``chi`` is
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
            x, y, z = camera_point(Rh, th, L, j)
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
        project_into(K, R[h], t[h], L, width, height, 0.0, uv)
        hit[:] = False
        for i in range(n):
            if a[h, i] >= 0:
                hit[a[h, i]] = True
        for j in range(L.shape[0]):
            if not np.isnan(uv[j, 0]) and not hit[j]:
                out[h] += 1
    return out


@njit(cache=True, nogil=True)
def _kth_smallest(a: NDArray, k: int) -> float:
    """The ``k``-th smallest of ``a`` (0-based), ``a`` partially reordered (quickselect).

    After the call ``a[:k]`` holds values at most the result (Hoare partitions).
    """
    lo, hi = 0, a.size - 1
    while hi > lo:
        mid = (lo + hi) >> 1
        x, y, z = a[lo], a[mid], a[hi]  # median of three as the pivot
        pivot = max(min(x, y), min(max(x, y), z))
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return a[k]
    return a[k]


@njit(cache=True, nogil=True)
def median_inplace(a: NDArray) -> float:
    """``np.median(a)`` of a non-empty finite ``a``, to the bit, reordering ``a`` (no copy).

    The middle value, or the mean ``(lo + hi) / 2`` of the two middle ones as numba's
    ``np.median`` computes it; order statistics do not depend on how they are selected.
    """
    n = a.size
    half = n >> 1
    hi = _kth_smallest(a, half)
    if n & 1:
        return hi
    lo = a[0]
    for i in range(1, half):  # the largest of the values below the half
        lo = max(lo, a[i])
    return (lo + hi) / 2


@njit(cache=True, nogil=True)
def anchor_pairs(det: NDArray, k: int) -> NDArray:
    """(P, 2) every pair among ``k`` spread-out finite detections (N, 2) of the dense part of the image.

    The spread-out part of :func:`localization.associate.hypotheses.spread_anchor_pairs` (whose
    docstring says why): detections whose median squared distance to the others is at most the
    median of that (at least ``k`` of them, the least spread out), then farthest-point selection
    starting from the one with the largest sum of squared distances; pairs in selection order.
    """
    n = det.shape[0]
    if n < 2:
        return np.empty((0, 2), dtype=np.int64)
    if n > k:
        spread = np.empty(n)
        row = np.empty(n)
        for i in range(n):  # one row at a time: no (N, N) matrix, selected in place
            for j in range(n):
                row[j] = sq_to(det, i, det[j, 0], det[j, 1])
            spread[i] = median_inplace(row)
        pool = np.flatnonzero(spread <= np.median(spread))
        if pool.size < k:
            pool = np.argsort(spread, kind="mergesort")[:k]
    else:
        pool = np.arange(n)
    p = pool.size
    sub = np.empty((p, p))
    for i in range(p):
        for j in range(p):
            sub[i, j] = sq_to(det, pool[i], det[pool[j], 0], det[pool[j], 1])
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


#: Up to this squared cap the nearest projections are searched in a window of u (a projection
#: behind the camera, at ``_FAR_PX``, is then always beyond the cap); above it, all of them.
_WINDOW_MAX_CAP_SQ = 0.25 * _FAR_PX**2


@njit(cache=True, nogil=True)
def _nearest_brute(det: NDArray, uv: NDArray, near: NDArray) -> None:
    """Into ``near`` (N,) each detection's squared distance to the nearest projection of ``uv``.

    ``uv`` (M, 2); a NaN projection counts as one at (``_FAR_PX``, ``_FAR_PX``).
    """
    for i in range(det.shape[0]):
        best = np.inf
        for j in range(uv.shape[0]):
            far = np.isnan(uv[j, 0])
            d = sq_to(det, i, _FAR_PX if far else uv[j, 0], _FAR_PX if far else uv[j, 1])
            if d < best:  # not min(): a NaN detection keeps inf, as before
                best = d
        near[i] = best


@njit(cache=True, nogil=True)
def _nearest_in_window(det: NDArray, uv: NDArray, cap_sq: float, order: NDArray, near: NDArray) -> None:
    """:func:`_nearest_brute` where it is below ``cap_sq``, else a value at or above it.

    Only the finite projections within ``sqrt(cap_sq)`` in u of a detection are measured (sorted
    by u, found by binary search; the window a part in 1e9 wider, so that rounding never drops
    one inside the cap): any other lies at least the cap away, and the caller caps. The
    distances are computed as :func:`_nearest_brute` computes them: the capped values agree to
    the bit. ``order`` (M,): workspace.
    """
    cap = np.sqrt(cap_sq) * (1.0 + 1e-9)
    k = 0
    for j in range(uv.shape[0]):
        if not np.isnan(uv[j, 0]):
            order[k] = j
            k += 1
    us = np.empty(k)
    for r in range(k):
        us[r] = uv[order[r], 0]
    srt = np.argsort(us, kind="mergesort")
    for i in range(det.shape[0]):
        u0 = det[i, 0] - cap
        lo, hi = 0, k  # first projection with u >= u0
        while lo < hi:
            mid = (lo + hi) // 2
            if us[srt[mid]] < u0:
                lo = mid + 1
            else:
                hi = mid
        best = np.inf
        for r in range(lo, k):
            j = order[srt[r]]
            if uv[j, 0] > det[i, 0] + cap:
                break
            d = sq_to(det, i, uv[j, 0], uv[j, 1])
            if d < best:
                best = d
        near[i] = best


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
        projection, capped at ``cap_sq``.
    """
    n_t, m = shift.shape[0], p.shape[0]
    uv = np.empty((n_t, m, 2))
    depth = np.empty((n_t, m))
    explained = np.zeros(n_t, dtype=np.int64)
    misfit = np.zeros(n_t)
    order = np.empty(m, dtype=np.int64)
    near = np.empty(det.shape[0])
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
        if cap_sq < _WINDOW_MAX_CAP_SQ:
            _nearest_in_window(det, uv[q], cap_sq, order, near)
        else:
            _nearest_brute(det, uv[q], near)
        for i in range(det.shape[0]):
            best = min(near[i], cap_sq)
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
    :func:`~localization.associate.assign_kernels.refine_reassign` does without robust weights.

    Returns:
        ``(a (N,), R, t, alive, prior_sq, far, chi, missed)``: the assignment, the pose, whether
        it survived the refinement, :func:`check_many`'s prior distance, far flag and chi-square
        (px^2), and :func:`missed_many`'s count.
    """
    n = det.shape[0]
    proj = np.empty((L.shape[0], 2))
    project_into(K, R0, t0, L, width, height, margin, proj)
    dg = np.empty((good.size, 2))
    for i in range(good.size):
        dg[i] = det[good[i]]
    local = np.empty(good.size, dtype=np.int64)
    assign_one(dg, proj, (coarse_gate / 4.0) ** 2, np.int64(3), local)
    a0 = np.full((1, n), -1, dtype=np.int64)
    for i in range(good.size):
        a0[0, good[i]] = local[i]
    R1 = np.empty((1, 3, 3))
    R1[0] = R0
    t1 = np.empty((1, 3))
    t1[0] = t0
    a, R, t, alive = refine_reassign(
        K, L, det, good, a0, R1, t1, width, height, margin, gate, coarse_gate, max_iterations, need,
        np.bool_(False),  # typed as the Python callers' bool, not as a literal: one compilation
    )
    prior_sq, chi, far = check_many(K, L, det, a, R, t, prior_R, prior_C, sigmas)
    missed = missed_many(K, L, a, R, t, width, height)
    return a[0], R[0], t[0], alive[0], prior_sq[0], far[0], chi[0], missed[0]
