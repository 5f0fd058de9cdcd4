"""skrl on the env: MAPPO with one shared policy and a centralized critic on ``state()`` trains.

The recipe of docs/training.md ("skrl"), run for real: skrl's PettingZoo wrapper, its MAPPO agent,
memory and sequential trainer, for a few short rollouts.
"""

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("skrl", reason="skrl is not installed (pip install 'uav-struct-env[rl-extra]')")

from skrl.envs.wrappers.torch import wrap_env  # noqa: E402
from skrl.memories.torch import RandomMemory  # noqa: E402
from skrl.models.torch import DeterministicMixin, GaussianMixin, Model  # noqa: E402
from skrl.multi_agents.torch.mappo import MAPPO  # noqa: E402
from skrl.trainers.torch import SequentialTrainer  # noqa: E402

from uav_struct_env.wrappers import make_train_env  # noqa: E402

#: MAPPO_CFG fields whose default ({}) skrl 2.1.1's MultiAgentCfg.expand rejects: give one per agent.
SKRL_PER_AGENT_KWARGS = ("learning_rate_scheduler_kwargs", "observation_preprocessor_kwargs",
                         "state_preprocessor_kwargs", "value_preprocessor_kwargs")


class Policy(GaussianMixin, Model):
    def __init__(self, observation_space, action_space, device):
        Model.__init__(self, observation_space=observation_space, action_space=action_space, device=device)
        GaussianMixin.__init__(self, clip_actions=True)
        self.net = torch.nn.Sequential(torch.nn.Linear(self.num_observations, 64), torch.nn.Tanh(),
                                       torch.nn.Linear(64, self.num_actions))
        self.log_std = torch.nn.Parameter(torch.full((self.num_actions,), -1.0))

    def compute(self, inputs, role=""):
        return self.net(inputs["observations"]), {"log_std": self.log_std}


class Value(DeterministicMixin, Model):
    """The centralized critic: it reads the env's state() (the four true poses and who flies)."""

    def __init__(self, state_space, device):
        Model.__init__(self, state_space=state_space, device=device)
        DeterministicMixin.__init__(self)
        self.net = torch.nn.Sequential(torch.nn.Linear(self.num_states, 64), torch.nn.Tanh(),
                                       torch.nn.Linear(64, 1))

    def compute(self, inputs, role=""):
        return self.net(inputs["states"]), {}


def test_skrl_mappo_trains_one_shared_policy_with_a_state_critic(tmp_path):
    torch.manual_seed(0)
    env = wrap_env(make_train_env("state", max_cycles=8), wrapper="pettingzoo")
    agents = env.possible_agents
    obs_space, act_space = env.observation_space(agents[0]), env.action_space(agents[0])
    policy = Policy(obs_space, act_space, env.device)  # one instance: parameters shared by all four
    value = Value(env.state_space(agents[0]), env.device)
    memories = {a: RandomMemory(memory_size=16, num_envs=env.num_envs, device=env.device) for a in agents}
    mappo = MAPPO(
        possible_agents=agents,
        models={a: {"policy": policy, "value": value} for a in agents},
        memories=memories,
        observation_spaces=env.observation_spaces,
        state_spaces=env.state_spaces,
        action_spaces=env.action_spaces,
        device=env.device,
        cfg={"rollouts": 16, "learning_epochs": 2, "mini_batches": 2, "discount_factor": 0.95,
             # bootstrap V(final observation) where an episode ends at its time limit (skrl's
             # default, False, runs the advantage on into the next episode's first value)
             "time_limit_bootstrap": True,
             # skrl writes TensorBoard logs and checkpoints to ./runs unless told otherwise
             "experiment": {"directory": str(tmp_path), "write_interval": 0, "checkpoint_interval": 0},
             # skrl 2.1.1 refuses its own empty-dict defaults as "keys do not match possible agents"
             **{k: {a: {} for a in agents} for k in SKRL_PER_AGENT_KWARGS}},
    )
    before = [p.detach().clone() for p in policy.parameters()]
    # the test closes the env itself (skrl's at-exit close logs to pytest's closed streams)
    trainer = SequentialTrainer(env=env, agents=mappo, cfg={"timesteps": 48, "headless": True,
                                                             "disable_progressbar": True,
                                                             "close_environment_at_exit": False})
    trainer.train()
    # three PPO updates ran on the one shared policy
    assert any(not torch.equal(a, b) for a, b in zip(before, policy.parameters(), strict=True))
    for a in agents:
        assert mappo.policies[a] is policy and mappo.values[a] is value
        assert mappo.cfg.time_limit_bootstrap[a] is True
        # skrl reads the env's time limit as a truncation, never as a termination: the last
        # rollout (16 steps of 8-step episodes) ends two episodes per agent at steps 8 and 16
        truncated = memories[a].get_tensor_by_name("truncated").reshape(-1).cpu().numpy()
        terminated = memories[a].get_tensor_by_name("terminated").reshape(-1).cpu().numpy()
        assert np.flatnonzero(truncated).tolist() == [7, 15]
        assert not terminated.any()
    # the state the critic reads is the env's state(): 4 x (position, quaternion, alive)
    state = env.state()[agents[0]]
    assert state.shape[-1] == 32
    np.testing.assert_allclose(state.reshape(-1, 8)[:, 7].cpu().numpy(), 1.0)
    env.close()
