import itertools

import cv2
import numpy as np
import pytest

from localization.failure import FailureCode
from localization.geometry.transforms import (
    camera_center,
    look_at,
    project,
    rotation_angle_deg,
    so3_exp,
    so3_log,
)
from localization.pose.covariance import pose_covariance, pose_jacobian, prior_mahalanobis_sq
from localization.pose.pnp import (
    ippe_candidates,
    is_coplanar,
    planar_points,
    pnp_candidates,
    refine_pose,
    solve_pnp,
)

SLAB = np.array([(-0.3, -0.3, 3.5), (8.3, -0.3, 3.5), (8.3, 11.3, 3.5), (-0.3, 11.3, 3.5)])


def _view(rng, target=(4.0, 5.5, 3.5)):
    a = rng.uniform(0, 2 * np.pi)
    d, h = rng.uniform(15, 35), rng.uniform(10, 25)
    return look_at([4 + d * np.cos(a), 5.5 + d * np.sin(a), h], target)


def test_so3_log_exp_round_trip(rng):
    for angle in (0.0, 1e-7, 0.3, 2.0, np.pi - 1e-4):
        axis = rng.normal(size=3)
        w = axis / np.linalg.norm(axis) * angle
        np.testing.assert_allclose(so3_exp(so3_log(so3_exp(w))), so3_exp(w), atol=1e-9)


def test_ippe_plane_frame_workaround_all_orderings(rng, K):
    """OpenCV 5 IPPE fails for half the orderings off z = 0; the plane-frame wrapper never does."""
    for _ in range(5):
        T = _view(rng)
        uv, _ = project(K, T, SLAB)
        for perm in itertools.permutations(range(4)):
            p = list(perm)
            cands = pnp_candidates(SLAB[p], uv[p], K)
            errs = [np.linalg.norm(camera_center(c) - camera_center(T)) for c in cands]
            assert min(errs) < 1e-6


def test_one_plane_frame_serves_every_ordering(rng, K):
    """The exhaustive association fits a subset's plane once: IPPE in it gives each ordering's poses."""
    for _ in range(3):
        T = _view(rng)
        uv, _ = project(K, T, SLAB)
        p_from_w, Xp = planar_points(SLAB)
        np.testing.assert_array_equal(Xp[:, 2], 0.0)
        np.testing.assert_allclose((Xp - p_from_w[:3, 3]) @ p_from_w[:3, :3], SLAB, atol=1e-9)  # world again
        for perm in itertools.permutations(range(4)):
            p = list(perm)
            shared = ippe_candidates(Xp[p], uv[p], K, p_from_w)
            own = pnp_candidates(SLAB[p], uv[p], K)
            assert len(shared) == len(own) >= 1
            errs = [np.linalg.norm(camera_center(c) - camera_center(T)) for c in shared]
            assert min(errs) < 1e-6
            for a in shared:  # the same candidate poses, up to rounding
                assert min(np.abs(a - b).max() for b in own) < 1e-7
    assert ippe_candidates(Xp[:3], uv[:3], K, p_from_w) == []


def test_raw_ippe_defect_still_present_or_fixed(rng, K):
    """Documents the trap the workaround exists for (passes either way; prints the rate)."""
    T = _view(rng)
    uv, _ = project(K, T, SLAB)
    wrong = 0
    for perm in itertools.permutations(range(4)):
        p = list(perm)
        n, rv, tv, _ = cv2.solvePnPGeneric(
            SLAB[p].reshape(-1, 1, 3), uv[p].reshape(-1, 1, 2), K, None, flags=cv2.SOLVEPNP_IPPE
        )
        R, _ = cv2.Rodrigues(rv[0])
        wrong += np.linalg.norm(-R.T @ tv[0].ravel() - camera_center(T)) > 1e-3
    assert 0 <= wrong <= 24


def test_sqpnp_non_coplanar_and_lm(rng, K):
    X = rng.uniform([0, 0, 0], [8, 11, 7], size=(10, 3))
    assert not is_coplanar(X)
    T = _view(rng)
    uv, _ = project(K, T, X)
    res = solve_pnp(X, uv + rng.normal(0, 0.5, uv.shape), K, T)
    assert res.success
    assert np.linalg.norm(camera_center(res.cam_from_world) - camera_center(T)) < 0.5
    assert res.rmse_px < 1.5


def test_refine_reduces_error_from_perturbed_start(rng, K):
    X = rng.uniform([0, 0, 0], [8, 11, 7], size=(8, 3))
    T = _view(rng)
    uv, _ = project(K, T, X)
    start = T.copy()
    start[:3, :3] = so3_exp([0.02, -0.03, 0.01]) @ start[:3, :3]
    start[:3, 3] += [0.5, -0.4, 0.8]
    out, rmse = refine_pose(X, uv, K, start)
    assert rmse < 1e-6
    assert rotation_angle_deg(out, T) < 1e-6


def test_jacobian_matches_finite_differences(rng, K):
    X = rng.uniform([0, 0, 0], [8, 11, 7], size=(6, 3))
    T = _view(rng)
    J, uv = pose_jacobian(K, T, X)
    R_wc, C = T[:3, :3].T, camera_center(T)
    eps = 1e-6
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        R2 = so3_exp(d[3:]) @ R_wc
        C2 = C + d[:3]
        T2 = np.eye(4)
        T2[:3, :3] = R2.T
        T2[:3, 3] = -R2.T @ C2
        uv2, _ = project(K, T2, X)
        np.testing.assert_allclose(J[:, i], ((uv2 - uv) / eps).reshape(-1), rtol=1e-3, atol=1e-2)


def test_covariance_matches_monte_carlo(K):
    rng = np.random.default_rng(7)
    X = np.array([(x, y, 6.75) for y in (0, 4, 7, 11) for x in (0, 4, 8)], dtype=float)
    T = look_at([4, -20, 18], [4, 5.5, 3.5])
    uv, _ = project(K, T, X)
    cov = pose_covariance(K, T, X, 1.0)
    errs = []
    for _ in range(300):
        res = solve_pnp(X, uv + rng.normal(0, 1.0, uv.shape), K, T)
        errs.append(camera_center(res.cam_from_world) - camera_center(T))
    mc = np.var(np.array(errs), axis=0).sum()
    assert 0.7 < mc / np.trace(cov[:3, :3]) < 1.4


def test_degenerate_inputs_fail_with_reason(K):
    T = look_at([4, -20, 18], [4, 5.5, 3.5])
    uv, _ = project(K, T, SLAB)
    res = solve_pnp(SLAB[:3], uv[:3], K, T)
    assert not res.success and "too few" in res.failure_reason
    np.testing.assert_array_equal(res.cam_from_world, T)
    line = np.array([(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)], dtype=float)
    # exactly on a line, and 1 mm off it (which SQPnP "solved" 50 m from the truth at 0.01 px)
    for pts in (line, line + np.array([(0, 0, 0), (0, 0.001, 0), (0, 0, 0), (0, 0, 0)])):
        res = solve_pnp(pts, project(K, T, pts)[0], K, T)
        assert not res.success
        assert res.failure_code is FailureCode.DEGENERATE_GEOMETRY
        assert "lie on a line" in res.failure_reason
        assert res.rmse_px == np.inf
        np.testing.assert_array_equal(res.cam_from_world, T)
    with pytest.raises(ValueError, match="same length"):
        solve_pnp(SLAB, uv[:3], K)
    with pytest.raises(ValueError, match=r"shape \(N, 2\)"):
        solve_pnp(SLAB, np.zeros((4, 3)), K)


def test_prior_mahalanobis(K):
    T = look_at([4, -20, 18], [4, 5.5, 3.5])
    assert prior_mahalanobis_sq(T, T) == pytest.approx(0.0, abs=1e-12)
    T2 = np.linalg.inv(np.linalg.inv(T) + np.pad(np.array([[3.0], [0], [0]]), ((0, 1), (3, 0))))
    assert prior_mahalanobis_sq(T2, T) == pytest.approx(1.0, rel=1e-6)
