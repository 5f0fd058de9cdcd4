"""Study --track-workers: worker_tracking in results.json with true, estimated and prior poses."""

import json

import pytest

from uav_struct_env.errors import ConfigError
from uav_struct_env.study import StudyConfig
from uav_struct_env.study.study import run_study
from uav_struct_env.study.tracking import TRACKING_ACTIVITY


def _tracked(folder):
    out = folder / "study"
    config = StudyConfig(track_workers=True, n_viewpoints=2, methods=("slab_corners", "all"),
                         image_size=(640, 360))
    return run_study(config, out, progress=False, figures=True), out


@pytest.fixture(scope="module")
def tracked(shared_output):
    """The study with worker tracking, run once a session however many xdist workers read it."""
    return shared_output("tracked-study", _tracked)[1]


def test_worker_tracking_entry_with_the_three_pose_sources(tracked):
    results, out = tracked
    t = json.loads((out / "results.json").read_text())["worker_tracking"]
    assert t == results["worker_tracking"]
    assert set(t) >= {"truth", "estimated", "prior", "estimated_by_method", "workers_present"}
    for source in ("truth", "estimated", "prior"):
        assert set(t[source]) == {"median_m", "p95_m", "n_observations"}
    assert t["estimated_methods"] == {"columns": "all", "slab": "slab_corners"}
    assert set(t["estimated_by_method"]) == {"slab_corners", "all"}
    # light activity: 6 workers at each of 2 viewpoints of 2 scenes; most seen by >= 2 cameras
    assert t["workers_present"] == 24 and t["activity"] == TRACKING_ACTIVITY and t["upright"] is False
    assert 12 <= t["truth"]["n_observations"] <= 24
    # 2 px keypoint noise at 640 px (4 px at the paper's 1280): decimetres with true poses
    assert 0.0 < t["truth"]["median_m"] < 0.3 and t["truth"]["median_m"] <= t["truth"]["p95_m"]
    # estimated poses (decimetre camera errors) cost little; the 3 m / 5 deg prior costs metres
    assert t["estimated"]["median_m"] < 2 * t["truth"]["median_m"] + 0.05
    assert t["prior"]["median_m"] > 1.0
    assert (out / "worker_tracking_cdf.png").stat().st_size > 10_000
    table = (out / "worker_tracking.md").read_text()
    assert "| Ground truth (floor) |" in table and "site activity light" in table
    assert "worker tracking (2.0 px keypoint noise)" in table


def test_track_workers_must_be_a_bool():
    with pytest.raises(ConfigError, match="track_workers must be True or False, got 'yes'"):
        StudyConfig(track_workers="yes")
    with pytest.raises(ConfigError, match="upright_workers must be True or False, got 1"):
        StudyConfig(upright_workers=1)
    with pytest.raises(ConfigError, match="worker_pixel_sigma must be finite and > 0, got 0"):
        StudyConfig(worker_pixel_sigma=0)
    # workers need site activity: light unless another was chosen
    assert StudyConfig().activity == "none"
    assert StudyConfig(track_workers=True).activity == TRACKING_ACTIVITY == "light"
    assert StudyConfig(track_workers=True, activity="busy").activity == "busy"
