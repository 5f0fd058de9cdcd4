"""LocalizationWrapper(temporal=True) on real env runs, the degraded GNSS in the env, the study."""

import json
import math

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

import uav_struct_env
from localization.temporal import FilterNoise
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.sensors import DegradedGnssNoise
from uav_struct_env.study import temporal as study
from uav_struct_env.wrappers import LocalizationWrapper

FILTER_KEYS = ("filtered_translation_error_m", "filtered_rotation_error_deg", "filtered_position_std_m",
               "fix_accepted", "fix_nis", "gnss_fix")


def wrapped(noise="gnss_ins", steps=12, **kwargs):
    env = uav_struct_env.parallel_env(
        "paper", noise=noise, observe_image=False, max_cycles=steps, landmark_sets=("all",)
    )
    return LocalizationWrapper(
        env, landmarks="all", temporal=True, miss_rate=0.1, false_positives=1.0, **kwargs
    )


def orbit_actions(w, k):
    """The study's scripted pilot: orbit 9..30 m around the site at 8 m, looking at it."""
    base = w.unwrapped
    center = np.array([*base.site.center[:2], 0.5 * base.site.center[2]])
    cfg = base.config
    return {
        a: study.pilot_action(
            base.uav_state(a),
            study.target_position((k + 1) * cfg.control_period, base.possible_agents.index(a), center, 9.0,
                                  30.0, 8.0),
            center, cfg.limits, cfg.control_period,
        )
        for a in w.agents
    }


def run(w, seed, steps):
    obs, infos = w.reset(seed=seed)
    out = [(obs, infos)]
    for k in range(steps):
        obs, _, _, _, infos = w.step(orbit_actions(w, k))
        out.append((obs, infos))
    return out


def test_filtered_pose_is_finite_at_every_step_and_beats_the_prior():
    w = wrapped()
    space = w.observation_space("uav_0")
    errors, priors, failed_steps = [], [], 0
    for obs, infos in run(w, seed=2, steps=12):
        for a in obs:
            assert space.contains(obs[a]), a
            assert np.all(np.isfinite(obs[a]["pose"])) and np.all(obs[a]["pose_std"] > 0)
            loc = infos[a]["localization"]
            for key in FILTER_KEYS:
                assert isinstance(loc[key], (bool, int, float)) and math.isfinite(loc[key]), key
            truth = infos[a]["world_from_cam"][:3, 3]
            assert np.linalg.norm(obs[a]["pose"][:3] - truth) == pytest.approx(
                loc["filtered_translation_error_m"], abs=1e-3)
            errors.append(loc["filtered_translation_error_m"])
            priors.append(np.linalg.norm(infos[a]["prior_world_from_cam"][:3, 3] - truth))
            failed_steps += not loc["success"]
            assert obs[a]["localized"][0] == float(loc["fix_accepted"])
    assert failed_steps > 0  # frames without a fix happened, and the pose was still given
    assert np.median(errors) < 0.2 * np.median(priors)
    assert np.max(errors) < 2.0


def test_seeds_reproduce():
    a = run(wrapped(), seed=4, steps=5)
    b = run(wrapped(), seed=4, steps=5)
    for (oa, ia), (ob, ib) in zip(a, b, strict=True):
        for agent in oa:
            np.testing.assert_array_equal(oa[agent]["pose"], ob[agent]["pose"])
            np.testing.assert_array_equal(oa[agent]["pose_std"], ob[agent]["pose_std"])
            assert ia[agent]["localization"] == ib[agent]["localization"]


def test_gnss_outage_holds_the_last_fix_and_the_filter_keeps_a_pose():
    """Always in an outage after reset: the env repeats the reset fix, the filter flies on."""
    w = wrapped(noise=DegradedGnssNoise(outage_clearance=1e4), steps=6)
    steps = run(w, seed=1, steps=6)
    first = {a: steps[0][0][a]["gnss"].copy() for a in steps[0][0]}
    assert all(steps[0][1][a]["gnss_fix"] for a in first)
    for obs, infos in steps[1:]:
        for a in obs:
            assert not infos[a]["gnss_fix"] and not infos[a]["localization"]["gnss_fix"]
            np.testing.assert_array_equal(obs[a]["gnss"], first[a])
            np.testing.assert_allclose(infos[a]["prior_world_from_cam"][:3, 3], first[a].astype(np.float64))
            assert np.all(np.isfinite(obs[a]["pose"]))
    moved = [np.linalg.norm(steps[-1][1][a]["world_from_cam"][:3, 3] - first[a]) for a in first]
    filtered = [steps[-1][1][a]["localization"]["filtered_translation_error_m"] for a in first]
    assert max(moved) > 5.0  # the stale GNSS is metres off by now; the filter is not
    assert np.median(filtered) < 0.5


def test_gnss_outage_at_reset_is_a_clear_error():
    class NoFixEver(DegradedGnssNoise):
        def measure(self, state, rng, reading):
            return np.full(3, np.nan), np.asarray(reading.attitude, dtype=np.float64)

    env = uav_struct_env.parallel_env("paper", noise=NoFixEver(), observe_image=False)
    with pytest.raises(ConfigError, match="no GNSS fix .* at reset"):
        env.reset(seed=0)


def test_options_and_errors():
    w = wrapped(filter_noise=FilterNoise(velocity_sigma=1.0))
    assert w.tracks.noise.velocity_sigma == 1.0
    with pytest.raises(ConfigError, match="filter_noise must be"):
        wrapped(filter_noise={"velocity_sigma": 1.0})
    plain = LocalizationWrapper(
        uav_struct_env.parallel_env("paper", observe_image=False, landmark_sets=("all",)), landmarks="all"
    )
    _, infos = plain.reset(seed=0)
    assert plain.tracks is None and "fix_accepted" not in infos["uav_0"]["localization"]


def test_parallel_api_conformance():
    parallel_api_test(wrapped(steps=4), num_cycles=4)


def test_study_writes_results_and_figure(tmp_path):
    args = ["--seeds", "1", "--steps", "6", "--noise", "gnss_degraded", "--no-progress"]
    assert study.main(["--out", str(tmp_path / "t"), *args]) == 0
    res = json.loads((tmp_path / "t" / "results.json").read_text())
    r = res["noise"]["gnss_degraded"]
    assert r["steps"] == 4 * 7
    assert r["filtered"]["pose_share"] == 1.0 and r["prior"]["pose_share"] == 1.0
    assert 0.0 <= r["single_frame"]["pose_share"] <= 1.0
    assert set(r) >= {*study.METHODS, "gnss_fix_share"}
    assert (tmp_path / "t" / "temporal.png").stat().st_size > 10_000


def test_recovery_counts_gaps_and_steps():
    t = [0.1, 0.1, 0.8, 0.9, 0.6, 0.3, 0.1, 0.1]
    acc = [True, True, False, False, True, True, True, True]
    assert study.recovery(t, acc) == [(2, 0.9, 2)]
    assert study.recovery(t, [True] * 8) == []
    assert study.recovery([0.1, 0.9, 0.9], [True, False, True]) == [(1, 0.9, None)]
