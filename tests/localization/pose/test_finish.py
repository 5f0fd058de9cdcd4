"""The robust localization's last step in one compiled call (localization.pose.finish).

``finish_pose`` must give exactly what the separate steps give -- ``refine_pose``, the depth of
``reprojection_residuals``, ``pose_covariance``, the edge-on spread and ``prior_mahalanobis_sq``
-- bit for bit, so that the localizer answers exactly as those steps would.
"""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from localization.geometry.camera import PAPER_K
from localization.geometry.kernels import minor_spread
from localization.geometry.transforms import camera_center, look_at, project, so3_exp
from localization.pose.covariance import PriorSigmas, pose_covariance, prior_distance_sq, prior_mahalanobis_sq
from localization.pose.finish import REFINE_ITERATIONS, REFINE_TOL, FinishInputs, finish_pose
from localization.pose.pnp import refine_pose, reprojection_residuals


def _moved(T: np.ndarray, rng: np.random.Generator, pos_m: float, rot_deg: float) -> np.ndarray:
    out = T.copy()
    out[:3, :3] = T[:3, :3] @ so3_exp(np.radians(rot_deg) * rng.normal(size=3) / np.sqrt(3)).T
    out[:3, 3] = -out[:3, :3] @ (camera_center(T) + pos_m * rng.normal(size=3) / np.sqrt(3))
    return out


def _separately(X, uv, T0, prior, sigmas, pixel_sigma=1.0):
    T, rmse = refine_pose(X, uv, PAPER_K, T0)
    _, depth = reprojection_residuals(PAPER_K, T, X, uv)
    cov = pose_covariance(PAPER_K, T, X, pixel_sigma)
    spread = float(minor_spread(np.ascontiguousarray(uv)))
    return T, rmse, bool(np.all(depth > 0)), cov, prior_mahalanobis_sq(T, prior, sigmas), spread


def _finished(L, det, a, T0, prior, sigmas, pixel_sigma=1.0):
    done = finish_pose(FinishInputs(PAPER_K, T0, L, det, a, pixel_sigma, prior, sigmas))
    q = done.prior_mahalanobis_sq
    return done.cam_from_world, done.rmse_px, done.in_front, done.covariance, q, done.spread_px


def test_the_refinement_defaults_are_refine_poses():
    # refine_pose runs 10 * max_iterations LM steps
    defaults = inspect.signature(refine_pose).parameters
    assert REFINE_ITERATIONS == 10 * defaults["max_iterations"].default
    assert REFINE_TOL == defaults["tol"].default


@pytest.mark.parametrize("n", [4, 7, 12])
def test_finish_pose_is_the_separate_steps_bit_for_bit(rng, n):
    L = np.column_stack([rng.uniform(-8, 8, 12), rng.uniform(-6, 6, 12), rng.uniform(0, 7, 12)])[:n]
    sigmas = PriorSigmas()
    for _ in range(20):
        eye = np.array([rng.uniform(15, 30), rng.uniform(-20, 20), rng.uniform(8, 25)])
        truth = look_at(eye, np.zeros(3))
        uv, depth = project(PAPER_K, truth, L)
        assert np.all(depth > 0)
        uv = uv + rng.normal(0.0, 1.0, uv.shape)
        start, prior = _moved(truth, rng, 0.3, 0.5), _moved(truth, rng, 3.0, 3.0)
        # the detections in another order, with two unassigned (clutter) among them
        det = np.vstack([uv, rng.uniform(0, 1000, (2, 2))])
        ids = np.concatenate([np.arange(n), [-1, -1]])
        order = rng.permutation(n + 2)
        det, ids = det[order], ids[order]
        m = ids >= 0
        a = _separately(L[ids[m]], det[m], start, prior, sigmas)
        b = _finished(L, det, ids, start, prior, sigmas)
        np.testing.assert_array_equal(a[0], b[0])  # the refined pose
        assert a[1] == b[1] and a[2] is b[2] is True  # rmse, every point in front
        np.testing.assert_array_equal(a[3], b[3])  # covariance
        assert a[4] == b[4] and a[5] == b[5]  # prior distance, spread
        assert 0 < a[1] < 3 and np.isfinite(a[3]).all() and a[4] > 0


def test_finish_pose_reports_points_behind_the_camera_and_far_priors(rng):
    L = np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0], [0, 3, 1.0], [2, 1, 2.0]])
    truth = look_at(np.array([20.0, -12.0, 14.0]), np.zeros(3))
    uv, _ = project(PAPER_K, truth, L)
    behind = np.array([[0.0, 0.0, 40.0]])  # a landmark behind this camera, above and far behind it
    X = np.vstack([L, camera_center(truth) + 2.0 * (camera_center(truth) - behind)])
    uv_b = np.vstack([uv, [[600.0, 400.0]]])
    sigmas = PriorSigmas()
    b = _finished(X, uv_b, np.arange(len(X)), truth, truth, sigmas)
    a = _separately(X, uv_b, truth, truth, sigmas)
    assert a[2] is b[2] is False
    np.testing.assert_array_equal(a[0], b[0])
    # a prior turned half a revolution away: the exact logarithm, as prior_mahalanobis_sq takes it
    flipped = truth.copy()
    flipped[:3, :3] = so3_exp(np.array([0.0, 0.0, np.pi - 0.01])) @ truth[:3, :3]
    flipped[:3, 3] = -flipped[:3, :3] @ camera_center(truth)
    refined = finish_pose(FinishInputs(PAPER_K, truth, L, uv, np.arange(len(L)), 1.0, flipped, sigmas))
    T = refined.cam_from_world
    _, far = prior_distance_sq(  # the kernel's distance is not exact here: finish_pose recomputes it
        np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]),
        np.ascontiguousarray(flipped[:3, :3]), camera_center(flipped), sigmas.as_array(),
    )
    assert far
    assert _finished(L, uv, np.arange(len(L)), truth, flipped, sigmas)[4] == _separately(
        L, uv, truth, flipped, sigmas)[4]
