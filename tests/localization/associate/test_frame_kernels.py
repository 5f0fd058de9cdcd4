"""The compiled per-frame selection of robust association against the numpy code it replaced."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from localization.associate.assign_kernels import assign_many
from localization.associate.hypothesis_kernels import rival_translations, upright_starts
from localization.associate.paper import assign, candidate_landmarks
from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import camera_center, invert, look_at, project
from localization.pose.pnp import reprojection_residuals


def _view(rng):
    angle = rng.uniform(0, 2 * np.pi)
    eye = np.array([25 * np.cos(angle), 25 * np.sin(angle), rng.uniform(5, 25)])
    return look_at(eye, rng.uniform(-2, 2, 3))


def test_candidates_are_the_projections_in_front_and_near_the_image(rng):
    for _ in range(20):
        T = _view(rng)
        L = rng.uniform(-30, 30, (40, 3))  # some behind the camera, some far outside the image
        uv, depth = project(PAPER_K, T, L)
        ok = (depth > 1e-6) & np.isfinite(uv).all(axis=1)
        ok &= (uv[:, 0] >= -40.5) & (uv[:, 0] <= 1319.5) & (uv[:, 1] >= -40.5) & (uv[:, 1] <= 759.5)
        idx, proj = candidate_landmarks(L, PAPER_K, T, (1280, 720), 40.0)
        np.testing.assert_array_equal(idx, np.flatnonzero(ok))
        np.testing.assert_allclose(proj, uv[ok], rtol=0, atol=1e-9)
        assert 0 < idx.size < 40


def _assign_numpy(det, model, gate_px):
    """:func:`localization.associate.paper.assign` as plain numpy code (no compiled costs)."""
    out = np.full(det.shape[0], -1, dtype=np.int64)
    d2 = np.sum((det[:, None, :] - model[None, :, :]) ** 2, axis=2)
    d2 = np.where(np.isfinite(d2), d2, 1e12)
    if gate_px is None:
        rows, cols = linear_sum_assignment(d2)
        out[rows] = cols
        return out
    cost = np.minimum(d2 - gate_px**2, 0.0)
    rows, cols = linear_sum_assignment(cost)
    real = cost[rows, cols] < 0.0
    out[rows[real]] = cols[real]
    return out


def test_assign_is_the_minimum_cost_assignment_of_the_numpy_code(rng):
    for _ in range(50):
        model = rng.uniform(0, 200, (int(rng.integers(1, 12)), 2))
        det = np.vstack([model + rng.normal(0, 3, model.shape), rng.uniform(0, 200, (3, 2))])
        det = det[rng.permutation(det.shape[0])]
        det[0] = np.nan  # a NaN row is never paired under a gate
        for gate in (None, 5.0):
            np.testing.assert_array_equal(assign(det, model, gate), _assign_numpy(det, model, gate))
    assert assign(np.zeros((0, 2)), np.zeros((3, 2)), 5.0).shape == (0,)


def _upright_numpy(det, idx, uv, prior_sq, explained, misfit, gate_px, min_pairs, keep, n_distinct):
    """:func:`upright_starts`' selection as plain numpy code."""
    order = np.lexsort((prior_sq, misfit, -explained))
    order = order[explained[order] >= min_pairs][:keep]
    out, seen = [], set()
    first = n_distinct + n_distinct // 2
    for block in (order[:first], order[first:]):
        if block.size == 0:
            break
        local = assign_many(det, uv[block], gate_px)
        a = np.where(local >= 0, idx[np.maximum(local, 0)], -1)
        for q in range(block.size):
            key = a[q].tobytes()
            if key in seen or (a[q] >= 0).sum() < min_pairs:
                continue
            seen.add(key)
            out.append((a[q], block[q]))
            if len(out) == n_distinct:
                return out
    return out


def test_upright_starts_are_the_distinct_assignments_of_the_best_poses(rng):
    for trial in range(30):
        n, m, s = 7, 6, 60
        det = rng.uniform(0, 100, (n, 2))
        idx = np.sort(rng.choice(20, m, replace=False)).astype(np.int64)
        # poses whose projections land near the detections in a few distinct ways, many repeated
        base = det[rng.integers(0, n, (4, m))] + rng.normal(0, 1.0, (4, m, 2))
        uv = base[rng.integers(0, 4, s)] + rng.normal(0, 0.5, (s, m, 2))
        uv[rng.random((s, m)) < 0.1] = np.nan  # behind the camera
        explained = rng.integers(2, 7, s)
        misfit = np.round(rng.uniform(0, 50, s), 1)  # ties broken by the prior distance, then order
        prior_sq = np.round(rng.uniform(0, 10, s), 0)
        for keep, n_distinct in ((40, 16), (12, 8), (60, 3)):
            args = (det, idx, uv, prior_sq, explained, misfit, 4.0, 4, keep, n_distinct)
            got_a, got_pose = upright_starts(*args)
            want = _upright_numpy(*args)
            assert got_a.shape[0] == len(want) <= n_distinct
            for (a, pose), ga, gp in zip(want, got_a, got_pose, strict=True):
                np.testing.assert_array_equal(ga, a)
                assert gp == pose
        if trial == 0:
            assert len(want) >= 2  # the cases hold several distinct assignments


def _translations_numpy(det, L, K, T, anchors, prior_centre, sigma, max_sq, gate_px, need, limit):
    """:func:`localization.associate.ambiguity.translation_hypotheses`' candidates as plain numpy code."""
    from localization.associate.hypothesis_kernels import translation_scores

    t = np.round((L[None, :, :] - L[anchors][:, None, :]).reshape(-1, 3), 3)
    t = t[np.lexsort((t[:, 2], t[:, 1], t[:, 0]))]
    t = t[np.concatenate([[True], np.any(t[1:] != t[:-1], axis=1)])]
    t = t[np.linalg.norm(t, axis=1) > 1e-3]
    centre = camera_center(T)
    prior_sq = np.sum(((centre + t - prior_centre) / sigma) ** 2, axis=1)
    t, prior_sq = t[prior_sq <= max_sq], prior_sq[prior_sq <= max_sq]
    R = T[:3, :3]
    uv, depth, explained, misfit = translation_scores(det, (L - centre) @ R.T, t @ R.T, K, gate_px**2)
    order = np.lexsort((prior_sq, misfit))
    order = order[explained[order] >= need][:limit]
    return t[order], uv[order], depth[order]


def test_rival_translations_are_the_layout_moves_of_the_numpy_code(rng):
    # a regular grid (many repeated translations) seen with its detections shifted by one bay
    g = np.array([[x, y, 9.0] for x in (-10.0, -5.0, 0.0, 5.0, 10.0) for y in (-6.0, 0.0, 6.0)])
    proposed = 0
    for _ in range(10):
        T = _view(rng)
        uv, _ = project(PAPER_K, T, g + np.array([5.0, 0.0, 0.0]))
        det = uv + rng.normal(0, 1.0, uv.shape)
        anchors = rng.choice(g.shape[0], 4, replace=False).astype(np.int64)
        prior = T.copy()
        prior[:3, 3] += rng.normal(0, 2.0, 3)
        sigma = np.array([3.0, 3.0, 3.0])
        for limit in (6, 2):
            got_t, got_uv, got_depth, centre = rival_translations(
                det, g, PAPER_K, T, anchors, camera_center(prior), sigma, 22.46, 40.0**2, 4, limit)
            want_t, want_uv, want_depth = _translations_numpy(
                det, g, PAPER_K, T, anchors, camera_center(prior), sigma, 22.46, 40.0, 4, limit)
            np.testing.assert_array_equal(got_t, want_t)
            np.testing.assert_allclose(got_uv, want_uv, rtol=0, atol=1e-9)
            np.testing.assert_allclose(got_depth, want_depth, rtol=0, atol=1e-12)
            np.testing.assert_allclose(centre, camera_center(T), rtol=0, atol=1e-12)
            assert got_t.shape[0] <= limit
            proposed += got_t.shape[0]
    assert proposed >= 10  # the cases propose rivals (the comparison is not of empty lists)


def test_centre_inverse_and_residuals_are_the_numpy_formulas(rng):
    for _ in range(20):
        T = _view(rng)
        R, t = T[:3, :3], T[:3, 3]
        np.testing.assert_allclose(camera_center(T), -R.T @ t, rtol=0, atol=1e-12)
        inv = invert(T)
        np.testing.assert_allclose(inv[:3, :3], R.T, rtol=0, atol=0)
        np.testing.assert_allclose(inv[:3, 3], -R.T @ t, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(inv[3], [0.0, 0.0, 0.0, 1.0])
        np.testing.assert_allclose(inv @ T, np.eye(4), rtol=0, atol=1e-12)
        X = rng.uniform(-8, 8, (10, 3))
        uv = rng.uniform(0, 1280, (10, 2))
        res, depth = reprojection_residuals(PAPER_K, T, X, uv)
        proj, d = project(PAPER_K, T, X)
        np.testing.assert_allclose(res, proj - uv, rtol=0, atol=1e-8)
        np.testing.assert_allclose(depth, d, rtol=0, atol=1e-12)
    # a point at the camera centre: depth 0, the residual inf or NaN as numpy's division gives
    res, depth = reprojection_residuals(PAPER_K, T, camera_center(T)[None], np.zeros((1, 2)))
    assert depth[0] == 0.0 and not np.isfinite(res).all()


def test_the_compiled_helpers_refuse_shapes_they_would_read_out_of_bounds():
    for bad in (np.eye(3), np.zeros(4), np.zeros((2, 4, 4))):
        with pytest.raises(ValueError, match=r"cam_from_world must be a \(4, 4\) rigid transform, got shape"):
            camera_center(bad)
        with pytest.raises(ValueError, match=r"b_from_a must be a \(4, 4\) rigid transform"):
            invert(bad)
    with pytest.raises(ValueError, match="3 points and 2 pixels"):
        reprojection_residuals(PAPER_K, np.eye(4), np.zeros((3, 3)), np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"K \(2, 2\)"):
        reprojection_residuals(np.eye(2), np.eye(4), np.zeros((3, 3)), np.zeros((3, 2)))


def test_inverse_intrinsics_is_the_inverse_cached_read_only_and_refuses_other_shapes():
    from localization.geometry.camera import PAPER_K
    from localization.geometry.transforms import inverse_intrinsics

    inv = inverse_intrinsics(PAPER_K)
    np.testing.assert_allclose(inv @ PAPER_K, np.eye(3), atol=1e-15)
    assert inverse_intrinsics(PAPER_K.copy()) is inv  # one inverse per distinct matrix
    assert not inv.flags.writeable
    other = PAPER_K * np.array([[2.0], [2.0], [1.0]])
    np.testing.assert_allclose(inverse_intrinsics(other) @ other, np.eye(3), atol=1e-15)
    with pytest.raises(ValueError, match=r"K must have shape \(3, 3\), got \(4, 4\)"):
        inverse_intrinsics(np.eye(4))
