"""The pinhole camera and its exact conversion to pybullet's matrices (no rendering here)."""

from __future__ import annotations

import numpy as np
import pytest

from localization.geometry.transforms import look_at, project
from uav_struct_env.sim.camera import (
    GL_FROM_CV,
    Camera,
    depth_from_buffer,
    projection_matrix,
    view_matrix,
)


def _gl_pixels(camera: Camera, cam_from_world: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixel (u, v) where OpenGL puts ``points``: NDC -> u = (x+1) W/2 - 0.5, row 0 at NDC y=+1."""
    P = np.array(projection_matrix(camera)).reshape(4, 4).T
    V = np.array(view_matrix(cam_from_world)).reshape(4, 4).T
    clip = (P @ V @ np.c_[points, np.ones(len(points))].T).T
    ndc = clip[:, :3] / clip[:, 3:]
    u = (ndc[:, 0] + 1) * camera.width / 2 - 0.5
    v = (1 - ndc[:, 1]) * camera.height / 2 - 0.5
    return np.c_[u, v], ndc[:, 2]


def test_default_camera_is_the_papers():
    cam = Camera()
    assert (cam.width, cam.height) == (1280, 720)
    np.testing.assert_array_equal(cam.K, [[1108.5, 0, 640], [0, 1108.5, 360], [0, 0, 1]])
    assert cam.K.dtype == np.float64


@pytest.mark.parametrize(
    "camera",
    [Camera(), Camera(cx=600.0, cy=390.0), Camera(width=333, height=211, fx=300, fy=310, cx=170.2,
                                                  cy=99.7, skew=2.0)],
)
def test_projection_matrix_reproduces_K_exactly(camera, rng):
    cam_from_world = look_at([3.0, -20.0, 12.0], [1.0, 2.0, 0.5])
    pts = rng.uniform([-10, -5, 0], [10, 15, 8], (200, 3))
    uv_gl, _ = _gl_pixels(camera, cam_from_world, pts)
    uv_k, depth = project(camera.K, cam_from_world, pts)
    assert np.all(depth > 0)
    np.testing.assert_allclose(uv_gl, uv_k, atol=1e-9)


def test_depth_buffer_round_trip(rng):
    camera = Camera(near=0.5, far=300.0)
    cam_from_world = look_at([0.0, -30.0, 10.0], [0.0, 0.0, 0.0])
    pts = rng.uniform([-10, -5, 0], [10, 15, 8], (50, 3))
    _, ndc_z = _gl_pixels(camera, cam_from_world, pts)
    _, depth = project(camera.K, cam_from_world, pts)
    buffer = (ndc_z + 1) / 2  # OpenGL's default depth range
    np.testing.assert_allclose(depth_from_buffer(buffer, camera), depth, rtol=1e-5)
    assert depth_from_buffer(np.ones(1), camera)[0] == pytest.approx(camera.far)


def test_view_matrix_is_gl_flip_of_cam_from_world():
    T = look_at([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    V = np.array(view_matrix(T)).reshape(4, 4).T  # column-major
    np.testing.assert_allclose(V, GL_FROM_CV @ T)


def test_scaled_keeps_field_of_view_and_pixel_edges():
    cam = Camera(cx=600.0, cy=390.0)
    small = cam.scaled(128, 72)
    assert (small.width, small.height) == (128, 72)
    assert small.fx == pytest.approx(110.85)
    # The image's left edge u = -0.5 maps to itself, the right edge W - 0.5 to w - 0.5.
    for c, s, full, part in (("cx", "fx", 1280, 128), ("cy", "fy", 720, 72)):
        for edge_full, edge_small in ((-0.5, -0.5), (full - 0.5, part - 0.5)):
            ray = (edge_full - getattr(cam, c)) / getattr(cam, s)
            assert getattr(small, c) + ray * getattr(small, s) == pytest.approx(edge_small)
    assert cam.scaled(1280, 720) == cam


def test_from_K_round_trip():
    cam = Camera(width=640, height=480, fx=500, fy=510, cx=300.5, cy=250.0, near=0.2, far=100.0)
    again = Camera.from_K(cam.K, 640, 480, near=0.2, far=100.0)
    assert again == cam


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"width": 0}, r"Camera.width must be an int >= 1, got 0"),
        ({"height": 7.5}, r"Camera.height must be an int >= 1, got 7.5"),
        ({"fx": -1.0}, "focal lengths must be positive"),
        ({"near": 0.0}, "0 < near < far"),
        ({"near": 10.0, "far": 5.0}, "0 < near < far"),
        ({"cx": float("nan")}, "cx must be finite"),
    ],
)
def test_bad_camera_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Camera(**kwargs)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="shape"):
        Camera.from_K(np.eye(2), 10, 10)
    with pytest.raises(ValueError, match="cam_from_world"):
        view_matrix(np.eye(3))
    with pytest.raises(TypeError, match="cx must be a number"):
        Camera(cx="640")


def test_a_replaced_camera_equals_dataclasses_replace_and_builds_its_own_K():
    """The renders' unchecked copy (near plane, shifted principal point) is ``replace``'s camera."""
    from dataclasses import replace

    cam = Camera().scaled(64, 36)
    before = cam.K  # cached on the camera
    moved = cam._replaced(cx=cam.cx - 0.5, cy=cam.cy + 0.25, near=0.7)
    assert moved == replace(cam, cx=cam.cx - 0.5, cy=cam.cy + 0.25, near=0.7)
    assert moved.K[0, 2] == cam.cx - 0.5 and moved.K[1, 2] == cam.cy + 0.25  # not the cached K
    np.testing.assert_array_equal(cam.K, before)
    assert type(moved.near) is float and moved.width == 64
