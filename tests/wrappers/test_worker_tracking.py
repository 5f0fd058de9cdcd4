"""WorkerTracking: tracking numbers in info (finite, seeded), pose sources, the reward option."""

import numpy as np
import pytest

import uav_struct_env
from uav_struct_env.errors import ConfigError
from uav_struct_env.wrappers import (
    TRACKING_INFO_KEYS,
    LocalizationWrapper,
    TrackingReward,
    WorkerTracking,
)

HOLD = np.zeros(5, np.float32)
ENV = {"image_size": (320, 180), "activity": "busy", "observe_image": False, "max_cycles": 6}


def _env(**kw):
    return uav_struct_env.parallel_env(stage="columns", landmark_sets=("all",), **{**ENV, **kw})


def _rollout(wenv, seed=3, steps=2):
    out = []
    obs, infos = wenv.reset(seed=seed, options={"viewpoint": 2})
    out.append({a: dict(infos[a]["worker_tracking"]) for a in infos})
    for _ in range(steps):
        obs, rew, term, trunc, infos = wenv.step({a: HOLD for a in wenv.agents})
        out.append(
            {a: (dict(infos[a]["worker_tracking"]), rew[a], dict(infos[a]["reward_terms"])) for a in infos}
        )
    return out


def test_info_numbers_from_estimated_poses_and_reward_terms_sum():
    wenv = WorkerTracking(LocalizationWrapper(_env(), landmarks="all"), reward="tracking")
    assert wenv.poses == "estimated"
    history = _rollout(wenv)
    first = history[0]["uav_0"]
    assert tuple(first) == TRACKING_INFO_KEYS
    for step in history[1:]:
        for info, reward, terms in step.values():
            assert all(isinstance(v, (int, float)) and np.isfinite(v) for v in info.values())
            assert reward == pytest.approx(sum(terms.values()), abs=1e-12)
            assert {"tracking_coverage", "tracking_error", "alive"} <= set(terms)
            assert terms["tracking_coverage"] == pytest.approx(info["n_tracked_with_me"] / info["n_workers"])
            if info["n_tracked_with_me"]:
                assert -1.0 <= terms["tracking_error"] < 0.0
    info = history[-1]["uav_0"][0]
    # busy site: 16 workers, four cameras at a paper viewpoint 320 px wide (8 px at 1280)
    assert info["n_workers"] == 16 and info["n_tracked"] >= 10
    assert 0 < info["median_error_m"] < 0.5 and info["median_error_m"] <= info["p95_error_m"]
    assert 0 < info["my_position_std_m"] < 1.0
    result = wenv.last_result
    assert all(len(w.cameras) >= 2 for w in result.tracked)
    # seeded: the same numbers again
    again = WorkerTracking(LocalizationWrapper(_env(), landmarks="all"), reward="tracking")
    assert _rollout(again) == history
    again.close()
    wenv.close()


def test_truth_poses_are_the_floor_and_the_prior_is_far_worse():
    medians = {}
    env = _env()  # one env, the same seeded scene seen through both pose sources
    for poses in ("truth", "prior"):
        wenv = WorkerTracking(env, poses=poses)
        _, infos = wenv.reset(seed=3, options={"viewpoint": 2})
        medians[poses] = infos["uav_0"]["worker_tracking"]["median_error_m"]
    env.close()
    assert 0 < medians["truth"] < 0.2
    # a 3 m / 2-5 deg prior: metres, or nothing consistent at all
    assert medians["prior"] == -1.0 or medians["prior"] > 5 * medians["truth"]


def test_tracking_reward_numbers():
    reward = TrackingReward(coverage_weight=2.0, error_weight=0.5, error_cap=0.4)
    terms = reward.terms(8, np.array([0.1, 0.3, 2.0]))
    assert terms["tracking_coverage"] == pytest.approx(2.0 * 3 / 8)
    assert terms["tracking_error"] == pytest.approx(-0.5 * (0.1 + 0.3 + 0.4) / 3)
    assert reward.terms(0, np.array([])) == {"tracking_coverage": 0.0, "tracking_error": -0.0}


def test_clear_errors():
    with pytest.raises(ConfigError, match="worker_points', 'worker_visibility'|methods .* missing"):
        WorkerTracking(_FakeEnv())
    bare = uav_struct_env.parallel_env(observe_image=False, image_size=(64, 36))
    with pytest.raises(ConfigError, match=r"no site activity \(activity='none'\): build it with"):
        WorkerTracking(bare)
    bare.close()
    env = _env()
    with pytest.raises(ConfigError, match="poses='estimated' needs a LocalizePoses"):
        WorkerTracking(env, poses="estimated")
    with pytest.raises(ConfigError, match="poses must be one of"):
        WorkerTracking(env, poses="gnss")
    with pytest.raises(ConfigError, match="reward must be None, 'tracking' or a TrackingReward, got 'error'"):
        WorkerTracking(env, reward="error")
    with pytest.raises(ConfigError, match=r"height_range\[1\] must be finite and > 2, got 1"):
        WorkerTracking(env, poses="truth", height_range=(2.0, 1.0))
    with pytest.raises(ConfigError, match="miss_rate must be a number in \\[0, 1\\], got 2"):
        WorkerTracking(env, miss_rate=2)
    with pytest.raises(ConfigError, match="error_cap must be finite and > 0, got 0"):
        TrackingReward(error_cap=0)
    env.close()


class _FakeEnv:
    unwrapped = property(lambda self: self)
    possible_agents = ["a"]


def test_parallel_api_and_seed_conformance():
    from pettingzoo.test import parallel_api_test, parallel_seed_test

    def make():
        return WorkerTracking(_env(image_size=(128, 72), activity="light"), reward="tracking")

    env = make()
    parallel_api_test(env, num_cycles=6)
    env.close()
    parallel_seed_test(make, num_cycles=4)
