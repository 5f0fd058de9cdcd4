"""The env's ``camera`` setting: the paper's pinhole unchanged, the Mavic 2 Pro's real camera.

With ``camera="mavic2pro"`` a moving UAV's image shows distortion and rolling shutter, and
OpenCV's ArUco detector finds the marker corners at ``info[agent]["landmarks"]["aruco"]["uv"]``
within 1 px for every marker of 25 px or more (median 0.4 px over all; markers under 25 px,
a few px tall at grazing angles, cost the detector itself up to 1.7 px through the ideal pinhole
too); the wrapper's localizer gets the env's coefficients.
"""

from __future__ import annotations

import numpy as np
import pytest
from env_helpers import small_parallel_env

import uav_struct_env
from localization.aruco import ArucoLocalizer
from localization.geometry.transforms import invert
from uav_struct_env.envs.settings import settings_markdown
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.lens import MAVIC2PRO, LensView
from uav_struct_env.wrappers.localize import LocalizePoses


def test_paper_camera_renders_exactly_the_pinhole_view_with_zero_distortion() -> None:
    env = small_parallel_env(camera="paper")
    try:
        obs, infos = env.reset(seed=0, options={"viewpoint": 2})
        obs, _, _, _, infos = env.step({a: np.full(5, 0.5, np.float32) for a in env.agents})
        assert env.camera == Camera().scaled(128, 72)
        for agent in env.agents:
            direct = env.world.render(invert(infos[agent]["world_from_cam"]), env.camera).rgb
            np.testing.assert_array_equal(obs[agent]["image"], direct)  # bit for bit, moving or not
            np.testing.assert_array_equal(infos[agent]["distortion"], np.zeros(5))
    finally:
        env.close()


def test_camera_setting_is_validated_and_documented() -> None:
    with pytest.raises(ConfigError, match=r"camera must be one of \['mavic2pro', 'paper'\] or a CameraModel"):
        small_parallel_env(camera="gopro")
    row = next(line for line in settings_markdown().splitlines() if line.startswith("| `camera` |"))
    assert "| `'paper'` |" in row and "mavic2pro" in row  # default by name, the presets explained


@pytest.fixture(scope="module")
def mavic_step():
    """A moving step of the Mavic 2 Pro env at 1280 x 720 (observations, infos, env)."""
    env = uav_struct_env.parallel_env("paper", camera="mavic2pro", stage="slab")
    env.reset(seed=0, options={"viewpoint": 0})
    # Forward, climbing, turning and tilting: every row of the frame sees another pose.
    obs, _, _, _, infos = env.step({a: np.array([0.6, 0.3, 0.3, 0.5, 0.2], np.float32) for a in env.agents})
    yield obs, infos, env
    env.close()


def test_mavic_info_carries_its_intrinsics_and_distortion(mavic_step) -> None:
    obs, infos, env = mavic_step
    expected = MAVIC2PRO.camera(1280, 720).K
    for agent in env.agents:
        np.testing.assert_array_equal(infos[agent]["intrinsics"], expected)
        np.testing.assert_array_equal(infos[agent]["distortion"], MAVIC2PRO.distortion)
        assert obs[agent]["image"].shape == (720, 1280, 3)
    wrapper = LocalizePoses(env, landmarks="slab_corners")
    np.testing.assert_array_equal(wrapper.stack.localizer.distortion, MAVIC2PRO.distortion)
    aruco = LocalizePoses(env, landmarks="aruco", detector="aruco")
    np.testing.assert_array_equal(aruco.stack.aruco.dist_coeffs, MAVIC2PRO.distortion)


def test_aruco_finds_the_corners_where_the_info_says(mavic_step) -> None:
    obs, infos, env = mavic_step
    view = LensView(MAVIC2PRO, 1280, 720)
    errors, sizes, shutter = [], [], []
    for agent in env.agents:
        truth = infos[agent]["landmarks"]["aruco"]
        detector = ArucoLocalizer(env.site.markers, infos[agent]["intrinsics"])
        ids, corners = detector.detect(obs[agent]["image"])
        static, *_ = view.project(invert(infos[agent]["world_from_cam"]), truth["xyz"])
        for marker_id, found in zip(ids, corners, strict=True):
            k = detector._index.get(int(marker_id))
            if k is None:  # a false detection (an id the site does not have)
                continue
            rows = [int(np.argmin(np.linalg.norm(truth["xyz"] - p, axis=1)))
                    for p in detector.corners_world[4 * k: 4 * k + 4]]
            assert np.all(truth["visible"][rows])
            d = found - found[[2, 3, 0, 1]]
            size = np.sqrt(0.5 * abs(d[0, 0] * d[1, 1] - d[0, 1] * d[1, 0]))  # sqrt of the quad's area
            errors.append(np.linalg.norm(found - truth["uv"][rows], axis=1))
            sizes.append(np.full(4, size))
            shutter.append(np.linalg.norm(static[rows] - truth["uv"][rows], axis=1))
    errors, sizes = np.concatenate(errors), np.concatenate(sizes)
    assert np.sum(sizes >= 25) >= 32, "too few markers found to test"
    assert errors[sizes >= 25].max() <= 1.0, errors[sizes >= 25].round(2)
    # Markers under 25 px (a few px tall at grazing angles) cost the detector itself up to 1.7 px
    # through the ideal pinhole too (same views, camera="paper"): that tail is the detector's.
    assert np.median(errors) <= 0.5 and errors.max() <= 2.0, errors.round(2)
    assert np.concatenate(shutter).max() > 5.0  # the readout moved them: the truth followed


def test_learned_detector_output_localizes_through_the_distorting_lens(mavic_step) -> None:
    """The learned detector's points (distorted pixels) localize once the localizer undistorts."""
    from localization import Localizer
    from localization.detect.learned import LearnedDetector
    from localization.geometry.transforms import camera_center

    _, _, env = mavic_step
    obs, infos = env.reset(seed=0, options={"viewpoint": 3})  # hovering: no rolling shutter
    detector = LearnedDetector.for_localizer("slab_corners", 1280, "robust", None, True)
    model = env.site.landmarks("slab_corners")
    with_d, without = [], []
    for agent in env.agents:
        info = infos[agent]
        found = detector.detect(obs[agent]["image"], {"image_size": (1280, 720)})
        truth = camera_center(invert(info["world_from_cam"]))
        for distortion, errors in ((info["distortion"], with_d), (None, without)):
            est = Localizer(model.xyz, info["intrinsics"], distortion=distortion).localize(
                found, invert(info["prior_world_from_cam"]))
            assert est.success, est.failure_reason
            errors.append(np.linalg.norm(camera_center(est.cam_from_world) - truth))
    assert np.median(with_d) < 0.2 and np.median(without) > 1.5 * np.median(with_d), (with_d, without)


def test_mavic_depth_raycast_and_render_paths() -> None:
    """Depth is warped with the image; without images the truth is ray-cast through the lens too."""
    env = small_parallel_env(camera="mavic2pro", observe_depth=True, render_mode="rgb_array")
    rays = small_parallel_env(camera="mavic2pro", observe_image=False, render_mode="rgb_array")
    try:
        obs, infos = env.reset(seed=1, options={"viewpoint": 1})
        _, ray_infos = rays.reset(seed=1, options={"viewpoint": 1})
        for agent in env.agents:
            depth = obs[agent]["depth"]
            assert depth.shape == (72, 128) and env.observation_space(agent).contains(obs[agent])
            a, b = infos[agent]["landmarks"]["all"], ray_infos[agent]["landmarks"]["all"]
            np.testing.assert_allclose(a["uv"], b["uv"])  # the same lens projection
            assert np.mean(a["visible"] == b["visible"]) > 0.95
            # the depth at a marker corner's pixel (on the ground) is its depth: warped as the image
            m = infos[agent]["landmarks"]["aruco"]
            k = np.flatnonzero(m["visible"])
            cols, rows = np.clip(np.rint(m["uv"][k]).astype(int).T, 0, [[127], [71]])
            T = infos[agent]["world_from_cam"]
            z = (m["xyz"][k] - T[:3, 3]) @ T[:3, 2]
            assert len(k) >= 8 and np.median(np.abs(depth[rows, cols] - z) / z) < 0.03
        frame = rays.render()
        assert frame.ndim == 3 and frame.dtype == np.uint8 and frame.std() > 5
    finally:
        env.close()
        rays.close()


def test_mavic_env_passes_pettingzoo_api_and_seed_tests() -> None:
    """Moving frames warp by the step's motion; the same seed gives the same frames."""
    from functools import partial

    from pettingzoo.test import parallel_api_test, parallel_seed_test

    env = small_parallel_env(camera="mavic2pro")
    parallel_api_test(env, num_cycles=4)
    env.close()
    parallel_seed_test(partial(small_parallel_env, camera="mavic2pro"), num_cycles=4)
