"""The scripted baselines, the greedy Cramér-Rao one above all, on the real wrapped state env."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from localization.geometry.transforms import invert
from localization.metrics import cramer_rao_bound
from uav_struct_env.baselines import BASELINES, GreedyCrbPolicy, make_baseline
from uav_struct_env.sim.uav import UavState


@pytest.fixture(scope="module")
def env():
    from uav_struct_env.wrappers import make_train_env

    warnings.filterwarnings("ignore", "The `render_mode` attribute is not defined")
    e = make_train_env("state")
    yield e
    e.close()


def true_bound(env, info) -> float:
    """Position bound at the true pose from the landmarks the env reports visible."""
    sets = info["landmarks"]["column_tops"]
    pts = np.asarray(sets["xyz"])[np.asarray(sets["visible"], bool)]
    if len(pts) < 4:
        return math.inf
    return cramer_rao_bound(pts, invert(info["world_from_cam"]), env.poses.K, 1.0).position_rms_m


def test_predicted_bound_matches_the_bound_of_the_in_frame_landmarks(env):
    obs, infos = env.reset(seed=3)
    greedy = GreedyCrbPolicy(env)
    state = env.unwrapped.uav_state("uav_0")
    # An unoccluded view of the column tops: every in-frame landmark is visible.
    expected = cramer_rao_bound(
        np.asarray(infos["uav_0"]["landmarks"]["column_tops"]["xyz"])[
            np.asarray(infos["uav_0"]["landmarks"]["column_tops"]["in_frame"], bool)],
        invert(state.world_from_cam), greedy.K, greedy.pixel_sigma).position_rms_m
    assert greedy.predicted_bound(state) == pytest.approx(expected, rel=1e-9)
    away = UavState.make(state.xyz, state.yaw + math.pi, state.pitch)
    assert greedy.predicted_bound(away) == math.inf


def test_greedy_lowers_the_true_bound_and_stays_clear(env):
    greedy = make_baseline("greedy", env)
    obs, infos = env.reset(seed=10_000)
    start = {a: true_bound(env, infos[a]) for a in obs}
    for _ in range(8):
        actions = greedy({a: obs[a] for a in env.agents}, env)
        assert all(a.dtype == np.float32 and np.all(np.abs(a) <= 1) for a in actions.values())
        obs, _, term, trunc, infos = env.step(actions)
        assert not any(term.values()), {a: infos[a]["termination_reason"] for a in term}
    end = {a: true_bound(env, infos[a]) for a in obs}
    for a in obs:
        assert end[a] < 0.7 * start[a], (a, start[a], end[a])
        d = float(env.unwrapped.obstacles.distances(env.unwrapped.uav_state(a).xyz[None])[0])
        assert d > 5.0, (a, d)


def test_every_baseline_acts_and_bad_names_are_refused(env):
    obs, _ = env.reset(seed=1)
    for name in BASELINES:
        actions = make_baseline(name, env, seed=0)(obs, env)
        assert set(actions) == set(obs) and all(a.shape == (5,) for a in actions.values())
    with pytest.raises(ValueError, match=r"baseline must be one of .*got 'greedi'"):
        make_baseline("greedi", env)
    wrapped_only = "needs an env wrapped by LocalizationWrapper, got UavStructParallelEnv"
    with pytest.raises(TypeError, match=wrapped_only):
        GreedyCrbPolicy(env.unwrapped)


def test_without_a_pose_in_the_observation_the_baselines_act_on_the_wrappers_pose():
    from uav_struct_env.wrappers import make_train_env

    pixels, image = make_train_env("pixels", max_cycles=4), make_train_env("image", max_cycles=4)
    try:
        obs_p, _ = pixels.reset(seed=5)
        obs_i, _ = image.reset(seed=5)
        for name in ("orbit", "greedy"):  # the same actions as where the pose is observed
            act_p = make_baseline(name, pixels)(obs_p, pixels)
            act_i = make_baseline(name, image)(obs_i, image)
            for agent in pixels.agents:
                assert "pose" not in obs_p[agent]
                np.testing.assert_allclose(act_p[agent], act_i[agent], atol=1e-6, err_msg=f"{name} {agent}")
    finally:
        pixels.close()
        image.close()
