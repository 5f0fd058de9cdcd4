"""Smoke test: SB3 PPO trains through SuperSuit's vector-env conversion (docs/design.md)."""

import numpy as np
import pytest

sb3 = pytest.importorskip("stable_baselines3")
ss = pytest.importorskip("supersuit")

from stable_baselines3.common.logger import configure  # noqa: E402

import uav_struct_env  # noqa: E402

SMALL_RL = {"image_size": (64, 36), "render_mode": "rgb_array", "max_cycles": 32}


def make_vec_env(num_vec_envs=1, num_cpus=0):
    # the train preset ends the episode for everyone on a crash (on_crash="all"), which
    # SuperSuit's conversion needs (its black_death_v3 does not support Dict observations)
    env = uav_struct_env.parallel_env("train", **SMALL_RL)
    vec = ss.pettingzoo_env_to_vec_env_v1(env)
    return ss.concat_vec_envs_v1(
        vec, num_vec_envs, num_cpus=num_cpus, base_class="stable_baselines3"
    )


@pytest.mark.filterwarnings("ignore:The `render_mode` attribute is not defined")
@pytest.mark.slow  # SB3's own run (7 s); the trainer's image policy runs by default (test_examples: pixels)
def test_ppo_multi_input_policy_trains_a_few_hundred_steps(tmp_path):
    vec = make_vec_env()
    assert vec.num_envs == 4  # one per UAV
    # no PPO(seed=...): SB3 would call vec.seed(), which SuperSuit 3.11's ConcatVecEnv lacks
    model = sb3.PPO("MultiInputPolicy", vec, n_steps=64, batch_size=64, n_epochs=1, device="cpu")
    # an explicit logger: SB3's default one makes an empty SB3-<date> directory in /tmp per run
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(total_timesteps=256)
    header, *rows = (tmp_path / "progress.csv").read_text().splitlines()
    assert len(rows) == 256 // (64 * vec.num_envs)  # one row per rollout of 64 steps x 4 envs
    assert rows[-1].split(",")[header.split(",").index("time/total_timesteps")] == "256"
    obs = vec.reset()
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (4, 5) and np.all(np.abs(action) <= 1)
    vec.close()


@pytest.mark.filterwarnings("ignore:The `render_mode` attribute is not defined")
@pytest.mark.slow  # two SuperSuit worker processes, each importing the stack
def test_vector_envs_in_subprocesses():
    vec = make_vec_env(num_vec_envs=2, num_cpus=2)
    assert vec.num_envs == 8
    obs = vec.reset()
    assert obs["image"].shape == (8, 36, 64, 3)
    for _ in range(3):
        obs, rew, done, info = vec.step(np.zeros((8, 5), np.float32))
    assert np.all(rew == 0)
    vec.close()
