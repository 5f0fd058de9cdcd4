"""What the RL libraries read besides reset/step: space dicts on env and wrappers, state()."""

import numpy as np
import pytest

import uav_struct_env
from uav_struct_env.errors import ResetNeededError
from uav_struct_env.wrappers import iter_chain, make_train_env


def test_space_dicts_match_the_per_agent_spaces_on_the_env_and_every_wrapper():
    wrapped = make_train_env("state")
    try:
        seen = 0
        for layer in iter_chain(wrapped):
            for a in layer.possible_agents:
                assert layer.observation_spaces[a] == layer.observation_space(a)
                assert layer.action_spaces[a] == layer.action_space(a)
            seen += 1
        # The wrapper's dict has the keys it adds (pose ...), not the bare env's.
        assert "pose" in wrapped.observation_spaces["uav_0"].spaces
        assert "pose" not in wrapped.unwrapped.observation_spaces["uav_0"].spaces
        assert seen >= 3
    finally:
        wrapped.close()


def test_state_stacks_the_true_camera_poses_and_who_is_alive():
    env = uav_struct_env.parallel_env("train", renderer="tiny", observe_image=False)
    try:
        with pytest.raises(ResetNeededError, match="state\\(\\) before reset"):
            env.state()
        env.reset(seed=0)
        s = env.state()
        assert s.shape == env.state_space.shape == (32,) and s.dtype == np.float32
        assert env.state_space.contains(s)
        per = s.reshape(4, 8)
        for i, a in enumerate(env.possible_agents):
            T = env.uav_state(a).world_from_cam
            np.testing.assert_allclose(per[i, :3], T[:3, 3], atol=1e-4)
            assert np.linalg.norm(per[i, 3:7]) == pytest.approx(1.0, abs=1e-6)
        np.testing.assert_array_equal(per[:, 7], 1.0)
        # A UAV flown into the ground is no longer alive in the state.
        down = np.array([0, 0, -1, 0, 0], dtype=np.float32)
        for _ in range(200):
            _, _, term, _, _ = env.step({a: down if a == "uav_0" else np.zeros(5, np.float32)
                                         for a in env.agents})
            if term.get("uav_0"):
                break
        assert env.state().reshape(4, 8)[0, 7] == 0.0
    finally:
        env.close()


def _numbers_only(value) -> bool:
    if isinstance(value, dict):
        return all(_numbers_only(v) for v in value.values())
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "biuf" and bool(np.all(np.isfinite(value)))
    return isinstance(value, (bool, int, float, np.number)) and bool(np.isfinite(value))


def test_the_wrapper_info_is_finite_numbers_and_deterministic_for_a_seed():
    """What tensor libraries read, and PettingZoo's own seed test on the wrapped env."""
    from pettingzoo.test import parallel_seed_test

    from localization import FailureCode
    from uav_struct_env.wrappers.localize import UNDEFINED, failure_code_number

    env = make_train_env("state", max_cycles=8)
    try:
        _, infos = env.reset(seed=3)
        codes = set()
        for _ in range(8):
            for a, info in infos.items():
                loc = info["localization"]
                assert _numbers_only(loc), loc
                if not loc["success"]:
                    assert loc["translation_error_m"] == UNDEFINED and loc["failure_code"] > 0
                    code = env.last_frames[a].estimate.failure_code or FailureCode.UNKNOWN
                    assert loc["failure_code"] == failure_code_number(code)
                codes.add(loc["failure_code"])
            if not env.agents:
                break
            _, _, _, _, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
        assert 0 in codes
    finally:
        env.close()
    parallel_seed_test(lambda: make_train_env("state", max_cycles=6), num_cycles=6)


def test_flatten_observation_gives_one_vector_with_named_slices():
    from uav_struct_env.wrappers import FlattenObservation

    env = FlattenObservation(make_train_env("state"))
    twin = make_train_env("state")  # the same seed, unflattened
    try:
        space = env.observation_space("uav_0")
        assert space.dtype == np.float32 and space.shape == (3 + 3 + 10 + 1 + 7 + 6,)
        assert env.observation_spaces["uav_0"] is space
        assert sorted(env.layout) == sorted(twin.observation_space("uav_0").spaces)
        flat, _ = env.reset(seed=0)
        ref, _ = twin.reset(seed=0)
        for _ in range(2):
            for a, o in flat.items():
                assert space.contains(o)
                for key, where in env.layout.items():
                    np.testing.assert_array_equal(o[where], np.ravel(ref[a][key]))
            acts = {a: env.action_space(a).sample() for a in env.agents}
            flat, *_ = env.step(acts)
            ref, *_ = twin.step(acts)
    finally:
        env.close()
        twin.close()
