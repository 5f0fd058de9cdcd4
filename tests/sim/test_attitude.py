"""The attitude convention (docs/environment.md): ZYX Euler, body FLU, positive pitch looks down."""

import numpy as np
import pytest

from localization.geometry.transforms import invert, look_at, project
from uav_struct_env.sim.attitude import attitude_from_world_from_cam, world_from_cam_from_attitude


def optical_axis(world_from_cam):
    return world_from_cam[:3, 2]


def test_zero_attitude_looks_along_x_with_image_down_being_world_down():
    T = world_from_cam_from_attitude([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(optical_axis(T), [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(T[:3, 0], [0, -1, 0], atol=1e-12)  # image right = world -y
    np.testing.assert_allclose(T[:3, 1], [0, 0, -1], atol=1e-12)  # image down = world down
    np.testing.assert_allclose(T[:3, 3], [1, 2, 3])


def test_positive_pitch_looks_down_and_yaw_is_counter_clockwise():
    T = world_from_cam_from_attitude([0, 0, 0], [0.0, np.radians(30), 0.0])
    assert optical_axis(T)[2] == pytest.approx(-0.5)
    T = world_from_cam_from_attitude([0, 0, 0], [0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(optical_axis(T), [0, 1, 0], atol=1e-12)


def test_positive_roll_lifts_the_cameras_left_side():
    # A point ahead, to the world's left (+y), at the camera's height: with positive roll the
    # camera's left side goes up, so the horizon on the left appears below the image centre.
    T = world_from_cam_from_attitude([0, 0, 0], [np.radians(10), 0.0, 0.0])
    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    uv, _ = project(K, invert(T), [[10.0, 1.0, 0.0]])
    assert uv[0, 0] < 50 and uv[0, 1] > 50


@pytest.mark.parametrize("seed", range(5))
def test_round_trip_and_agreement_with_look_at(seed):
    rng = np.random.default_rng(seed)
    att = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-1.4, 1.4), rng.uniform(-3.1, 3.1)])
    pos = rng.normal(size=3) * 10
    T = world_from_cam_from_attitude(pos, att)
    p2, a2 = attitude_from_world_from_cam(T)
    np.testing.assert_allclose(p2, pos)
    np.testing.assert_allclose(a2, att, atol=1e-9)
    # look_at (image up ~ world up) is the zero-roll attitude
    eye, target = rng.normal(size=3) * 20 + [0, 0, 30], rng.normal(size=3)
    Tl = invert(look_at(eye, target))
    _, (roll, pitch, yaw) = attitude_from_world_from_cam(Tl)
    assert roll == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(world_from_cam_from_attitude(eye, (0.0, pitch, yaw)), Tl, atol=1e-9)
