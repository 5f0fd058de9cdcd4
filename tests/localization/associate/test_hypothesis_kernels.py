"""The compiled checks and scores of robust association against plain numpy statements of them."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from localization.associate.hypothesis_kernels import (
    anchor_pairs,
    check_many,
    missed_many,
    translation_scores,
)
from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import camera_center, look_at, so3_exp
from localization.pose.batch import pose_difference_many, project_many, to_transforms


def _views(rng, n):
    out = []
    for _ in range(n):
        angle = rng.uniform(0, 2 * np.pi)
        eye = np.array([25 * np.cos(angle), 25 * np.sin(angle), rng.uniform(5, 25)])
        out.append(look_at(eye, rng.uniform(-2, 2, 3)))
    return np.array(out)


def test_check_many_is_the_prior_distance_and_the_chi_square_of_the_pairs(rng):
    L = rng.uniform(-6, 6, (12, 3))
    T = _views(rng, 6)
    T[5] = np.diag([1.0, -1.0, -1.0, 1.0]) @ T[5]  # a point behind this camera: counts as 1e6 px
    prior = _views(rng, 1)[0]
    det = rng.uniform(0, 1280, (9, 2))
    det[8] = np.nan  # an unassigned NaN row is never read
    a = rng.integers(-1, 12, (6, 9))
    a[:, 8] = -1
    sig = np.array([3.0, 3.0, 3.0, 0.035, 0.035, 0.087])
    R, t = T[:, :3, :3].copy(), T[:, :3, 3].copy()
    prior_sq, chi, far = check_many(PAPER_K, L, det, a, R, t, prior[:3, :3].copy(), camera_center(prior), sig)
    d = pose_difference_many(T[:, :3, :3], T[:, :3, 3], prior)
    Q = T[:, :3, :3].transpose(0, 2, 1) @ prior[:3, :3]
    np.testing.assert_array_equal(far, (np.trace(Q, axis1=1, axis2=2) - 1.0) / 2.0 <= -0.99)
    assert (~far).sum() >= 3  # the rest of the views (random around the building) are compared
    np.testing.assert_allclose(prior_sq[~far], np.sum((d / sig) ** 2, axis=1)[~far], rtol=1e-12)
    uvp, _ = project_many(PAPER_K, T[:, :3, :3], T[:, :3, 3], L[np.maximum(a, 0)])
    r2 = np.where(a >= 0, np.sum((np.nan_to_num(uvp, nan=1e6) - np.nan_to_num(det)) ** 2, axis=2), 0.0)
    np.testing.assert_allclose(chi, r2.sum(axis=1), rtol=1e-12)
    assert chi[5] > 1e11
    # a rotation pi from the prior's is flagged for the exact logarithm
    flipped = T[:1].copy()
    flipped[0, :3, :3] = prior[:3, :3] @ so3_exp([0.0, 0.0, np.pi - 0.01])
    assert check_many(PAPER_K, L, det, a[:1], flipped[:, :3, :3].copy(), flipped[:, :3, 3].copy(),
                      prior[:3, :3].copy(), camera_center(prior), sig)[2][0]


def test_missed_many_counts_landmarks_predicted_in_the_image_and_left_unmatched(rng):
    L = rng.uniform(-6, 6, (15, 3))
    T = _views(rng, 4)
    a = np.full((4, 5), -1)
    uv, _ = project_many(PAPER_K, T[:, :3, :3], T[:, :3, 3], L)
    w, h = 1280, 720
    inside = (uv[..., 0] >= -0.5) & (uv[..., 0] <= w - 0.5) & (uv[..., 1] >= -0.5) & (uv[..., 1] <= h - 0.5)
    for k in range(4):
        a[k, :3] = np.flatnonzero(inside[k])[:3]
    got = missed_many(PAPER_K, L, a, T[:, :3, :3].copy(), T[:, :3, 3].copy(), w, h)
    np.testing.assert_array_equal(got, inside.sum(axis=1) - np.minimum(inside.sum(axis=1), 3))


def test_anchor_pairs_picks_far_apart_detections_of_the_dense_part(rng):
    det = np.vstack([[[600.0, 300.0], [700.0, 300.0], [600.0, 400.0], [700.0, 400.0], [650.0, 350.0]],
                     [[5.0, 5.0], [1275.0, 715.0]]])  # two clutter detections at the corners
    pairs = anchor_pairs(det, 4)
    assert pairs.shape == (6, 2)
    # the four corners of the square, not the clutter and not its centre
    assert sorted(set(pairs.ravel().tolist())) == [0, 1, 2, 3]
    assert sorted(map(tuple, np.sort(pairs, axis=1).tolist())) == list(itertools.combinations(range(4), 2))


def test_translation_scores_is_the_capped_nearest_distance_after_each_move(rng):
    L = rng.uniform(-6, 6, (10, 3))
    T = _views(rng, 1)[0]
    R, C = T[:3, :3], camera_center(T)
    p = (L - C) @ R.T
    # the last move: 100 m forward along the optical axis, every landmark behind the camera
    shifts = np.vstack([np.zeros(3), rng.normal(0, 2, (4, 3)), 100.0 * R[2]])
    uv_true, _ = project_many(PAPER_K, T[None, :3, :3], T[None, :3, 3], L)
    det = uv_true[0, :6] + rng.normal(0, 0.5, (6, 2))
    uv, depth, explained, misfit = translation_scores(det, p, shifts @ R.T, PAPER_K, 400.0)
    for q, s in enumerate(shifts):
        moved = to_transforms(R[None], (-R @ (C + s))[None])
        want_uv, want_z = project_many(PAPER_K, moved[:, :3, :3], moved[:, :3, 3], L)
        np.testing.assert_allclose(depth[q], want_z[0], atol=1e-9)
        np.testing.assert_allclose(uv[q], want_uv[0], atol=1e-6)
        d2 = np.sum((det[:, None, :] - want_uv[0][None]) ** 2, axis=2)
        with np.errstate(invalid="ignore"):
            nearest = np.minimum(np.min(np.where(np.isnan(d2), np.inf, d2), axis=1), 400.0)
        assert misfit[q] == pytest.approx(nearest.sum(), rel=1e-9)
        assert explained[q] == np.sum(nearest < 400.0)
    assert explained[0] == 6 and misfit[0] < 6 * 4.0  # no move: every detection within noise
    assert np.isnan(uv[-1]).all() and explained[-1] == 0 and misfit[-1] == 6 * 400.0



def test_the_nearest_projection_in_a_window_of_u_is_the_brute_force_one_below_the_cap(rng):
    from localization.associate.hypothesis_kernels import _nearest_brute, _nearest_in_window

    for _ in range(200):  # integer pixels: detections exactly the cap away in u, and in distance
        det = rng.integers(0, 400, (int(rng.integers(1, 200)), 2)).astype(float)
        uv = rng.integers(0, 400, (int(rng.integers(1, 40)), 2)).astype(float)
        uv[rng.random(uv.shape[0]) < 0.2] = np.nan  # behind the camera
        cap_sq = float(rng.choice([9.0, 25.0, 1600.0, 2.0, 1e6]))
        brute, window = np.empty(det.shape[0]), np.empty(det.shape[0])
        _nearest_brute(det, uv, brute)
        _nearest_in_window(det, uv, cap_sq, np.empty(uv.shape[0], dtype=np.int64), window)
        np.testing.assert_array_equal(np.minimum(window, cap_sq), np.minimum(brute, cap_sq))



def test_the_median_selected_in_place_is_numpys_to_the_bit(rng):
    from localization.associate.hypothesis_kernels import median_inplace

    for n in [1, 2, 3, 4, *rng.integers(5, 400, 200).tolist()]:
        a = rng.uniform(0, 1e6, n) if n % 3 else np.round(rng.uniform(0, 5, n))  # ties too
        want = np.median(a)
        assert median_inplace(a.copy()) == want, n  # == on floats: the same bits


def test_pose_covariance_is_the_inverse_information_of_pose_jacobian(rng):
    from localization.pose.covariance import pose_covariance, pose_jacobian

    for _ in range(40):
        T = _views(rng, 1)[0]
        X = rng.uniform(-6, 6, (int(rng.integers(4, 20)), 3))
        J, _ = pose_jacobian(PAPER_K, T, X)
        want = 0.7**2 * np.linalg.inv(J.T @ J)
        got = pose_covariance(PAPER_K, T, X, 0.7)
        np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-14)
        np.testing.assert_array_equal(got, got.T)
    # two points, collinear points, a point at the camera centre: singular, all inf
    T = _views(rng, 1)[0]
    line = np.outer(np.linspace(0, 1, 6), [1.0, 2.0, 0.5])
    at_centre = np.vstack([rng.uniform(-6, 6, (5, 3)), camera_center(T)])
    for X in (rng.uniform(-6, 6, (2, 3)), line, at_centre):
        assert np.isinf(pose_covariance(PAPER_K, T, X)).all()


def test_prior_mahalanobis_sq_matches_the_pose_difference_also_near_pi(rng):
    from localization.pose.covariance import PriorSigmas, pose_difference, prior_mahalanobis_sq

    sig = PriorSigmas().as_array()
    T = _views(rng, 1)[0]
    for angle in (0.0, 1e-9, 0.3, 2.0, np.pi - 0.05, np.pi):  # the last two take the exact logarithm
        P = T.copy()
        P[:3, :3] = T[:3, :3] @ so3_exp(angle * np.array([0.6, 0.0, 0.8]))
        P[:3, 3] += [1.0, -2.0, 0.5]
        want = float(np.sum((pose_difference(T, P) / sig) ** 2))
        assert prior_mahalanobis_sq(T, P) == pytest.approx(want, rel=1e-9)
