"""TorchRL on the env: the recipe of docs/training.md ("TorchRL") collects and takes PPO steps.

TorchRL's ``PettingZooWrapper`` stacks every info entry into a fixed-shape tensor, so the env goes
in through :class:`uav_struct_env.wrappers.TensorInfo` (numeric ``localization`` entries only).
"""

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl", reason="TorchRL is not installed (pip install 'uav-struct-env[rl-extra]')")

from tensordict.nn import NormalParamExtractor, TensorDictModule  # noqa: E402
from torchrl.collectors import Collector  # noqa: E402
from torchrl.envs.libs.pettingzoo import PettingZooWrapper  # noqa: E402
from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal  # noqa: E402
from torchrl.objectives import ClipPPOLoss, ValueEstimators  # noqa: E402

from uav_struct_env.errors import ConfigError  # noqa: E402
from uav_struct_env.wrappers import FlattenObservation, TensorInfo, make_train_env  # noqa: E402


def make_env(max_cycles=6):
    return PettingZooWrapper(TensorInfo(FlattenObservation(make_train_env("state", max_cycles=max_cycles))),
                             return_state=True, seed=0)


def test_tensor_info_keeps_the_numbers_of_the_localization_info_and_refuses_the_rest():
    env = TensorInfo(make_train_env("state"))
    twin = make_train_env("state")
    try:
        _, flat = env.reset(seed=4)
        _, raw = twin.reset(seed=4)
        for a in env.possible_agents:
            assert set(flat[a]) == {f"localization.{k}" for k in raw[a]["localization"]}
            for k, v in raw[a]["localization"].items():
                assert flat[a][f"localization.{k}"] == pytest.approx(v, nan_ok=True)
    finally:
        env.close()
        twin.close()
    with pytest.raises(ConfigError, match=r"info\['termination_reason'\] of 'uav_0' is None, not a number"):
        TensorInfo(make_train_env("state"), keys=("termination_reason",)).reset(seed=0)
    with pytest.raises(ConfigError, match=r"info of 'uav_0' has no 'nope'"):
        TensorInfo(make_train_env("state"), keys=("nope",)).reset(seed=0)
    with pytest.raises(ConfigError, match="keys must be a non-empty sequence"):
        TensorInfo(make_train_env("state"), keys="localization")


def test_torchrl_collects_with_a_shared_policy_and_takes_ppo_steps():
    torch.manual_seed(0)
    env = make_env()
    assert env.group_map == {"uav": ["uav_0", "uav_1", "uav_2", "uav_3"]}
    n_obs = env.observation_spec["uav", "observation"].shape[-1]
    action_spec = env.full_action_spec["uav", "action"]
    policy = ProbabilisticActor(
        TensorDictModule(
            torch.nn.Sequential(
                MultiAgentMLP(n_agent_inputs=n_obs, n_agent_outputs=2 * 5, n_agents=4, centralized=False,
                              share_params=True, depth=2, num_cells=64),
                NormalParamExtractor(),
            ),
            in_keys=[("uav", "observation")], out_keys=[("uav", "loc"), ("uav", "scale")],
        ),
        spec=action_spec,
        in_keys=[("uav", "loc"), ("uav", "scale")],
        out_keys=[("uav", "action")],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": action_spec.space.low, "high": action_spec.space.high},
        return_log_prob=True,
    )
    critic = TensorDictModule(  # a centralized critic over the four agents' observations
        MultiAgentMLP(n_agent_inputs=n_obs, n_agent_outputs=1, n_agents=4, centralized=True,
                      share_params=True, depth=2, num_cells=64),
        in_keys=[("uav", "observation")], out_keys=[("uav", "state_value")],
    )
    loss = ClipPPOLoss(actor_network=policy, critic_network=critic)
    loss.set_keys(reward=("uav", "reward"), action=("uav", "action"), value=("uav", "state_value"),
                  done=("uav", "done"), terminated=("uav", "terminated"))
    loss.make_value_estimator(ValueEstimators.GAE, gamma=0.95, lmbda=0.9)
    optim = torch.optim.Adam(loss.parameters(), 3e-4)
    collector = Collector(env, policy, frames_per_batch=24, total_frames=48,
                          auto_register_policy_transforms=True)
    before = [p.detach().clone() for p in policy.parameters()]
    batches = 0
    for data in collector:
        assert data["next", "uav", "reward"].shape == (24, 4, 1)
        assert data["next", "state"].shape == (24, 32)
        # an episode ends every 6 steps (max_cycles), for all four agents at once
        assert data["next", "uav", "truncated"].squeeze(-1).all(-1).sum() == 4
        # ... truncated, not terminated: TorchRL's GAE bootstraps V(next) there
        assert not data["next", "uav", "terminated"].any()
        with torch.no_grad():
            loss.value_estimator(data, params=loss.critic_network_params,
                                 target_params=loss.target_critic_network_params)
        terms = loss(data.reshape(-1))
        total = terms["loss_objective"] + terms["loss_critic"] + terms["loss_entropy"]
        assert torch.isfinite(total)
        optim.zero_grad()
        total.backward()
        optim.step()
        batches += 1
    collector.shutdown()
    assert batches == 2
    assert any(not torch.equal(a, b) for a, b in zip(before, policy.parameters(), strict=True))
    info = data["next", "uav", "info", "localization.success"]
    assert set(np.unique(info.numpy())) <= {0.0, 1.0}
