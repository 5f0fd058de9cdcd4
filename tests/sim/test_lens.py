"""A real camera: distortion exact against OpenCV, rolling shutter and blur in render and truth.

The mapping tests compare with ``cv2.projectPoints`` (to 1e-6 px, pure maths); the warp test
draws Gaussian blobs into a "wide render" and finds their centroids in the delivered image
(<= 0.1 px, static and moving, against ``cv2.projectPoints`` and the rolling-shutter truth); the
render tests run OpenCV's ArUco detector on pybullet renders through the Mavic 2 Pro model and
find the corners of every marker of 25 px or more within 1 px of the truth (about 0.3 px of that
is the detector's own inward bias, also seen with the ideal pinhole; smaller markers cost the
detector about 1 px through the pinhole too).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from localization.aruco import ArucoLocalizer
from localization.geometry.distortion import distort_points, undistort_points
from localization.geometry.transforms import invert
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.lens import (
    MAVIC2PRO,
    CameraModel,
    LensView,
    Motion,
    line_blur,
    make_camera_model,
)
from uav_struct_env.sim.uav import UavState

D = np.array(MAVIC2PRO.distortion)


@pytest.fixture(scope="module")
def mavic() -> LensView:
    return LensView(MAVIC2PRO, 1280, 720)


def _points_in_view(rng: np.random.Generator, n: int) -> np.ndarray:
    """Camera-frame points spread over the Mavic's 1280 x 720 field."""
    z = rng.uniform(8.0, 60.0, n)
    x = rng.uniform(-0.62, 0.62, n) * z
    y = rng.uniform(-0.34, 0.34, n) * z
    return np.stack([x, y, z], axis=1)


def test_distort_points_equals_cv2_projectpoints_and_inverts(mavic: LensView) -> None:
    rng = np.random.default_rng(0)
    X = _points_in_view(rng, 2000)
    K = mavic.camera.K
    expected = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D)[0][:, 0]
    pinhole = X[:, :2] / X[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
    assert np.abs(distort_points(pinhole, K, D) - expected).max() < 1e-6
    assert np.abs(undistort_points(expected, K, D) - pinhole).max() < 1e-6


def test_static_map_is_exact_against_projectpoints(mavic: LensView) -> None:
    """The remap's map sends each delivered pixel to the render pixel of the same ray."""
    rng = np.random.default_rng(1)
    X = _points_in_view(rng, 500)
    uv = cv2.projectPoints(X, np.zeros(3), np.zeros(3), mavic.camera.K, D)[0][:, 0]
    uv = uv[(uv[:, 0] > 1) & (uv[:, 0] < 1278) & (uv[:, 1] > 1) & (uv[:, 1] < 718)]
    mx, my = mavic._static
    sample = np.stack([
        cv2.remap(m, uv[:, 0].astype(np.float32)[None], uv[:, 1].astype(np.float32)[None],
                  cv2.INTER_LINEAR)[0] for m in (mx, my)], axis=1)
    rays = undistort_points(uv, mavic.camera.K, D)
    Kr, K = mavic.render_camera.K, mavic.camera.K
    expected = (rays - K[:2, 2]) / [K[0, 0], K[1, 1]] * [Kr[0, 0], Kr[1, 1]] + Kr[:2, 2]
    assert np.abs(sample - expected).max() < 0.02


def _blob_render(view: LensView, X: np.ndarray, sigma: float = 2.0) -> np.ndarray:
    """A wide "render": Gaussian blobs at the render-camera projections of camera-frame points."""
    Kr = view.render_camera.K
    q = X[:, :2] / X[:, 2:] * [Kr[0, 0], Kr[1, 1]] + Kr[:2, 2]
    img = np.zeros((view.render_camera.height, view.render_camera.width), np.float32)
    yy, xx = np.mgrid[0: img.shape[0], 0: img.shape[1]]
    for u, v in q:
        sl = (slice(max(int(v) - 12, 0), int(v) + 13), slice(max(int(u) - 12, 0), int(u) + 13))
        img[sl] += 250.0 * np.exp(-((xx[sl] - u) ** 2 + (yy[sl] - v) ** 2) / (2 * sigma**2))
    return np.repeat(np.clip(img, 0, 255).astype(np.uint8)[..., None], 3, axis=2)


def _centroids(image: np.ndarray, uv: np.ndarray, radius: int = 10) -> np.ndarray:
    g = image[..., 0].astype(np.float64)
    out = []
    for u, v in uv:
        r0, c0 = int(round(v)), int(round(u))
        patch = g[r0 - radius: r0 + radius + 1, c0 - radius: c0 + radius + 1]
        yy, xx = np.mgrid[r0 - radius: r0 + radius + 1, c0 - radius: c0 + radius + 1]
        w = np.clip(patch - 3.0, 0, None)
        out.append([np.sum(w * xx) / w.sum(), np.sum(w * yy) / w.sum()])
    return np.array(out)


@pytest.mark.parametrize("motion", [None, Motion([6.0, -2.0, 1.0], [0.2, -0.3, 1.2])],
                         ids=["static", "moving"])
def test_warped_blobs_land_on_the_truth(mavic: LensView, motion: Motion | None) -> None:
    """Blobs on a plane 25 m ahead: delivered centroids = projectPoints / rolling-shutter truth."""
    cam_from_world = np.eye(4)
    gx, gy = np.meshgrid(np.linspace(-0.5, 0.5, 7), np.linspace(-0.26, 0.26, 5))
    X = np.stack([gx.ravel() * 25.0, gy.ravel() * 25.0, np.full(gx.size, 25.0)], axis=1)
    depth = np.full((mavic.render_camera.height, mavic.render_camera.width), 25.0, np.float32)
    out, _ = mavic.warp(_blob_render(mavic, X), depth, cam_from_world, motion)
    truth, *_ = mavic.project(cam_from_world, X, motion)
    if motion is None:
        expected = cv2.projectPoints(X, np.zeros(3), np.zeros(3), mavic.camera.K, D)[0][:, 0]
        np.testing.assert_allclose(truth, expected, atol=1e-6)
    else:  # the readout moves the points by pixels: the test can tell
        static, *_ = mavic.project(cam_from_world, X)
        assert np.abs(truth - static).max() > 10.0
    err = np.linalg.norm(_centroids(out, truth) - truth, axis=1)
    assert err.max() <= 0.1, err.round(3)


def test_row_time_convention(mavic: LensView) -> None:
    """The centre of the frame is exposed at the step's pose; rows 47 ms apart top to bottom."""
    t = mavic.row_time([-0.5, 359.5, 719.5])
    np.testing.assert_allclose(t, [-0.0235, 0.0, 0.0235], atol=1e-12)


def test_motion_between_states_moves_the_camera_as_the_kinematics_did() -> None:
    before = UavState.make([0.0, 0.0, 10.0], 0.3, 0.4)
    after = UavState.make([2.0, -1.0, 10.5], 0.5, 0.3)
    m = Motion.between(before, after, 0.5)
    np.testing.assert_allclose(m.velocity, [4.0, -2.0, 1.0])
    # Advancing `after` by the step's angular rates for 10 ms = rotating by w * 10 ms.
    ahead = UavState.make(after.xyz, 0.5 + 0.4 * 0.01, 0.3 - 0.2 * 0.01)
    R = cv2.Rodrigues(m.angular_velocity * 0.01)[0] @ after.world_from_cam[:3, :3]
    np.testing.assert_allclose(R, ahead.world_from_cam[:3, :3], atol=1e-5)
    assert Motion.between(before, after, 0.0).is_static


def test_line_blur_keeps_the_centroid() -> None:
    img = np.zeros((41, 41, 3), np.uint8)
    img[20, 20] = 255
    out = line_blur(img, (6.0, 2.0)).astype(np.float64)[..., 0]
    yy, xx = np.mgrid[0:41, 0:41]
    assert abs(np.sum(out * xx) / out.sum() - 20) < 1e-3 and abs(np.sum(out * yy) / out.sum() - 20) < 1e-3
    assert (out > 0).sum() >= 6  # spread along the segment
    assert line_blur(img, (0.2, 0.1)) is img


def test_paper_model_is_the_ideal_pinhole_and_bad_models_are_refused() -> None:
    paper = make_camera_model("paper")
    assert paper.is_ideal and not MAVIC2PRO.is_ideal
    assert paper.camera(640, 360) == CameraModel().intrinsics.scaled(640, 360)
    with pytest.raises(ConfigError, match="camera must be one of"):
        make_camera_model("gopro")
    with pytest.raises(ConfigError, match="distortion must hold the 5"):
        CameraModel(distortion=(0.1, 0.2))
    with pytest.raises(ConfigError, match="readout_time"):
        CameraModel(readout_time=-0.01)
    with pytest.raises(ConfigError, match="cannot be inverted"):
        LensView(CameraModel(distortion=(-0.9, 0, 0, 0, 0)), 320, 180)


POSES = [([8.0, -16.0, 12.0], np.pi / 2, 0.75), ([-6.0, -10.0, 9.0], np.pi / 3, 0.7)]


@pytest.mark.parametrize("motion", [None, Motion([0.0, 8.0, -2.0], [0.3, 0.0, -1.0])],
                         ids=["hovering", "moving"])
def test_aruco_finds_the_marker_corners_at_the_truth(paper_world, egl_ok, mavic, motion) -> None:
    world = paper_world("slab", "egl" if egl_ok else "tiny")
    aruco = ArucoLocalizer(world.site.markers, mavic.camera.K)
    errors, sizes, shifts = [], [], []
    for position, yaw, pitch in POSES:
        T = invert(UavState.make(position, yaw, pitch).world_from_cam)
        result = world.render(T, mavic.render_camera, depth=True)
        image, _ = mavic.warp(result.rgb, result.depth, T, motion)
        truth = mavic.landmark_truth(
            world.landmark_truth("aruco", T, mavic.render_camera, result), T, motion
        )
        ids, corners = aruco.detect(image)
        assert len(ids) >= 4
        for marker_id, found in zip(ids, corners, strict=True):
            k = aruco._index[int(marker_id)]
            xyz = aruco.corners_world[4 * k: 4 * k + 4]
            rows = [int(np.argmin(np.linalg.norm(truth["xyz"] - p, axis=1))) for p in xyz]
            assert np.all(truth["visible"][rows])
            d = found - found[[2, 3, 0, 1]]
            size = np.sqrt(0.5 * abs(d[0, 0] * d[1, 1] - d[0, 1] * d[1, 0]))  # sqrt of the quad's area
            errors.append(np.linalg.norm(found - truth["uv"][rows], axis=1))
            sizes.append(np.full(4, size))
            shifts.append(np.linalg.norm(mavic.project(T, xyz)[0] - truth["uv"][rows], axis=1))
    errors, sizes = np.concatenate(errors), np.concatenate(sizes)
    # Markers under 25 px cost the detector itself about 1 px, through the ideal pinhole too.
    assert np.sum(sizes >= 25) >= 16 and errors[sizes >= 25].max() <= 1.0, errors.round(2)
    assert np.median(errors) <= 0.5
    if motion is not None:  # the truth moved with the readout, and the image with it
        assert np.concatenate(shifts).max() > 5.0
