"""The simulated worker detector and the tracker's camera views from the env's infos."""

import cv2
import numpy as np
import pytest

import uav_struct_env
from localization import PoseEstimate
from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import invert, look_at, project
from uav_struct_env.errors import ConfigError
from uav_struct_env.tracking_sim import SimulatedWorkerDetector, camera_views

T = look_at([30.0, 0.0, 15.0], [0.0, 0.0, 0.0])
WORKERS = {"a": np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.75]]),
           "b": np.array([[3.0, -2.0, 0.0], [3.0, -2.0, 1.6]]),
           "behind": np.array([[40.0, 0.0, 20.0], [40.0, 0.0, 21.7]]),   # behind the camera
           "outside": np.array([[0.0, 60.0, 0.0], [0.0, 60.0, 1.7]])}   # left of the image
VISIBLE = {"a": 1.0, "b": 0.6, "behind": 1.0, "outside": 1.0}


def test_detects_what_is_visible_in_front_and_in_the_image():
    det = SimulatedWorkerDetector(pixel_sigma=1e-9, miss_rate=0.0, rng=np.random.default_rng(0))
    out = det.detect(WORKERS, VISIBLE, PAPER_K, T, PAPER_IMAGE_SIZE)
    assert [d.label for d in out] == ["a", "b"]
    for d in out:
        uv, _ = project(PAPER_K, T, WORKERS[d.label])
        np.testing.assert_allclose(d.points_uv, uv, atol=1e-6)
        assert d.sigma_px == 1e-9
    # half hidden: below min_visible 0.7 "b" (0.6 visible) is not detected; absent = invisible
    det = SimulatedWorkerDetector(pixel_sigma=1.0, miss_rate=0.0, min_visible=0.7)
    assert [d.label for d in det.detect(WORKERS, VISIBLE, PAPER_K, T, PAPER_IMAGE_SIZE)] == ["a"]
    assert det.detect(WORKERS, {}, PAPER_K, T, PAPER_IMAGE_SIZE) == []


def test_lens_distortion_is_projected_like_opencv():
    dist = np.array([-0.2, 0.08, 0.001, -0.002, -0.01])
    det = SimulatedWorkerDetector(pixel_sigma=1e-9, miss_rate=0.0)
    edge = {"c": np.array([[0.0, 16.0, 0.0], [0.0, 16.0, 1.7]])}  # near the image's left edge
    (d,) = det.detect(edge, {"c": 1.0}, PAPER_K, T, PAPER_IMAGE_SIZE, dist)
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    uv, _ = cv2.projectPoints(edge["c"], rvec, T[:3, 3], PAPER_K, dist)
    np.testing.assert_allclose(d.points_uv, uv.reshape(2, 2), atol=1e-6)
    assert np.max(np.abs(d.points_uv - project(PAPER_K, T, edge["c"])[0])) > 10.0  # distortion matters


def test_noise_misses_and_seeds():
    det = SimulatedWorkerDetector(pixel_sigma=2.0, miss_rate=0.3, rng=np.random.default_rng(4))
    truth = {k: project(PAPER_K, T, WORKERS[k])[0] for k in ("a", "b")}
    found, residuals = 0, []
    for _ in range(500):
        for d in det.detect(WORKERS, VISIBLE, PAPER_K, T, PAPER_IMAGE_SIZE):
            found += 1
            residuals.append(d.points_uv - truth[d.label])
    assert found / 1000 == pytest.approx(0.7, abs=0.04)
    assert np.std(residuals) == pytest.approx(2.0, rel=0.05)
    again = [SimulatedWorkerDetector(2.0, 0.3, rng=np.random.default_rng(9)).detect(
        WORKERS, VISIBLE, PAPER_K, T, PAPER_IMAGE_SIZE) for _ in range(2)]
    assert [d.label for d in again[0]] == [d.label for d in again[1]]
    assert all(np.array_equal(x.points_uv, y.points_uv) for x, y in zip(*again, strict=True))
    # default noise: 2 px at the paper's 1280 px, scaled to the image width
    assert SimulatedWorkerDetector().sigma(320) == pytest.approx(0.5)
    with pytest.raises(ConfigError, match=r"min_visible must be a number in \(0, 1\], got 0"):
        SimulatedWorkerDetector(min_visible=0)


def test_only_workers_the_env_sees_are_detected():
    env = uav_struct_env.parallel_env(activity="busy", observe_image=False, landmark_sets=(),
                                      image_size=(320, 180))
    try:
        _, infos = env.reset(seed=5, options={"viewpoint": 1})
        points = env.worker_points()
        det = SimulatedWorkerDetector(miss_rate=0.0, rng=np.random.default_rng(0))
        hidden = detected = 0
        for agent in env.agents:
            vis = env.worker_visibility(agent)
            cam_from_world = invert(infos[agent]["world_from_cam"])
            out = det.detect(points, vis, infos[agent]["intrinsics"], cam_from_world, (320, 180))
            expected = set()
            for name, pts in points.items():
                uv, depth = project(infos[agent]["intrinsics"], cam_from_world, pts)
                inside = np.all(depth > 0) and np.all((uv > -0.5) & (uv < [319.5, 179.5]))
                if vis[name] >= 0.5 and inside:
                    expected.add(name)
            assert {d.label for d in out} == expected
            hidden += sum(1 for v in vis.values() if v < 0.5)
            detected += len(out)
        assert hidden > 0 and detected > 20  # a busy site hides some of its 16 workers from some cameras
    finally:
        env.close()


def test_camera_views_at_each_pose_source():
    prior = look_at([31.0, 1.0, 14.0], [0.0, 0.0, 0.0])
    info = {"world_from_cam": invert(T), "prior_world_from_cam": invert(prior), "intrinsics": PAPER_K}
    infos = {"u0": info, "u1": {**info, "distortion": np.zeros(5)}}
    truth = camera_views(infos, "truth")
    assert [v.name for v in truth] == ["u0", "u1"] and truth[0].pose_covariance is None
    np.testing.assert_allclose(truth[0].cam_from_world, T, atol=1e-12)
    pri = camera_views(infos, "prior")
    np.testing.assert_allclose(pri[1].cam_from_world, prior, atol=1e-12)
    assert pri[1].pose_covariance[0, 0] == pytest.approx(9.0)  # the paper's 3 m
    ok = PoseEstimate(True, T, np.array([]), 0.5, 6, covariance=np.eye(6) * 1e-4)
    failed = PoseEstimate(False, prior, np.array([]))
    est = camera_views(infos, "estimated", {"u0": ok, "u1": failed})
    assert [v.name for v in est] == ["u0"] and est[0].pose_covariance[0, 0] == 1e-4
    with pytest.raises(ConfigError, match="source='estimated' needs the localizer's estimates"):
        camera_views(infos, "estimated")
    with pytest.raises(ConfigError, match="source must be one of"):
        camera_views(infos, "gps")
