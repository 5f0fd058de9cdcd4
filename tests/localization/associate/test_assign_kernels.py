"""The compiled refine / re-association rounds of robust association (localization.pose.lm)."""

from __future__ import annotations

import numpy as np

from localization.associate.assign_kernels import refine_reassign
from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import camera_center, look_at, project, so3_exp
from localization.pose.covariance import pose_difference

W, H = PAPER_IMAGE_SIZE


def _scene(rng: np.random.Generator, n: int = 12):
    """Landmarks on a 3 x 4 grid of column tops, a view of them, their pixels with 0.5 px noise."""
    gx, gy = np.meshgrid(np.arange(4) * 5.0 - 7.5, np.arange(3) * 5.0 - 5.0)
    L = np.column_stack([gx.ravel(), gy.ravel(), np.full(12, 3.0)])[:n]
    T = look_at(np.array([24.0, -18.0, 16.0]), np.zeros(3))
    uv, depth = project(PAPER_K, T, L)
    assert np.all(depth > 0) and np.all((uv >= 0) & (uv < [W, H]))
    return L, T, uv + rng.normal(0.0, 0.5, uv.shape)


def _perturbed(T: np.ndarray, rng: np.random.Generator, pos_m: float, rot_deg: float) -> np.ndarray:
    out = T.copy()
    dR = so3_exp(np.radians(rot_deg) * rng.normal(size=3) / np.sqrt(3))
    C = camera_center(T) + pos_m * rng.normal(size=3) / np.sqrt(3)
    out[:3, :3] = T[:3, :3] @ dR.T
    out[:3, 3] = -out[:3, :3] @ C
    return out


def _run(L, det, a, starts, first_robust=True, need=4, max_iterations=6):
    good = np.flatnonzero(np.isfinite(det).all(axis=1))
    return refine_reassign(
        PAPER_K, L, det, good, a, np.ascontiguousarray(starts[:, :3, :3]),
        np.ascontiguousarray(starts[:, :3, 3]), W, H, 60.0, 5.0, 40.0, max_iterations, need, first_robust,
    )


def test_wrong_coarse_pairs_are_corrected_and_the_pose_converges(rng):
    L, T, det = _scene(rng)
    truth = np.arange(12)
    a = truth.copy()
    a[[2, 7]] = a[[7, 2]]  # two identities swapped
    a[5] = -1  # and one detection left out
    starts = np.stack([_perturbed(T, rng, 0.5, 0.5), _perturbed(T, rng, 0.5, 0.5)])
    coarse = np.stack([a, truth])
    out_a, R, t, alive = _run(L, det, coarse, starts)
    assert alive.all()
    for k in range(2):
        np.testing.assert_array_equal(out_a[k], truth)
        Tk = np.eye(4)
        Tk[:3, :3], Tk[:3, 3] = R[k], t[k]
        d = pose_difference(Tk, T)
        assert np.linalg.norm(d[:3]) < 0.05 and np.degrees(np.linalg.norm(d[3:])) < 0.1, d
        np.testing.assert_allclose(R[k] @ R[k].T, np.eye(3), atol=1e-12)
    # the inputs are left as they were
    np.testing.assert_array_equal(coarse[0], a)


def test_a_hypothesis_with_too_few_pairs_dies_and_one_behind_the_camera_too(rng):
    L, T, det = _scene(rng)
    few = np.full(12, -1)
    few[:3] = np.arange(3)
    behind = _perturbed(T, rng, 0.0, 0.0)
    behind[:3, :3] = so3_exp([0.0, np.pi, 0.0]) @ behind[:3, :3]  # turned to look away
    behind[:3, 3] = -behind[:3, :3] @ camera_center(T)
    starts = np.stack([T, behind])
    _, _, _, alive = _run(L, det, np.stack([few, np.arange(12)]), starts)
    assert not alive[0]
    assert not alive[1]


def test_nan_detections_stay_unassigned_and_clutter_is_not_paired(rng):
    L, T, det = _scene(rng)
    det = np.vstack([det, [[np.nan, np.nan], [5.0, 5.0]]])  # a NaN row and far clutter
    a = np.concatenate([np.arange(12), [-1, -1]])
    out_a, _, _, alive = _run(L, det, a[None], np.stack([_perturbed(T, rng, 0.3, 0.3)]), first_robust=False)
    assert alive[0]
    np.testing.assert_array_equal(out_a[0], a)


def _dense_assign(det: np.ndarray, proj: np.ndarray, gate_sq: float, rounds: int) -> np.ndarray:
    """Mutual nearest neighbours on the full (N, M) matrix: the definition the kernel must keep."""
    with np.errstate(invalid="ignore"):
        d2 = ((det[:, None, :] - proj[None]) ** 2).sum(axis=2)
        d2[~(d2 <= gate_sq)] = np.inf
    out = np.full(det.shape[0], -1)
    for _ in range(rounds):
        jn, inn = d2.argmin(axis=1), d2.argmin(axis=0)  # argmin: the first of equals
        ok = (inn[jn] == np.arange(det.shape[0])) & np.isfinite(d2[np.arange(det.shape[0]), jn])
        if not ok.any():
            break
        out[ok] = jn[ok]
        d2[ok, :] = np.inf
        d2[:, jn[ok]] = np.inf
    return out


def test_assignment_over_the_gated_pairs_is_the_dense_mutual_nearest_one(rng):
    from localization.associate.assign_kernels import assign_many

    for trial in range(300):  # integer pixels: equal distances, whose ties the index order breaks
        n, m = rng.integers(1, 40), rng.integers(1, 30)
        det = rng.integers(0, 60, (n, 2)).astype(float)
        proj = rng.integers(0, 60, (3, m, 2)).astype(float)
        det[rng.random(n) < 0.1] = np.nan
        proj[rng.random((3, m)) < 0.1] = np.nan
        gate = float(rng.choice([3.0, 8.0, 25.0, 100.0]))
        rounds = int(rng.integers(1, 4))
        got = assign_many(det, proj, gate, rounds)
        for h in range(3):
            np.testing.assert_array_equal(got[h], _dense_assign(det, proj[h], gate * gate, rounds),
                                          err_msg=f"trial {trial}, layout {h}")


def _brute_votes(ux: np.ndarray, uy: np.ndarray, cnt: np.ndarray) -> np.ndarray:
    near = (np.abs(ux[:, None] - ux[None]) <= 1) & (np.abs(uy[:, None] - uy[None]) <= 1)
    return near.astype(np.int64) @ cnt


def test_neighbour_votes_count_the_3x3_neighbourhood_on_the_grid_and_by_search(rng):
    from localization.associate.hypothesis_kernels import MAX_GRID, neighbour_votes

    cells = np.unique(rng.integers(-6, 7, size=(60, 2)), axis=0)  # sorted by x, then y
    cnt = rng.integers(1, 5, size=cells.shape[0])
    ux, uy = cells[:, 0].copy(), cells[:, 1].copy()
    np.testing.assert_array_equal(neighbour_votes(ux, uy, cnt), _brute_votes(ux, uy, cnt))
    # one cell far away makes the dense grid too large: the binary search gives the same counts
    far = np.vstack([cells, [[10 * MAX_GRID, 0]]])
    cnt_far = np.append(cnt, 3)
    ux, uy = far[:, 0].copy(), far[:, 1].copy()
    assert (ux.max() - ux.min() + 3) * (uy.max() - uy.min() + 3) > MAX_GRID
    np.testing.assert_array_equal(neighbour_votes(ux, uy, cnt_far), _brute_votes(ux, uy, cnt_far))


def _reference_cells(cx: np.ndarray, cy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    cells, cell, cnt = np.unique(np.stack([cx, cy], axis=1), axis=0, return_inverse=True, return_counts=True)
    return cells[:, 0], cells[:, 1], cnt, cell.ravel()


def test_distinct_cells_count_on_the_grid_and_by_sort_alike(rng):
    from localization.associate.hypothesis_kernels import MAX_GRID, distinct_cells

    cx, cy = rng.integers(-40, 41, size=500), rng.integers(-30, 31, size=500)
    for x, y in ((cx, cy), (np.append(cx, 2 * MAX_GRID), np.append(cy, -7))):  # grid, then sort
        ux, uy, cnt, cell, nu = distinct_cells(x, y, x.size)
        rx, ry, rcnt, rcell = _reference_cells(x, y)
        assert nu == rx.size
        for got, want in ((ux[:nu], rx), (uy[:nu], ry), (cnt[:nu], rcnt), (cell, rcell)):
            np.testing.assert_array_equal(got, want)


def test_best_cells_rank_by_votes_then_the_lower_cell():
    from localization.associate.hypothesis_kernels import best_cells

    votes = np.array([3, 7, 7, 1, 9, 7])
    assert best_cells(votes, 4).tolist() == [4, 1, 2, 5]
    assert best_cells(votes, 9).tolist() == np.argsort(-votes * 6 + np.arange(6)).tolist()


def test_shift_votes_find_a_planted_image_shift(rng):
    from localization.associate.hypothesis_kernels import shift_votes

    proj = rng.uniform(100, 1100, size=(3, 12, 2))
    proj[1, :4] = np.nan  # landmarks behind the camera propose nothing
    shift = np.array([57.0, -23.0])
    det = np.vstack([proj[1, 4:] + shift + rng.normal(0, 1.0, (8, 2)), rng.uniform(0, 1280, (3, 2))])
    lay, s = shift_votes(det, proj, 40.0, 2)
    assert lay.tolist() == [0, 0, 1, 1, 2, 2]
    np.testing.assert_allclose(s[2], shift, atol=1.0)  # layout 1's best shift is the planted one


def test_the_compiled_steps_refuse_inconsistent_shapes_before_reading_out_of_bounds():
    import pytest

    from localization.associate.assign_kernels import assign_many
    from localization.pose.batch import refine_many
    from localization.pose.pnp import refine_pose

    with pytest.raises(ValueError, match="refine_pose needs"):
        refine_pose(np.zeros((5, 3)), np.zeros((4, 2)), PAPER_K, np.eye(4))
    R, t = np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 3))
    with pytest.raises(ValueError, match=r"refine_many needs .* \(2, 4\)"):
        refine_many(PAPER_K, R, t, np.zeros((2, 4, 3)), np.zeros((2, 3, 2)), np.ones((2, 4), bool))
    with pytest.raises(ValueError, match="assign_many needs"):
        assign_many(np.zeros((3, 3)), np.zeros((1, 4, 2)), 5.0)
