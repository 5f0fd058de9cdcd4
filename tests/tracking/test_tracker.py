"""Multi-view worker tracking with real numbers: exact recovery, noise and pose-error scaling,
association of close workers, degenerate cases, distortion, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from conftest import SITE_CENTRE, detect, four_views, random_workers

from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import invert, look_at, make_transform, project, so3_exp
from tracking import (
    CameraView,
    WorkerDetection,
    error_summary,
    gate,
    track_workers,
    triangulate_point,
    worker_errors,
)


def _pure(result) -> bool:
    return all(len(set(w.labels)) == 1 for w in result.workers)


def test_noise_free_views_recover_every_worker_exactly(views, rng):
    workers = random_workers(rng, 12)
    result = track_workers(views, detect(views, workers))
    assert len(result.tracked) == 12 and len(result.workers) == 12 and result.n_detections == 48
    assert _pure(result)
    assert all(w.cameras == ("uav_0", "uav_1", "uav_2", "uav_3") for w in result.tracked)
    for w in result.tracked:
        np.testing.assert_allclose(w.points, workers[w.label], atol=1e-9)
        assert w.feet.chi2 < 1e-12 and w.feet.dof == 5


def test_error_scales_with_pixel_noise_and_covariance_is_consistent(views, rng):
    workers = random_workers(rng, 12)
    medians, nees = {}, []
    for sigma in (0.5, 2.0):
        errs = []
        for _ in range(8):
            result = track_workers(views, detect(views, workers, rng, sigma))
            assert len(result.tracked) == 12 and _pure(result)
            errs.extend(worker_errors(result, workers))
            if sigma == 2.0:
                for w in result.tracked:
                    for k, point in enumerate((w.feet, w.head)):
                        e = point.xyz - workers[w.label][k]
                        nees.append(e @ np.linalg.solve(point.covariance, e))
        medians[sigma] = float(np.median(errs))
    # error proportional to the pixel noise: 4x the noise, 4x the error (sampling: +-25 %)
    assert 3.0 < medians[2.0] / medians[0.5] < 5.0
    # about 25 m away with four views, 1 px ~ 2.3 cm per view: 2 px gives a few cm
    assert 0.02 < medians[2.0] < 0.15
    # the covariance is the right size: mean NEES of a 3D point is 3
    assert 2.5 < np.mean(nees) < 3.5


def _perturbed(view: CameraView, rng, position_m: float, rotation_deg: float) -> CameraView:
    world_from_cam = invert(view.cam_from_world)
    R = so3_exp(rng.normal(0.0, np.radians(rotation_deg), 3)) @ world_from_cam[:3, :3]
    t = world_from_cam[:3, 3] + rng.normal(0.0, position_m, 3)
    cov = np.diag([position_m**2] * 3 + [np.radians(rotation_deg) ** 2] * 3)
    return view.replace_pose(invert(make_transform(R, t)), cov)


def _run(views, rng, pos, rot, with_covariance=True, trials=8):
    errs, impure, tracked = [], 0, 0
    for _ in range(trials):
        workers = random_workers(rng, 10)
        est = [_perturbed(v, rng, pos, rot) if pos else v for v in views]
        if not with_covariance:
            est = [v.replace_pose(v.cam_from_world) for v in est]  # claimed exact
        result = track_workers(est, detect(est, workers, rng, 1.0, truth_views=views))
        impure += sum(len(set(w.labels)) > 1 for w in result.tracked)
        tracked += len(result.tracked)
        errs.extend(worker_errors(result, workers))
    return error_summary(errs), impure, tracked


def test_error_grows_with_pose_error_and_pose_covariance_keeps_association(views, rng):
    exact, impure0, tracked0 = _run(views, rng, 0.0, 0.0)
    good, impure, tracked = _run(views, rng, 0.05, 0.1)  # about the localizer's column-top errors
    assert impure0 == 0 and tracked0 == 80
    assert impure <= 1 and tracked >= 78
    assert exact["median_m"] < 0.05 < good["median_m"] < 0.15
    # 0.05 m and 0.1 deg per camera (5 cm at 29 m) roughly triple the worker error, no more
    assert good["p95_m"] < 0.25
    # the same poses claimed exact: gates too tight (workers split or left out), errors larger
    claimed, impure_claimed, tracked_claimed = _run(views, rng, 0.05, 0.1, with_covariance=False)
    assert impure_claimed + abs(tracked_claimed - 80) > impure + abs(tracked - 80)
    assert claimed["p95_m"] > good["p95_m"]


def test_upright_workers_share_their_horizontal_position(views, rng):
    workers = random_workers(rng, 12)
    exact = track_workers(views, detect(views, workers), upright=True)
    assert np.max(worker_errors(exact, workers)) < 1e-9
    independent, upright, nees = [], [], []
    for _ in range(6):
        dets = detect(views, workers, rng, 2.0)
        independent.extend(worker_errors(track_workers(views, dets), workers))
        result = track_workers(views, dets, upright=True)
        upright.extend(worker_errors(result, workers))
        for w in result.tracked:
            assert np.allclose(w.feet_xyz[:2], w.head_xyz[:2]) and w.feet.dof == 6
            e = w.feet_xyz - workers[w.label][0]
            nees.append(e @ np.linalg.solve(w.feet.covariance, e))
    # four unknowns instead of six: the horizontal position from both points, about 25 % better
    assert np.median(upright) < 0.85 * np.median(independent)
    assert np.percentile(upright, 95) < 0.9 * np.percentile(independent, 95)
    assert 2.4 < np.mean(nees) < 3.6
    # a leaning worker (head 0.5 m to the side) does not fit the model: its chi-square shows it
    leaning = {"w": workers["w0"] + [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]]}
    w = track_workers(views, detect(views, leaning), upright=True).tracked[0]
    assert w.feet.chi2 + w.head.chi2 > 10 * gate(0.999, 12)


def test_close_workers_are_associated_correctly(views, rng):
    # pairs of workers 0.3-0.5 m apart: in a single pair of views they are often confusable
    workers = {}
    for k, base in enumerate(random_workers(rng, 6, spacing=3.0).values()):
        offset = rng.uniform(0.3, 0.5) * np.array([*np.ravel(so3_exp([0, 0, rng.uniform(0, 6.3)])[:2, 0]), 0])
        workers[f"a{k}"] = base
        workers[f"b{k}"] = base + offset
        workers[f"b{k}"][1, 2] = base[1, 2] - 0.2  # a shorter colleague
    for _ in range(10):
        result = track_workers(views, detect(views, workers, rng, 1.0), height_range=(1.0, 2.3))
        assert _pure(result)
        assert len(result.tracked) == 12
        assert np.max(worker_errors(result, workers)) < 0.15


def test_inconsistent_detection_is_left_out(views, rng):
    workers = random_workers(rng, 5)
    dets = detect(views, workers, rng, 1.0)
    bad = dets["uav_2"][0]
    dets["uav_2"][0] = WorkerDetection(bad.feet_uv + [40.0, 0.0], bad.head_uv + [40.0, 0.0], 1.0, bad.label)
    result = track_workers(views, dets)
    assert _pure(result) and len(result.tracked) == 5
    left = [w for w in result.workers if not w.success]
    assert len(left) == 1 and left[0].detections == (("uav_2", 0),)
    assert left[0].failure_reason == "feet: seen by 1 camera only: a 3D point needs two"
    assert np.all(np.isnan(left[0].points))
    (victim,) = [w for w in result.tracked if w.label == bad.label]
    assert victim.cameras == ("uav_0", "uav_1", "uav_3")


def test_one_view_is_reported_not_crashed(views, rng):
    workers = random_workers(rng, 3)
    dets = detect(views[:1], workers)
    result = track_workers(views, dets)
    assert result.tracked == () and len(result.workers) == 3
    assert all("seen by 1 camera only" in w.failure_reason for w in result.workers)
    assert error_summary(worker_errors(result, workers)) == {
        "median_m": pytest.approx(np.nan, nan_ok=True), "p95_m": pytest.approx(np.nan, nan_ok=True),
        "n_observations": 0}


def test_parallel_rays_are_reported_not_crashed():
    eye = SITE_CENTRE + [25.0, 0.0, 15.0]
    a = CameraView("a", look_at(eye, SITE_CENTRE), PAPER_K)
    b = CameraView("b", look_at(eye + [0.0, 0.02, 0.0], SITE_CENTRE), PAPER_K)  # 2 cm baseline at 29 m
    point = SITE_CENTRE + [1.0, 2.0, 1.7]
    uv = np.array([project(v.K, v.cam_from_world, point[None])[0][0] for v in (a, b)])
    est = triangulate_point([a, b], uv, 1.0)
    assert not est.success and est.ray_angle_deg < 0.1
    assert "viewing rays nearly parallel" in est.failure_reason and np.all(np.isnan(est.xyz))
    # the same camera twice: rays exactly parallel
    est = triangulate_point([a, CameraView("a2", a.cam_from_world, PAPER_K)], uv[[0, 0]], 1.0)
    assert not est.success and "nearly parallel" in est.failure_reason
    # and through the tracker: the pair is never associated, both detections left single
    det = {name: [WorkerDetection(p, p - [0, 60], 1.0)] for name, p in zip("ab", uv, strict=True)}
    result = track_workers([a, b], det)
    assert result.tracked == () and len(result.workers) == 2


def test_behind_camera_is_reported():
    # two cameras 2 m apart looking along +x; rays that diverge in front meet 3.3 m behind them
    a = CameraView("a", look_at([0.0, 0.0, 0.0], [10.0, 0.0, 0.0]), PAPER_K)
    b = CameraView("b", look_at([0.0, 2.0, 0.0], [10.0, 2.0, 0.0]), PAPER_K)
    uv = np.array([project(a.K, a.cam_from_world, [[10.0, -3.0, 0.0]])[0][0],
                   project(b.K, b.cam_from_world, [[10.0, 5.0, 0.0]])[0][0]])
    est = triangulate_point([a, b], uv, 1.0)
    assert not est.success
    assert est.failure_reason.startswith("the triangulated point is behind camera(s) ['a', 'b']")
    # the same cameras with converging rays: in front, exact
    uv = np.array([project(v.K, v.cam_from_world, [[10.0, 1.0, 0.0]])[0][0] for v in (a, b)])
    est = triangulate_point([a, b], uv, 1.0)
    assert est.success and np.linalg.norm(est.xyz - [10.0, 1.0, 0.0]) < 1e-9


def test_distorted_detections_are_undistorted_exactly(rng):
    dist = np.array([-0.12, 0.05, 0.001, -0.0005, -0.01])
    views = [CameraView(v.name, v.cam_from_world, v.K, distortion=dist) for v in four_views()]
    workers = random_workers(rng, 8)
    dets = {}
    for v in views:
        rvec, _ = cv2.Rodrigues(v.cam_from_world[:3, :3])
        out = []
        for name, pts in workers.items():
            uv, _ = cv2.projectPoints(pts, rvec, v.cam_from_world[:3, 3], v.K, dist)
            out.append(WorkerDetection(uv[0, 0], uv[1, 0], 1.0, name))
        dets[v.name] = out
    result = track_workers(views, dets)
    assert len(result.tracked) == 8 and _pure(result)
    assert np.max(worker_errors(result, workers)) < 1e-6
    # the same pixels read as an ideal pinhole are wrong by decimetres (the test can fail)
    pinhole = [CameraView(v.name, v.cam_from_world, v.K) for v in views]
    wrong = track_workers(pinhole, dets, gate_probability=1 - 1e-12)
    assert np.max(worker_errors(wrong, workers), initial=1.0) > 0.01


def test_bad_input_names_the_value(views):
    det = WorkerDetection([1.0, 2.0], [1.0, 1.0], 1.0)
    with pytest.raises(ValueError, match=r"detections name views \['uav_9'\]"):
        track_workers(views, {"uav_9": [det]})
    with pytest.raises(ValueError, match="view names must be unique, got 'uav_0' twice"):
        track_workers([views[0], views[0]], {})
    with pytest.raises(ValueError, match=r"gate_probability must be a number in \(0, 1\), got 1.0"):
        track_workers(views, {}, gate_probability=1.0)
    with pytest.raises(ValueError, match=r"feet_uv must have shape \(2,\)"):
        WorkerDetection([1.0, 2.0, 3.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="sigma_px must be finite and > 0, got 0"):
        WorkerDetection([1.0, 2.0], [1.0, 1.0], 0.0)
    with pytest.raises(ValueError, match="distortion must be 4, 5 or 8"):
        CameraView("a", views[0].cam_from_world, PAPER_K, distortion=[0.1, 0.2])
    with pytest.raises(ValueError, match="pose_covariance must be positive semi-definite"):
        CameraView("a", views[0].cam_from_world, PAPER_K, pose_covariance=-np.eye(6))
    with pytest.raises(TypeError, match="must hold WorkerDetection objects, got tuple"):
        track_workers(views, {"uav_0": [((1, 2), (3, 4))]})
    assert track_workers(views, {}).workers == ()
