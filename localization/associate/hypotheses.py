"""Where robust association starts: identity hypotheses from the layout of the detections.

Three sources of starting hypotheses for :mod:`localization.associate.robust`:

- :func:`upright_hypotheses` -- with the prior's tilt, two correspondences fix the pose in
  closed form (:mod:`localization.associate.upright`); spread-out anchor pairs of detections
  (:func:`spread_anchor_pairs`) against ordered pairs of candidate landmarks give the poses,
  ranked and turned into distinct gated assignments;
- :func:`layout_hypotheses` -- the prior camera centre moved on a grid of sigmas, and for each,
  every (detection, projected landmark) pair proposes a 2D shift ranked by how many other pairs
  agree with it (a Hough vote, :func:`layout_shift_votes`);
- :func:`exhaustive_hypotheses` -- small problems (a slab's four corners) enumerate every
  one-to-one assignment;

and one source of rivals: :func:`regrowth_hypotheses` -- a hypothesis' own pairs, two at a time,
with its tilt, grown as the upright poses are.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numpy.typing import NDArray

from localization.associate.assign_kernels import assign_many
from localization.associate.hypothesis_kernels import anchor_pairs, shift_votes, upright_starts
from localization.associate.upright import score_samples, score_upright_poses
from localization.geometry.kernels import kernel_array, residuals
from localization.geometry.transforms import camera_center, inverse_intrinsics
from localization.pose.batch import project_many, rotation_between, to_transforms
from localization.pose.covariance import PriorSigmas, prior_mahalanobis_sq
from localization.pose.pnp import (
    ippe_candidates,
    is_coplanar,
    planar_points,
    pnp_candidates,
)

__all__ = [
    "candidate_projections",
    "exhaustive_hypotheses",
    "layout_hypotheses",
    "layout_shift_votes",
    "regrowth_hypotheses",
    "spread_anchor_pairs",
    "upright_hypotheses",
]

#: Most pairs of a hypothesis that :func:`regrowth_hypotheses` combines two at a time (66 samples).
REGROWTH_PAIRS = 12


def layout_shift_votes(
    det: NDArray, proj: NDArray, vote_px: float, k: int
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The ``k`` best-voted image shifts of each layout ``proj`` (L, M, 2) onto ``det`` (N, 2).

    Every (detection, projection) pair proposes a shift; shifts are binned in cells of
    ``vote_px`` and a cell's vote is the number of shifts in it and its eight neighbours (a Hough
    vote, O(L N M); compiled, :func:`~localization.associate.hypothesis_kernels.shift_votes`).
    Each returned shift is the mean of the layout's proposals within ``vote_px`` of its cell's
    mean. NaN projections propose nothing. Returns ``(layout index (S,), shift (S, 2))``, each
    layout's best first.
    """
    f64 = np.float64
    det, proj = kernel_array(det, dtype=f64), kernel_array(proj, dtype=f64)
    return shift_votes(det, proj, float(vote_px), int(k))


def candidate_projections(
    K: NDArray, R: NDArray, t: NDArray, landmarks_xyz: NDArray, image_size: tuple[int, int], margin_px: float
) -> NDArray[np.float64]:
    """(H, M, 2) projections at H poses, NaN where :func:`candidate_landmarks` would drop one."""
    uv, _ = project_many(K, R, t, landmarks_xyz)
    w, h = image_size
    with np.errstate(invalid="ignore"):
        ok = (uv[..., 0] >= -0.5 - margin_px) & (uv[..., 0] <= w - 0.5 + margin_px)
        ok &= (uv[..., 1] >= -0.5 - margin_px) & (uv[..., 1] <= h - 0.5 + margin_px)
    uv[~ok] = np.nan
    return uv


def layout_hypotheses(
    det: NDArray,
    landmarks_xyz: NDArray,
    K: NDArray,
    prior: NDArray,
    image_size: tuple[int, int],
    margin_px: float,
    sig: PriorSigmas,
    offsets: tuple[tuple[float, float, float], ...],
    gate_px: float,
    k: int,
    min_pairs: int,
) -> list[tuple[tuple, NDArray, NDArray]]:
    """Coarse assignments from perturbed priors, each shifted by its best-voted image shifts.

    The prior camera centre is moved by each of ``offsets`` (in units of the prior's position
    sigmas; the perspective and scale change that a shift cannot model), the landmarks
    re-projected, and the projection shifted by zero and by its ``k`` best-voted shifts (the
    attitude error, which mostly shifts the image). Each shifted layout gives a gated assignment
    (``gate_px``); its shift is re-centred on the matched pairs once and the layout re-assigned;
    layouts with fewer than ``min_pairs`` pairs are dropped. All layouts go through the same
    numpy calls at once. Returns ``[(rank key, assignment of det rows (N,) into landmarks,
    start cam_from_world (4, 4)), ...]``, best first: more matches, then smaller mean squared
    distance, then smaller perturbation. The start pose is the moved prior turned so that the
    layout's matched projections move by the shift.
    """
    o = np.asarray(offsets, dtype=np.float64).reshape(-1, 3)
    centres = camera_center(prior) + o * np.asarray(sig.position_m, dtype=np.float64)
    R = np.broadcast_to(prior[:3, :3], (o.shape[0], 3, 3))
    t = -np.einsum("ij,hj->hi", prior[:3, :3], centres)
    proj = candidate_projections(K, R, t, landmarks_xyz, image_size, margin_px)
    lay_v, shift_v = layout_shift_votes(det, proj, gate_px, k)
    lay = np.concatenate([np.arange(o.shape[0]), lay_v])
    shift = np.concatenate([np.zeros((o.shape[0], 2)), shift_v])
    base = proj[lay]
    for rnd in range(2):
        local = assign_many(det, base + shift[:, None, :], gate_px)
        ok = local >= 0
        cnt = ok.sum(axis=1)
        matched = base[np.arange(lay.size)[:, None], np.maximum(local, 0)]  # (Q, N, 2)
        resid = np.where(ok[..., None], det[None] - (matched + shift[:, None, :]), 0.0)
        mean_resid = resid.sum(axis=1) / np.maximum(cnt, 1)[:, None]
        if rnd == 0:
            keep = cnt >= min_pairs
            lay, shift, base = lay[keep], shift[keep] + mean_resid[keep], base[keep]
    keep = cnt >= min_pairs
    if not keep.any():
        return []
    lay, shift, local, ok, cnt = lay[keep], shift[keep], local[keep], ok[keep], cnt[keep]
    matched, resid = matched[keep], resid[keep]
    mse = np.sum(resid**2, axis=(1, 2)) / cnt
    # the start pose: turn the moved prior so the matched projections' centroid moves by the shift
    c = np.sum(np.where(ok[..., None], matched, 0.0), axis=1) / cnt[:, None]
    Kinv = inverse_intrinsics(K)
    b1 = np.column_stack([c, np.ones(c.shape[0])]) @ Kinv.T
    b2 = np.column_stack([c + shift, np.ones(c.shape[0])]) @ Kinv.T
    dR = rotation_between(b1, b2)
    starts = to_transforms(dR @ R[lay], np.einsum("hij,hj->hi", dR, t[lay]))
    size = np.sum(o[lay] ** 2, axis=1)
    out = [
        ((-int(cnt[q]), float(mse[q]), float(size[q])), np.where(ok[q], local[q], -1), starts[q])
        for q in range(lay.size)
    ]
    out.sort(key=lambda h: h[0])
    return out


def exhaustive_hypotheses(
    det: NDArray,
    good: NDArray,
    idx: NDArray,
    landmarks_xyz: NDArray,
    K: NDArray,
    prior: NDArray,
    need: int,
    pixel_sigma: float,
    gate_px: float,
    sig: PriorSigmas,
    limit: int,
    keep: int,
) -> list[tuple[NDArray, NDArray]] | None:
    """Every one-to-one assignment of the largest size, scored by PnP fit + prior; None if too many.

    For small sets (a slab's four corners) the layout vote is weak (the corners spread over the
    whole image, so distance and perspective errors of the prior exceed the coarse gate), and
    enumerating is cheap: each assignment gets its IPPE/SQPnP candidates, scored by
    ``sum r^2 / sigma^2 + prior Mahalanobis^2 + (unused detections) * gate^2 / sigma^2``; the best
    ``keep`` go on to re-association, each with its best candidate pose as the start.
    """
    n_good, m = good.size, idx.size
    k = min(n_good, m)
    if k < need:
        return []
    count = math.comb(n_good, k) * math.perm(m, k)
    if count > limit:
        return None
    K = kernel_array(K, dtype=np.float64)
    det = kernel_array(det, dtype=np.float64)
    landmarks_xyz = kernel_array(landmarks_xyz, dtype=np.float64)
    candidates = _CandidatePoses(landmarks_xyz[idx], K, is_coplanar(landmarks_xyz[idx]))
    unused_cost = (n_good - k) * (gate_px / pixel_sigma) ** 2
    scored: list[tuple[float, NDArray, NDArray]] = []
    for dsub in itertools.combinations(range(n_good), k):
        u = det[good[list(dsub)]]
        for msub in itertools.permutations(range(m), k):
            X = landmarks_xyz[idx[list(msub)]]
            best, best_T = np.inf, None
            for T in candidates(msub, u):
                res, depth = residuals(K, T, X, u)  # compiled (reprojection_residuals without its checks)
                if not np.all(depth > 0):
                    continue
                score = float(np.sum(res**2)) / pixel_sigma**2
                if score >= best:  # the prior's term (>= 0) cannot make it the best
                    continue
                score += prior_mahalanobis_sq(T, prior, sig)
                if score < best:
                    best, best_T = score, T
            if best_T is not None:
                a = np.full(det.shape[0], -1, dtype=np.int64)
                a[good[list(dsub)]] = idx[list(msub)]
                scored.append((best + unused_cost, a, best_T))
    scored.sort(key=lambda t: t[0])
    return [(a, T) for _, a, T in scored[:keep]]


class _CandidatePoses:
    """PnP candidates of orderings of a few landmarks, the plane of each subset fitted once.

    ``points`` (M, 3), the candidate landmarks; ``coplanar``, whether they all are (IPPE) or not
    (SQPnP). Called with ``order`` (k indices into ``points``) and the pixels (k, 2) they are
    assigned to. For coplanar landmarks the best-fit plane of the subset ``sorted(order)`` is
    fitted once (an enumeration tries every ordering of every subset, each subset's plane the same
    up to rounding) and each ordering indexes into its points in that plane.
    """

    def __init__(self, points: NDArray, K: NDArray, coplanar: bool) -> None:
        self.points, self.K, self.coplanar = points, K, coplanar
        self.planes: dict[tuple[int, ...], tuple[NDArray, NDArray, dict[int, int]]] = {}

    def __call__(self, order: tuple[int, ...], uv: NDArray) -> list[NDArray[np.float64]]:
        if not self.coplanar or len(order) < 4:
            return pnp_candidates(self.points[list(order)], uv, self.K, coplanar=self.coplanar)
        key = tuple(sorted(order))
        if key not in self.planes:
            p_from_w, Xp = planar_points(self.points[list(key)])
            self.planes[key] = (p_from_w, Xp, {j: r for r, j in enumerate(key)})
        p_from_w, Xp, row = self.planes[key]
        return ippe_candidates(Xp[[row[j] for j in order]], uv, self.K, p_from_w)


def spread_anchor_pairs(det: NDArray, k: int = 4, log_odds: NDArray | None = None) -> NDArray[np.int64]:
    """(P, 2) anchor pairs: among ``k`` spread-out detections, then among the ``k`` likeliest.

    The pairs among ``k`` spread-out detections of the dense part of the image come first; with
    ``log_odds`` (N,), every further pair among the ``k`` likeliest detections follows.
    Far-apart anchors condition the two-point pose best, but the extremes of a detection set are
    often clutter (uniform over the image, while landmarks gather on the building): the anchors
    are taken, farthest-point first, among the detections whose median distance to the others
    is at most the median of that (and any detection when there are at most ``k``). Every pair
    of ``k`` anchors leaves a pair of true detections unless ``k - 1`` of them are clutter.
    Clutter is not always uniform: a stack of formwork or pallets gives a dozen corner-like
    detections in one place, which is then the dense part, and every anchor is clutter (four
    slab corners found within 1 px, a prior 100 px off, no hypothesis). The detector's scores
    know better: its ``k`` likeliest detections anchor too. Compiled (the spread-out part):
    :func:`localization.associate.hypothesis_kernels.anchor_pairs`.
    """
    pairs = anchor_pairs(kernel_array(det, dtype=np.float64), int(k))
    if log_odds is None or det.shape[0] <= k:  # with at most k detections every pair is there
        return pairs
    top = np.sort(np.argsort(-np.asarray(log_odds), kind="stable")[:k])
    have = {(min(i, j), max(i, j)) for i, j in pairs.tolist()}
    extra = [p for p in itertools.combinations(top.tolist(), 2) if p not in have]
    return np.concatenate([pairs, np.array(extra, dtype=np.int64).reshape(-1, 2)]) if extra else pairs


def upright_hypotheses(
    det: NDArray,
    landmarks_xyz: NDArray,
    idx: NDArray,
    proj: NDArray,
    K: NDArray,
    prior: NDArray,
    sig: PriorSigmas,
    max_prior_sq: float | None,
    gate_px: float,
    min_pairs: int,
    keep: int,
    n_distinct: int,
    log_odds: NDArray | None = None,
) -> list[tuple[NDArray, NDArray]]:
    """Coarse assignments from upright two-point poses (:mod:`localization.associate.upright`).

    For each anchor pair of detections (:func:`spread_anchor_pairs`; ``log_odds`` (N,), the detections'
    score log-odds or None) and each ordered pair of
    candidate landmarks ``idx``, the pose with the prior's tilt that puts the two landmarks on
    the two detections; poses farther from the prior than ``max_prior_sq`` (yaw and position
    terms) are dropped. Each pose is scored like a rival (:func:`localization.associate.ambiguity.
    translation_hypotheses`): detections explained within ``gate_px``, then the sum of squared
    distances to the nearest projection capped at ``gate_px^2``, then the prior distance. The
    best ``keep`` give gated assignments, of which the first ``n_distinct`` different ones with
    ``min_pairs`` pairs or more are returned: ``[(assignment of det rows into landmarks, start
    cam_from_world), ...]``, best first.
    """
    pairs = spread_anchor_pairs(det, log_odds=log_odds)
    m = idx.size
    if pairs.shape[0] == 0 or m < 2:
        return []
    i1, i2 = pairs[:, 0].copy(), pairs[:, 1].copy()
    f64 = np.float64
    scored = score_upright_poses(
        kernel_array(det, dtype=f64), _rays(det, K, prior[:3, :3]), i1, i2,
        kernel_array(idx, dtype=np.int64), kernel_array(proj, dtype=f64),
        kernel_array(landmarks_xyz, dtype=f64), kernel_array(K, dtype=f64),
        kernel_array(prior[:3, :3]), camera_center(prior), np.asarray(sig.position_m, dtype=f64),
        float(sig.rotation_rad[2]), np.inf if max_prior_sq is None else float(max_prior_sq),
        float(gate_px) ** 2,
    )
    return _gated_starts(det, idx, scored, gate_px, min_pairs, keep, n_distinct)


def _rays(det: NDArray, K: NDArray, R_cw: NDArray) -> NDArray[np.float64]:
    """(N, 3) world directions of detections ``det`` (N, 2) under the attitude ``R_cw`` (cam_from_world)."""
    h = np.ones((det.shape[0], 3))  # homogeneous pixels
    h[:, :2] = det
    return kernel_array(h @ inverse_intrinsics(K).T @ R_cw)


def _gated_starts(
    det: NDArray, idx: NDArray, scored: tuple[NDArray, ...], gate_px: float, min_pairs: int, keep: int,
    n_distinct: int,
) -> list[tuple[NDArray, NDArray]]:
    """The distinct gated assignments of the best scored upright poses, with their poses.

    ``scored``: :func:`localization.associate.upright.score_upright_poses`' outputs; the best
    poses' gated assignments of ``det`` into ``idx``, until ``n_distinct`` of them differ (a pose
    that repeats an earlier one's assignment, or pairs fewer than ``min_pairs``, would be dropped
    by the caller): :func:`localization.associate.hypothesis_kernels.upright_starts`.
    """
    R, t, uv, prior_sq, explained, misfit = scored
    if prior_sq.size == 0:
        return []
    a, chosen = upright_starts(
        kernel_array(det, dtype=np.float64), kernel_array(idx, dtype=np.int64), uv, prior_sq,
        explained, misfit, float(gate_px), int(min_pairs), int(keep), int(n_distinct),
    )
    T = to_transforms(R[chosen], t[chosen])
    return [(a[q], T[q]) for q in range(chosen.size)]


def regrowth_hypotheses(
    det: NDArray,
    pairs: NDArray,
    landmarks_xyz: NDArray,
    idx: NDArray,
    K: NDArray,
    cam_from_world: NDArray,
    prior: NDArray,
    sig: PriorSigmas,
    gate_px: float,
    min_pairs: int,
    keep: int,
    n_distinct: int,
) -> list[tuple[NDArray, NDArray]]:
    """Coarse assignments grown from a hypothesis' pairs, two at a time.

    A hypothesis refined from a start with most of its pairs wrong (the layout vote's shifts
    among dense clutter) settles where a dozen right pairs and a few wrong ones fit together,
    metres from the structure's pose, which would pair every landmark it predicts. Any two of
    its right pairs fix that pose with the hypothesis' tilt (:mod:`localization.associate.upright`),
    and a pose is grown from it as the upright starts are. Each pair of ``pairs`` (P, 2):
    ``(detection row of det, landmark)``, at most :data:`REGROWTH_PAIRS` of them (spread out,
    :func:`localization.associate.hypothesis_kernels.anchor_pairs`), gives both roots of the
    upright problem with the tilt of ``cam_from_world``; they are scored and turned into gated
    assignments of ``det`` into the candidate landmarks ``idx`` as :func:`upright_hypotheses`
    does (``gate_px``, ``min_pairs``, ``keep``, ``n_distinct``). The prior term of the ranking
    measures the yaw from ``cam_from_world``'s and the centre from ``prior``'s.
    Returns ``[(assignment of det rows into landmarks, start cam_from_world), ...]``, best first.
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if pairs.shape[0] < 2 or idx.size < 2:
        return []
    f64 = np.float64
    det = kernel_array(det, dtype=f64)
    chosen = anchor_pairs(kernel_array(det[pairs[:, 0]]), REGROWTH_PAIRS)
    s1, s2 = pairs[chosen[:, 0], 0].copy(), pairs[chosen[:, 1], 0].copy()
    t1, t2 = pairs[chosen[:, 0], 1].copy(), pairs[chosen[:, 1], 1].copy()
    R0 = kernel_array(cam_from_world[:3, :3], dtype=f64)
    scored = score_samples(
        det, _rays(det, K, R0), s1, s2, t1, t2, kernel_array(idx, dtype=np.int64),
        kernel_array(landmarks_xyz, dtype=f64), kernel_array(K, dtype=f64), R0,
        camera_center(prior), np.asarray(sig.position_m, dtype=f64), float(sig.rotation_rad[2]), np.inf,
        float(gate_px) ** 2,
    )
    return _gated_starts(det, idx, scored, gate_px, min_pairs, keep, n_distinct)
