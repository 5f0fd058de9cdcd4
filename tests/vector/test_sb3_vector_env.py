"""SB3 PPO trains on the vector env directly; done slots carry what SB3 reads at an episode's end."""

from __future__ import annotations

import numpy as np
import pytest

sb3 = pytest.importorskip("stable_baselines3")

from stable_baselines3.common.logger import configure  # noqa: E402

from uav_struct_env.vector import SB3VecEnv, make_vector_env  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore:The `render_mode` attribute is not defined")


def test_ppo_trains_on_the_vector_env(tmp_path):
    env = SB3VecEnv(make_vector_env("state", 2, max_cycles=8))
    assert env.num_envs == 8  # 2 envs x 4 UAVs
    model = sb3.PPO("MultiInputPolicy", env, n_steps=16, batch_size=64, n_epochs=1, seed=3, device="cpu")
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(total_timesteps=256)
    header, *rows = (tmp_path / "progress.csv").read_text().splitlines()
    assert len(rows) == 256 // (16 * 8)
    assert rows[-1].split(",")[header.split(",").index("time/total_timesteps")] == "256"
    action, _ = model.predict(env.reset(), deterministic=True)
    assert action.shape == (8, 5) and np.all(np.abs(action) <= 1)
    env.close()


def test_done_slots_carry_the_terminal_observation_and_the_time_limit():
    env = SB3VecEnv(make_vector_env("state", 2, max_cycles=3))
    assert env.seed(5) == [5, 5, 5, 5, 6, 6, 6, 6]
    first = env.reset()
    for _ in range(3):
        obs, rewards, dones, infos = env.step(np.zeros((8, 5), np.float32))
    assert dones.all() and rewards.dtype == np.float32
    for slot, info in enumerate(infos):
        assert info["TimeLimit.truncated"] is True  # hovering: the 3-step limit, no crash
        assert info["terminal_observation"]["gnss"].shape == (3,)
        assert "localization" in info and "final_observation" not in info
        # the step's observation is the next episode's first: a new start, not the terminal one
        assert not np.array_equal(obs["gnss"][slot], info["terminal_observation"]["gnss"])
    assert not np.array_equal(first["gnss"], obs["gnss"])
    # slot 5 is uav_1 of the second copy: SB3's attribute calls reach that copy
    assert env.get_attr("unwrapped", [5])[0] is env.vec.envs[1].unwrapped
    assert env.env_method("observation_space", "uav_0", indices=[0, 7]) == [env.observation_space] * 2
    env.set_attr("marker", 3, indices=[4])
    assert getattr(env.vec.envs[1], "marker", None) == 3 and getattr(env.vec.envs[0], "marker", None) is None
    assert env.env_is_wrapped(object) == [False] * 8
    env.close()
