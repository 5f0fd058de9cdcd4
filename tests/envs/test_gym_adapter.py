import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import uav_struct_env
from uav_struct_env.envs.gym_adapter import SingleUavEnv

SMALL = dict(image_size=(64, 36), renderer="tiny", max_cycles=5)


@pytest.fixture
def single():
    env = SingleUavEnv(uav_struct_env.parallel_env(**SMALL), agent="uav_1")
    yield env
    env.close()


def test_gymnasium_check_env_passes(single):
    check_env(single, skip_render_check=True)


def test_registered_id_builds_the_env_with_keyword_config():
    env = gym.make("uav_struct_env/UavStruct-v0", n_agents=1, **SMALL)
    obs, info = env.reset(seed=0)
    assert obs["image"].shape == (36, 64, 3)
    assert info["world_from_cam"].shape == (4, 4)
    env.close()


def test_controls_one_agent_while_the_others_hold(single):
    single.reset(seed=3)
    par = single.parallel
    before = {a: par.uav_state(a).xyz.copy() for a in par.possible_agents}
    obs, reward, terminated, truncated, info = single.step(np.array([1, 0, 0, 0, 0], np.float32))
    assert reward == 0.0 and not terminated and not truncated
    moved = {a: float(np.linalg.norm(par.uav_state(a).xyz - before[a])) for a in before}
    assert moved["uav_1"] > 1.0
    assert all(moved[a] < 1e-9 for a in before if a != "uav_1")


def test_same_seed_same_episode(single):
    a, _ = single.reset(seed=11)
    b, _ = single.reset(seed=11)
    np.testing.assert_array_equal(a["gnss"], b["gnss"])
    np.testing.assert_array_equal(a["image"], b["image"])


def test_unknown_agent_is_rejected():
    with pytest.raises(ValueError, match=r"agent must be one of \['uav_0'.*got 'uav_9'"):
        SingleUavEnv(uav_struct_env.parallel_env(**SMALL), agent="uav_9")
