"""Ray RLlib on the env: a crash ends the episode for RLlib too, and examples/train_rllib.py trains.

RLlib's PettingZoo wrappers set ``__all__`` only when every agent is terminated or every agent is
truncated; with ``on_crash="all"`` the env therefore terminates the whole team on a crash (one
terminated and three truncated agents kept RLlib stepping the finished env with ``{}``).
"""

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ray.rllib", reason="Ray RLlib is not installed (pip install 'uav-struct-env[ray]')")

from pettingzoo.utils import BaseParallelWrapper  # noqa: E402
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv, PettingZooEnv  # noqa: E402

import uav_struct_env  # noqa: E402
from uav_struct_env.wrappers import FlattenObservation, make_train_env  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
DOWN = np.array([0, 0, -1, 0, 0], np.float32)


class Dive(BaseParallelWrapper):
    """uav_0 flies down into the ground whatever it is told; counts steps of a finished env."""

    def __init__(self, env):
        super().__init__(env)
        self.steps_after_end = 0

    def step(self, actions):
        if not self.env.agents:
            self.steps_after_end += 1
        actions = {a: (DOWN if a == "uav_0" else act) for a, act in actions.items()}
        return self.env.step(actions)


def _until_crash(step, first_obs, n=200):
    obs = first_obs
    for _ in range(n):
        obs, _, term, trunc, infos = step(obs)
        if any(v for k, v in term.items() if k != "__all__"):
            return term, trunc, infos
    raise AssertionError("uav_0 never crashed")


def test_rllibs_parallel_wrapper_ends_the_episode_on_a_crash():
    env = ParallelPettingZooEnv(uav_struct_env.parallel_env("train", renderer="tiny", observe_image=False))
    obs, _ = env.reset(seed=0)
    zero = np.zeros(5, np.float32)
    term, trunc, infos = _until_crash(
        lambda o: env.step({a: DOWN if a == "uav_0" else zero for a in o}), obs
    )
    assert term == {"uav_0": True, "uav_1": True, "uav_2": True, "uav_3": True, "__all__": True}
    assert trunc["__all__"] is False
    assert infos["uav_0"]["termination_reason"] == "below_min_altitude"
    assert {infos[a]["termination_reason"] for a in ("uav_1", "uav_2", "uav_3")} == {"teammate_crash"}
    env.close()


def test_rllibs_aec_wrapper_ends_the_episode_on_a_crash():
    env = PettingZooEnv(uav_struct_env.env("train", renderer="tiny", observe_image=False))
    obs, _ = env.reset(seed=0)
    seen = {}
    for _ in range(200):  # the AEC wrapper steps one agent at a time
        agent = next(iter(obs))
        obs, _, term, trunc, _ = env.step({agent: DOWN if agent == "uav_0" else np.zeros(5, np.float32)})
        seen.update({a: v for a, v in term.items() if a != "__all__"})
        if term["__all__"] or trunc["__all__"]:
            break
    assert term["__all__"] is True and trunc["__all__"] is False
    assert seen == dict.fromkeys(("uav_0", "uav_1", "uav_2", "uav_3"), True)
    env.close()


def test_rllibs_env_runner_never_steps_a_finished_env():
    """The real sampler: every episode ends at the crash step, no empty step follows."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.env.multi_agent_env_runner import MultiAgentEnvRunner

    dives = []

    def creator(_):
        dives.append(Dive(make_train_env("state")))
        return ParallelPettingZooEnv(FlattenObservation(dives[-1]))

    config = (
        PPOConfig()
        .environment(creator)
        .multi_agent(policies={"shared"}, policy_mapping_fn=lambda aid, *a, **k: "shared")
        .env_runners(num_env_runners=0)
    )
    runner = MultiAgentEnvRunner(config=config)
    episodes = runner.sample(num_episodes=3, random_actions=True)
    runner.stop()
    assert len(episodes) == 3
    for ep in episodes:
        assert ep.is_terminated and not ep.is_truncated
        # all four agents end on the same (crash) step, well before max_cycles=30
        assert {len(sa) for sa in ep.agent_episodes.values()} == {len(ep)} and len(ep) < 30
        assert all(sa.is_terminated and not sa.is_truncated for sa in ep.agent_episodes.values())
    assert sum(d.steps_after_end for d in dives) == 0


@pytest.fixture
def train_rllib(load_script):
    """``examples/train_rllib.py`` as a fresh module."""
    return load_script(EXAMPLES / "train_rllib.py")


def test_train_rllib_refuses_bad_options_before_starting_ray(train_rllib, tmp_path):
    from uav_struct_env.errors import ConfigError, UsageError

    with pytest.raises(UsageError, match="num_env_runners must be an int >= 0, got -1"):
        train_rllib.main(out=str(tmp_path / "a"), num_env_runners=-1)
    with pytest.raises(ConfigError, match=r"minibatch_size \(512\) must not exceed train_batch_size \(256\)"):
        train_rllib.main(out=str(tmp_path / "b"), train_batch_size=256, minibatch_size=512)
    with pytest.raises(ValueError, match=r"unknown options \['n_envs'\]"):
        train_rllib.main(out=str(tmp_path / "c"), n_envs=2)
    with pytest.raises(ConfigError, match=r"config 'pixels_critic' is an asymmetric actor-critic .* "
                                          r"train it with examples/train_viewpoint_ppo.py"):
        train_rllib.main(out=str(tmp_path / "d"), config="pixels_critic")
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
def test_train_rllib_trains_on_a_local_ray_with_two_env_runners(train_rllib, tmp_path):
    import ray
    from ray.rllib.algorithms.algorithm import Algorithm

    out = tmp_path / "rllib"
    summary = train_rllib.main(out=str(out), num_env_runners=2, total_timesteps=1024, train_batch_size=512,
                         minibatch_size=128, num_epochs=2, max_cycles=8, checkpoint_every=1,
                         progress_bar=False, seed=5)
    assert not ray.is_initialized()  # the local instance it started is shut down
    assert summary["agent_steps"] >= 1024 and summary["iterations"] == 2
    rows = [json.loads(line) for line in (out / "progress.jsonl").read_text().splitlines()]
    assert [r["agent_steps"] for r in rows] == [512, 1024]  # 4 agents through one shared module
    assert all(np.isfinite(r["episode_return_mean"]) for r in rows)
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["iter_000001", "iter_000002"]
    assert json.loads((out / "train_rllib.json").read_text())["options"]["num_env_runners"] == 2
    # The checkpoint restores one module, shared by every agent, that acts on a real observation.
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        from ray.tune.registry import register_env

        register_env(train_rllib.ENV_NAME, train_rllib.make_env)
        algo = Algorithm.from_checkpoint(summary["checkpoint"])
        module = algo.get_module(train_rllib.SHARED)
        assert set(algo.config.policies) == {train_rllib.SHARED}
        env = train_rllib.make_env({"config": "state", "max_cycles": 8})
        obs, _ = env.reset(seed=1)
        import torch

        batch = torch.as_tensor(np.stack([obs[a] for a in sorted(obs)]))
        out_ = module.forward_inference({"obs": batch})
        assert out_["action_dist_inputs"].shape == (4, 10)  # mean and log std of 5 actions
        algo.stop()
    finally:
        ray.shutdown()
