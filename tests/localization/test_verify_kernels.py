"""The verification's compiled parts give what plain numpy gives (the code they replaced)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import look_at, project
from localization.pose.covariance import PriorSigmas, pose_jacobian, prior_mahalanobis_sq
from localization.verify import VerifyInputs, _scores
from localization.verify_kernels import lattice_hits, leave_one_out, offset_votes


def _offset_votes_numpy(pair_uv, free_uv, tol, radius, n_cells=12, n_out=3):
    off = free_uv[None, :, :] - pair_uv[:, None, :]
    d = np.hypot(off[..., 0], off[..., 1])
    pi, fi = np.nonzero((d <= radius) & (d > tol))
    if pi.size == 0:
        return np.zeros((0, 3))
    vec = off[pi, fi]
    span = int(2 * radius / tol) + 4
    cell = np.floor(vec / tol).astype(np.int64) + span // 2
    key = cell[:, 0] * span + cell[:, 1]
    cells, per_cell = np.unique(np.unique(key * len(pair_uv) + pi) // len(pair_uv), return_counts=True)
    votes = np.zeros(cells.size, dtype=np.int64)
    for shift in (di * span + dj for di in (-1, 0, 1) for dj in (-1, 0, 1)):
        at = np.clip(np.searchsorted(cells, cells + shift), 0, cells.size - 1)
        votes += np.where(cells[at] == cells + shift, per_cell[at], 0)
    out = []
    for c in cells[np.argsort(-votes, kind="stable")[:n_cells]]:
        first = vec[np.argmax(key == c)]
        centre = vec[np.hypot(*(vec - first).T) <= tol].mean(axis=0)
        agree = np.hypot(*(vec - centre).T) <= tol
        out.append([*centre, np.unique(pi[agree]).size])
    out.sort(key=lambda r: -r[2])
    return np.array(out[:n_out])


@pytest.mark.parametrize("case", range(40))
def test_offset_votes_equal_numpy_to_the_bit(case):
    rng = np.random.default_rng((7, case))
    n = int(rng.integers(1, 30))
    pairs = rng.uniform(0, 400 if case % 2 else 60, (n, 2))
    if case % 3 == 0:  # a ghost copy at one offset, some of it
        free = pairs[rng.random(n) < 0.7] + rng.uniform(-40, 40, 2) + rng.normal(0, 0.5, (1, 2))
    else:  # a lattice of neighbours and clutter
        free = np.vstack([pairs + rng.normal(0, 0.3, pairs.shape) + 12.0, rng.uniform(0, 400, (5, 2))])
    tol = float(rng.choice([1.0, 3.0, 10.0]))
    got = offset_votes(pairs, np.ascontiguousarray(free), tol, 80.0, 12, 3)
    want = _offset_votes_numpy(pairs, free, tol, 80.0)
    assert got.shape == want.shape
    assert np.array_equal(got, want)


def test_offset_votes_find_a_ghost_copy_offset_with_every_pair():
    rng = np.random.default_rng(3)
    pairs = rng.uniform(0, 1000, (15, 2))
    ghost = pairs + [23.0, -9.0]
    got = offset_votes(pairs, ghost, 6.0, 80.0, 12, 3)
    assert np.allclose(got[0, :2], [23.0, -9.0]) and got[0, 2] == 15


def _lattice_numpy(X, P, anchors, tol, least, key_m):
    tree = cKDTree(X)
    shifts = np.concatenate([X - P[i] for i in range(anchors)])
    dist, j = tree.query((P[None, :, :] + shifts[:, None, :]).reshape(-1, 3))
    dist, j = dist.reshape(len(shifts), len(P)), j.reshape(len(shifts), len(P))
    hit = dist <= tol
    out, seen = [], set()
    for i in np.flatnonzero(hit.sum(axis=1) >= least):
        d = shifts[i]
        key = tuple(np.round(d / key_m).astype(int))
        if np.linalg.norm(d) <= tol or key in seen or np.unique(j[i][hit[i]]).size != hit[i].sum():
            continue
        seen.add(key)
        out.append((i, hit[i], j[i]))
    return out


@pytest.mark.parametrize("case", range(12))
def test_lattice_hits_equal_a_kd_tree_search(case):
    rng = np.random.default_rng((11, case))
    xs, ys = np.meshgrid(np.arange(int(rng.integers(2, 8))) * 5.0, np.arange(int(rng.integers(2, 6))) * 4.0)
    X = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 7.0)]) + rng.normal(0, 0.004, (xs.size, 3))
    if case % 2:  # an irregular layout: a few landmarks more
        X = np.vstack([X, rng.uniform(0, 20, (4, 3))])
    patch = np.flatnonzero((X[:, 0] <= rng.uniform(5, 20)) & (X[:, 1] <= rng.uniform(4, 12)))
    paired = X[patch if patch.size >= 4 else np.arange(4)]
    tol = 0.02 if case % 3 else 1.0
    least = len(paired) if case % 4 < 2 else max(int(math.ceil(0.5 * len(paired))), 4)
    anchors = 1 if least == len(paired) else 3
    kept, hit, nearest = lattice_hits(X, paired, anchors, tol, least, max(tol, 0.02))
    want = _lattice_numpy(X, paired, anchors, tol, least, max(tol, 0.02))
    assert kept.tolist() == [i for i, _, _ in want]
    for r, (_, h, j) in enumerate(want):
        assert np.array_equal(hit[r], h) and np.array_equal(nearest[r][h], j[h])


def test_lattice_hits_find_the_periods_of_a_grid():
    xs, ys = np.meshgrid(np.arange(4) * 5.0, np.arange(3) * 4.0)
    X = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 7.0)])
    paired = X[(X[:, 0] <= 5.0) & (X[:, 1] <= 4.0)]  # a 2 x 2 patch in the corner
    kept, hit, nearest = lattice_hits(X, paired, 1, 0.02, len(paired), 0.02)
    shifts = {tuple(np.round(X[k % len(X)] - paired[0], 6)) for k in kept}
    # the patch moved by (0 | 5 | 10, 0 | 4) m stays on the grid, but not by nothing
    assert shifts == {(dx, dy, 0.0) for dx in (0.0, 5.0, 10.0) for dy in (0.0, 4.0)} - {(0.0, 0.0, 0.0)}
    assert hit.all() and all(len(set(j)) == len(paired) for j in nearest)


def _score_numpy(inputs, a, T):
    m = a >= 0
    uv, _ = project(inputs.K, T, inputs.landmarks_xyz[a[m]])
    chi = float(np.sum((uv - inputs.detections_uv[m]) ** 2)) / inputs.pixel_sigma**2
    q, depth = project(inputs.K, T, inputs.landmarks_xyz)
    w, h = inputs.image_size
    seen = (depth > 0) & (q[:, 0] >= -0.5) & (q[:, 0] <= w - 0.5)
    seen &= (q[:, 1] >= -0.5) & (q[:, 1] <= h - 0.5)
    seen[a[m]] = False
    n_free = int(np.count_nonzero(~m & np.isfinite(inputs.detections_uv).all(axis=1)))
    return (chi + n_free * (inputs.gate_px / inputs.pixel_sigma) ** 2 + int(seen.sum()) * inputs.miss_cost
            + prior_mahalanobis_sq(T, inputs.prior_cam_from_world, inputs.prior_sigmas))


def test_rival_scores_agree_with_numpy_projections():
    rng = np.random.default_rng(5)
    X = rng.uniform([-10, -10, 0], [10, 10, 8], (30, 3))
    truth = look_at([2.0, -30.0, 20.0], [0.0, 0.0, 3.0])
    uv, _ = project(PAPER_K, truth, X)
    det = np.vstack([uv[:20] + rng.normal(0, 1, (20, 2)), rng.uniform(0, 1000, (3, 2)), [[np.nan, np.nan]]])
    prior = look_at([4.0, -28.0, 22.0], [0.5, 0.0, 3.0])
    a = np.full(len(det), -1, dtype=np.int64)
    a[:20] = np.arange(20)
    inputs = VerifyInputs(
        detections_uv=det, landmarks_xyz=X, K=PAPER_K, image_size=PAPER_IMAGE_SIZE, cam_from_world=truth,
        assignment=a, covariance=np.eye(6), prior_cam_from_world=prior, prior_sigmas=PriorSigmas(),
        pixel_sigma=1.0, gate_px=5.0, need=4,
    )
    b = a.copy()
    b[5] = -1  # a landmark in view left unmatched
    hyps = [(a, truth), (a, prior), (b, look_at([-3.0, -25.0, 18.0], [0.0, 1.0, 3.0]))]
    got = _scores(inputs, hyps)
    for k, (ak, Tk) in enumerate(hyps):
        assert got[k] == pytest.approx(_score_numpy(inputs, ak, Tk), rel=1e-12)
    assert inputs.winner_score == pytest.approx(got[0], rel=1e-15)
    assert got[2] > got[0] + inputs.miss_cost  # the miss costs


def test_leave_one_out_agrees_with_the_hat_matrix():
    rng = np.random.default_rng(9)
    X = rng.uniform([-10, -10, 0], [10, 10, 8], (9, 3))
    T = look_at([2.0, -30.0, 20.0], [0.0, 0.0, 3.0])
    uv, _ = project(PAPER_K, T, X)
    det = uv + rng.normal(0, 1.0, uv.shape)
    det[4] += [6.0, -4.0]  # one wrong pair
    q, shift, det_b = leave_one_out(PAPER_K, np.ascontiguousarray(T[:3, :3]), -T[:3, :3].T @ T[:3, 3], X, det)
    J, p = pose_jacobian(PAPER_K, T, X)
    e = det - p
    N_inv = np.linalg.pinv(J.T @ J)
    H = J @ N_inv @ J.T
    for i in range(len(X)):
        B = np.eye(2) - H[2 * i:2 * i + 2, 2 * i:2 * i + 2]
        assert det_b[i] == pytest.approx(np.linalg.det(B), rel=1e-9)
        assert q[i] == pytest.approx(e[i] @ np.linalg.solve(B, e[i]), rel=1e-9)
        Ji = J[2 * i:2 * i + 2]
        move = (N_inv @ Ji.T @ np.linalg.solve(B, e[i]))[:3]
        assert shift[i] == pytest.approx(np.linalg.norm(move), rel=1e-9)
    assert int(np.argmax(q)) == 4 and q[4] > 13.8  # the wrong pair, beyond the 2-dof 99.9 % quantile
