import math

import numpy as np
import pytest

from localization.geometry.transforms import invert, project
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.schedule import PAPER_K, ScheduleSpec, make_schedule, sample_viewpoint
from uav_struct_env.site import paper_site


@pytest.fixture(scope="module")
def site():
    return paper_site("columns", marker_size=1.0)


@pytest.fixture(scope="module")
def schedule(site):
    return make_schedule(site, 4)


def test_shape_and_sides(schedule):
    assert schedule.positions.shape == (4, 10, 3)
    assert schedule.attitudes.shape == (4, 10, 3)
    assert schedule.sides == ("south", "east", "north", "west")
    d = schedule.positions[..., :2] - schedule.center[:2]
    az = np.degrees(np.arctan2(d[..., 1], d[..., 0]))
    for i, expected in enumerate([-90, 0, 90, 180]):
        off = (az[i] - expected + 180) % 360 - 180
        assert np.all(np.abs(off) <= 20.0 + 1e-9)


def test_ranges_and_stratification(site, schedule):
    spec = schedule.spec
    h = schedule.positions[..., 2]
    assert np.all((h >= spec.height[0]) & (h <= spec.height[1]))
    # every UAV covers each tenth of the height range exactly once (Latin hypercube)
    for i in range(4):
        strata = np.floor((h[i] - spec.height[0]) / (spec.height[1] - spec.height[0]) * 10).astype(
            int
        )
        assert sorted(strata) == list(range(10))
    # distance out from the own slab edge within 15-35 m (projected on the side's direction)
    xmin, ymin, xmax, ymax = site.building.slab_bounds
    out = np.stack(
        [
            ymin - schedule.positions[0, :, 1],
            schedule.positions[1, :, 0] - xmax,
            schedule.positions[2, :, 1] - ymax,
            xmin - schedule.positions[3, :, 0],
        ]
    )
    assert out.min() > 15.0 * math.cos(math.radians(20)) - 1e-6 and out.max() < 35.0 + 1e-6


def test_roll_zero_pitch_down_within_gimbal_range(schedule):
    roll, pitch = schedule.attitudes[..., 0], schedule.attitudes[..., 1]
    assert np.all(roll == 0.0)
    assert np.all((pitch > math.radians(10)) & (pitch < math.radians(80)))


@pytest.mark.parametrize("stage", ["slab", "columns"])
def test_every_structural_landmark_projects_inside_the_paper_image(schedule, stage):
    site = paper_site(stage, marker_size=1.0)
    pts = site.landmarks("all").xyz
    for i in range(4):
        for k in range(10):
            uv, depth = project(PAPER_K, invert(schedule.world_from_cam(i, k)), pts)
            assert np.all(depth > 0)
            assert np.all((uv >= 20) & (uv <= [1259, 699])), (i, k)


def test_own_side_markers_mostly_in_view(site, schedule):
    in_view = []
    for i in range(4):
        for k in range(10):
            uv, depth = project(
                PAPER_K, invert(schedule.world_from_cam(i, k)), site.landmarks("aruco").xyz
            )
            ok = (depth > 0) & np.all((uv >= 0) & (uv <= [1279, 719]), axis=1)
            in_view.append(ok.reshape(-1, 4).all(axis=1).sum())
    assert min(in_view) >= 1
    assert np.mean(in_view) >= 3


def test_seeded_and_data(site):
    a, b = make_schedule(site, 4), make_schedule(site, 4)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.attitudes, b.attitudes)
    c = make_schedule(site, 4, ScheduleSpec(seed=1))
    assert not np.array_equal(a.positions, c.positions)
    d = a.as_dict()
    assert len(d["positions_m"]) == 4 and d["sides"][0] == "south"


def test_other_agent_counts(site):
    s = make_schedule(site, 3, ScheduleSpec(n_viewpoints=4))
    assert s.positions.shape == (3, 4, 3) and s.sides == ("side 0", "side 1", "side 2")


def test_impossible_spec_raises(site):
    with pytest.raises(ConfigError, match="no viewpoint for agent 0"):
        sample_viewpoint(
            site,
            0,
            4,
            np.random.default_rng(0),
            ScheduleSpec(distance=(1, 2), height=(3, 4), max_tries=5),
        )
    with pytest.raises(ConfigError, match="distance"):
        ScheduleSpec(distance=(30, 10))
