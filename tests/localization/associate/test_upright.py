"""The upright two-point solver and the batched pose steps of robust association."""

from __future__ import annotations

import numpy as np

from localization.associate.assign_kernels import assign_many
from localization.associate.hypotheses import spread_anchor_pairs
from localization.associate.paper import assign
from localization.associate.upright import upright_two_point
from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import camera_center, look_at, project, so3_exp
from localization.pose.batch import pose_difference_many, project_many, refine_many, so3_exp_many
from localization.pose.covariance import pose_difference


def _random_view(rng: np.random.Generator) -> np.ndarray:
    angle = rng.uniform(0, 2 * np.pi)
    eye = np.array([25 * np.cos(angle), 25 * np.sin(angle), rng.uniform(5, 25)])
    return look_at(eye, rng.uniform(-2, 2, 3))


def test_upright_two_point_recovers_a_known_pose_exactly(rng):
    K = PAPER_K
    for _ in range(50):
        T = _random_view(rng)
        X = rng.uniform(-6, 6, size=(2, 3))
        uv, depth = project(K, T, X)
        assert np.all(depth > 0)
        yaw = rng.uniform(-0.3, 0.3)
        # the prior's attitude: the true one turned about the world z axis (tilt exact)
        R_wc0 = so3_exp([0.0, 0.0, yaw]) @ T[:3, :3].T
        rays = np.column_stack([uv, np.ones(2)]) @ np.linalg.inv(K).T @ R_wc0.T
        psi, C, ok = upright_two_point(rays[:1], rays[1:], X[:1], X[1:])
        err = np.linalg.norm(C - camera_center(T), axis=1)
        k = int(np.argmin(np.where(ok, err, np.inf)))
        assert ok[k] and err[k] < 1e-7, (err, ok)
        assert abs(psi[k] + yaw) < 1e-9
        R_wc = so3_exp([0.0, 0.0, psi[k]]) @ R_wc0
        np.testing.assert_allclose(R_wc, T[:3, :3].T, atol=1e-9)


def test_upright_two_point_rejects_what_has_no_solution():
    d = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # both rays horizontal
    psi, C, ok = upright_two_point(d[:1], d[1:], np.array([[0.0, 0, 5]]), np.array([[1.0, 0, 0]]))
    assert not ok.any()
    down = np.array([[0.1, 0.0, -1.0]])
    X = np.array([[1.0, 2.0, 3.0]])
    assert not upright_two_point(down, down, X, X)[2].any()  # one point twice
    # the higher landmark on the lower ray, the lower on the level one: no positive depths
    r1, r2 = np.array([[1.0, 0.0, 0.0]]), np.array([[1.0, 0.0, -0.01]])
    assert not upright_two_point(r1, r2, np.array([[0.0, 0, 0]]), np.array([[0.0, 0, 10]]))[2].any()


def _least_squares_pose(X: np.ndarray, uv: np.ndarray, K: np.ndarray, start: np.ndarray) -> np.ndarray:
    """The reprojection least-squares optimum by SciPy (rotation vector + translation), a reference
    independent of the package's LM."""
    from scipy.optimize import least_squares

    def residuals(x: np.ndarray) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = so3_exp(x[:3]) @ start[:3, :3], x[3:]
        return (project(K, T, X)[0] - uv).ravel()

    x = least_squares(residuals, np.concatenate([np.zeros(3), start[:3, 3]]), xtol=1e-14, ftol=1e-14).x
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = so3_exp(x[:3]) @ start[:3, :3], x[3:]
    return T


def test_refine_many_reaches_the_least_squares_optimum(rng):
    K = PAPER_K
    Rs, ts, Xs, uvs, want = [], [], [], [], []
    for _ in range(6):
        T = _random_view(rng)
        X = rng.uniform(-6, 6, size=(9, 3))
        uv = project(K, T, X)[0] + rng.normal(0, 1.0, (9, 2))
        start = T.copy()
        start[:3, :3] = so3_exp(rng.normal(0, 0.02, 3)) @ T[:3, :3]
        start[:3, 3] += rng.normal(0, 0.5, 3)
        want.append(_least_squares_pose(X, uv, K, start))
        Rs.append(start[:3, :3])
        ts.append(start[:3, 3])
        Xs.append(X)
        uvs.append(uv)
    mask = np.ones((6, 9), dtype=bool)
    mask[0, 7:] = False  # padding: the masked pairs must not count
    uvs[0][7:] += 300.0
    start0 = np.vstack([np.column_stack([Rs[0], ts[0]]), [0, 0, 0, 1]])
    want[0] = _least_squares_pose(Xs[0][:7], uvs[0][:7], K, start0)
    R, t, cost = refine_many(K, np.array(Rs), np.array(ts), np.array(Xs), np.array(uvs), mask, iterations=30)
    for h in range(6):
        np.testing.assert_allclose(R[h], want[h][:3, :3], atol=1e-7)
        np.testing.assert_allclose(t[h], want[h][:3, 3], atol=1e-5)
    assert np.all(np.isfinite(cost)) and np.all(cost < 9 * 2 * 4.0)


def test_refine_many_robust_weights_resist_a_wrong_pair(rng):
    K = PAPER_K
    T = _random_view(rng)
    X = rng.uniform(-6, 6, size=(10, 3))
    uv = project(K, T, X)[0] + rng.normal(0, 0.5, (10, 2))
    uv[0] += [35.0, -25.0]  # a wrong pair inside a 40 px coarse gate
    mask = np.ones((1, 10), dtype=bool)
    args = (K, T[None, :3, :3], T[None, :3, 3], X[None], uv[None], mask)
    plain = refine_many(*args, iterations=20)
    robust = refine_many(*args, iterations=20, robust_px=10.0)
    err = [np.linalg.norm(-r[0].T @ tt[0] - camera_center(T)) for r, tt, _ in (plain, robust)]
    assert err[1] < 0.5 * err[0], err


def test_assign_many_is_the_minimum_cost_assignment_on_separated_points(rng):
    model = rng.uniform(0, 1000, size=(4, 12, 2))
    model[:, :, 0] += 60 * np.arange(12)  # at least tens of px apart
    det = model[0, rng.permutation(12)[:9]] + rng.normal(0, 2.0, (9, 2))
    det = np.vstack([det, [[-500.0, -500.0], [np.nan, np.nan]]])  # clutter and a NaN row
    proj = model.copy()
    proj[1] = model[0] + [3.0, -2.0]
    proj[2, 3] = np.nan  # a landmark behind the camera
    got = assign_many(det, proj, 10.0)
    for h in range(4):
        want = np.full(det.shape[0], -1)
        fin = np.isfinite(det).all(axis=1)
        ok_cols = np.isfinite(proj[h]).all(axis=1)
        local = assign(det[fin], proj[h][ok_cols], 10.0)
        want[np.flatnonzero(fin)[local >= 0]] = np.flatnonzero(ok_cols)[local[local >= 0]]
        np.testing.assert_array_equal(got[h], want)
    assert got[0, 9] == -1 and got[0, 10] == -1


def test_batched_geometry_matches_the_scalar_functions(rng):
    w = rng.normal(0, 1.0, (20, 3))
    w[0] = 1e-9
    R = so3_exp_many(w)
    for i in range(20):
        np.testing.assert_allclose(R[i], so3_exp(w[i]), atol=1e-12)
    Ts = np.array([_random_view(rng) for _ in range(5)])
    prior = _random_view(rng)
    d = pose_difference_many(Ts[:, :3, :3], Ts[:, :3, 3], prior)
    for i in range(5):
        np.testing.assert_allclose(d[i], pose_difference(Ts[i], prior), atol=1e-9)
    X = rng.uniform(-5, 5, (7, 3))
    uv, depth = project_many(PAPER_K, Ts[:, :3, :3], Ts[:, :3, 3], X)
    for i in range(5):
        want, wd = project(PAPER_K, Ts[i], X)
        np.testing.assert_allclose(depth[i], wd, atol=1e-9)
        np.testing.assert_allclose(uv[i][wd > 0], want[wd > 0], atol=1e-6)


def test_anchor_pairs_avoid_outlying_clutter(rng):
    cluster = rng.uniform(500, 700, size=(10, 2))
    det = np.vstack([cluster, [[5.0, 5.0], [1270.0, 710.0], [1270.0, 5.0]]])
    pairs = spread_anchor_pairs(det)
    assert pairs.shape == (6, 2)
    assert np.all(pairs < 10)
    assert spread_anchor_pairs(det[:1]).shape == (0, 2)
    assert sorted(tuple(sorted(p)) for p in spread_anchor_pairs(det[:3]).tolist()) == [(0, 1), (0, 2), (1, 2)]


def test_anchor_pairs_add_the_likeliest_detections(rng):
    """With scores, the pairs among the four likeliest detections join the spread-out ones
    (each pair once); without, or with at most four detections, nothing changes."""
    det = np.vstack([rng.uniform(150, 250, size=(14, 2)), [[430, 407], [811, 413], [773, 273], [507, 270]]])
    log_odds = np.concatenate([np.full(14, -1.0), [4.0, 4.0, 3.0, 1.0]])
    plain = spread_anchor_pairs(det)
    assert np.all(plain < 14)  # the dense part is the clutter
    pairs = spread_anchor_pairs(det, log_odds=log_odds)
    np.testing.assert_array_equal(pairs[: len(plain)], plain)
    assert sorted(tuple(sorted(p)) for p in pairs[len(plain):].tolist()) == [
        (14, 15), (14, 16), (14, 17), (15, 16), (15, 17), (16, 17)]
    both = spread_anchor_pairs(det[10:], log_odds=log_odds[10:])  # anchors shared with the top four
    assert len({tuple(sorted(p)) for p in both.tolist()}) == len(both)
    np.testing.assert_array_equal(
        spread_anchor_pairs(det[:4], log_odds=log_odds[:4]), spread_anchor_pairs(det[:4])
    )
