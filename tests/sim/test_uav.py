import math

import numpy as np
import pytest

from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.uav import FlightLimits, Geofence, Obstacles, UavState, step_uav
from uav_struct_env.site import paper_site

LIM = FlightLimits()


def test_forward_moves_along_heading_and_left_is_90_degrees_ccw():
    s = UavState.make([0, 0, 10], yaw=math.pi / 2, pitch=0.3)
    s1 = step_uav(s, np.array([1.0, 0, 0, 0, 0]), LIM, 0.5)
    np.testing.assert_allclose(s1.xyz, [0, 5.0, 10], atol=1e-12)
    s2 = step_uav(s, np.array([0, 1.0, 0, 0, 0]), LIM, 0.5)
    np.testing.assert_allclose(s2.xyz, [-5.0, 0, 10], atol=1e-12)


def test_horizontal_command_clipped_to_unit_disc_and_vertical_is_asymmetric():
    s = UavState.make([0, 0, 10], 0.0, 0.0)
    s1 = step_uav(s, np.array([1.0, 1.0, 0, 0, 0]), LIM, 1.0)
    assert np.hypot(*s1.xyz[:2]) == pytest.approx(LIM.max_horizontal_speed)
    assert step_uav(s, np.array([0, 0, 1.0, 0, 0]), LIM, 1.0).xyz[2] == pytest.approx(
        10 + LIM.max_ascent_speed
    )
    assert step_uav(s, np.array([0, 0, -1.0, 0, 0]), LIM, 1.0).xyz[2] == pytest.approx(
        10 - LIM.max_descent_speed
    )


def test_yaw_wraps_and_gimbal_pitch_is_clipped_to_its_range():
    s = UavState.make([0, 0, 10], yaw=3.0, pitch=1.5)
    s1 = step_uav(s, np.array([0, 0, 0, 1.0, 1.0]), LIM, 1.0)
    assert -math.pi <= s1.yaw < math.pi
    assert s1.yaw == pytest.approx(3.0 + LIM.max_yaw_rate - 2 * math.pi)
    assert s1.pitch == pytest.approx(LIM.gimbal_pitch_max)
    s2 = step_uav(s, np.array([0, 0, 0, 0, -1.0]), LIM, 10.0)
    assert s2.pitch == pytest.approx(LIM.gimbal_pitch_min)


def test_true_attitude_has_zero_roll_and_the_gimbal_pitch():
    s = UavState.make([1, 2, 3], 0.4, 0.5)
    np.testing.assert_allclose(s.attitude, [0.0, 0.5, 0.4])
    assert s.world_from_cam[2, 2] == pytest.approx(-math.sin(0.5))  # optical axis looks down
    T = s.world_from_cam  # computed once per state; the caller gets its own copy
    T[:] = 0.0
    assert s.world_from_cam[2, 2] == pytest.approx(-math.sin(0.5))
    assert s == UavState.make([1, 2, 3], 0.4, 0.5)


def test_geofence():
    g = Geofence(min_altitude=2, max_altitude=50, max_distance=30)
    assert g.violation([0, 0, 10], [0, 0]) is None
    assert g.violation([0, 0, 1], [0, 0]) == "below_min_altitude"
    assert g.violation([0, 0, 51], [0, 0]) == "above_max_altitude"
    assert g.violation([25, 25, 10], [0, 0]) == "beyond_max_distance"
    with pytest.raises(ConfigError, match="min_altitude"):
        Geofence(min_altitude=10, max_altitude=5)


def test_bad_limits_raise():
    with pytest.raises(ConfigError, match="max_yaw_rate"):
        FlightLimits(max_yaw_rate=-1.0)
    with pytest.raises(ConfigError, match="gimbal pitch range"):
        FlightLimits(gimbal_pitch_min=0.5, gimbal_pitch_max=0.2)


def test_obstacles_from_paper_site():
    site = paper_site("columns")
    obs = Obstacles.from_site(site)
    assert obs.names.count("S1") == 8  # the slab cut into 3 x 3 cells minus the stair opening
    col = site.columns[0]
    assert obs.distances([[col.x, col.y, 1.0]])[0] == 0.0
    assert obs.distances([[col.x + 1.175, col.y, 1.0]])[0] == pytest.approx(1.0)
    # through the middle of the stair opening, at slab level: clear of the slab
    slab = site.slabs[0]
    (cx, cy) = slab.openings[0].center
    assert obs.distances([[cx, cy, slab.z_top - 0.1]])[0] > 1.0
    # on top of the slab elsewhere: touching
    assert obs.distances([[6.0, 2.0, slab.z_top + 0.2]])[0] == pytest.approx(0.2)
    d, name = obs.nearest([4.0, 4.0, 7.5])
    assert name.startswith("C1") and d == pytest.approx(7.5 - site.columns[-1].z_top)


def test_state_from_a_camera_pose_round_trips_and_drops_roll():
    rng = np.random.default_rng(5)
    for pitch in [*rng.uniform(-math.pi / 2, math.pi / 2, 200), math.pi / 2, -math.pi / 2]:
        s = UavState.make(rng.normal(0, 20, 3), rng.uniform(-math.pi, math.pi), pitch)
        back = UavState.from_world_from_cam(s.world_from_cam)
        np.testing.assert_allclose(back.world_from_cam, s.world_from_cam, atol=1e-9)
    # an estimate with a small roll: the same heading and pitch, roll 0 (what the gimbal holds)
    from localization.geometry.attitude import world_from_cam_from_attitude

    rolled = world_from_cam_from_attitude([1.0, 2.0, 3.0], [math.radians(0.5), 0.4, 1.2])
    s = UavState.from_world_from_cam(rolled)
    assert s.attitude[0] == 0.0
    assert abs(s.pitch - 0.4) < 1e-12 and abs(s.yaw - 1.2) < 1e-12
