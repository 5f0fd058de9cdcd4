"""The asymmetric actor-critic: the policy reads its keys only, the value every key; trained and evaluated."""

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("supersuit")

import torch  # noqa: E402
from gymnasium import spaces  # noqa: E402

from uav_struct_env.training.asymmetric import AsymmetricActorCriticPolicy  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
SPACE = spaces.Dict({
    "image": spaces.Box(0, 255, (3, 36, 64), np.uint8),  # channel-first, as SB3 hands it on
    "gnss": spaces.Box(-np.inf, np.inf, (3,), np.float32),
    "attitude": spaces.Box(-np.inf, np.inf, (3,), np.float32),
    "pose": spaces.Box(-np.inf, np.inf, (6,), np.float32),
    "layout": spaces.Box(-np.inf, np.inf, (8,), np.float32),
})
ACTIONS = spaces.Box(-1.0, 1.0, (5,), np.float32)


def _policy(**kwargs):
    torch.manual_seed(0)
    return AsymmetricActorCriticPolicy(SPACE, ACTIONS, lambda _: 3e-4,
                                       actor_keys=("image", "gnss", "attitude"), net_arch=[16, 16], **kwargs)


def _batch(rng, n=6):
    return {k: torch.as_tensor(rng.uniform(0, 255 if k == "image" else 1, (n, *s.shape)).astype(s.dtype))
            for k, s in SPACE.spaces.items()}


def test_actions_ignore_the_critics_keys_and_values_read_them(rng):
    policy = _policy()
    obs = _batch(rng)
    other = {**obs, "pose": obs["pose"] + 5.0, "layout": -obs["layout"]}
    with torch.no_grad():
        a, _ = policy.predict({k: v.numpy() for k, v in obs.items()}, deterministic=True)
        b, _ = policy.predict({k: v.numpy() for k, v in other.items()}, deterministic=True)
        np.testing.assert_array_equal(a, b)  # the trained policy is a function of its keys
        assert not torch.equal(policy.predict_values(obs), policy.predict_values(other))
        moved = {**obs, "gnss": obs["gnss"] + 1.0}
        c, _ = policy.predict({k: v.numpy() for k, v in moved.items()}, deterministic=True)
        assert not np.array_equal(a, c)  # ... and reads them
    widths = (policy.pi_features_extractor.features_dim, policy.vf_features_extractor.features_dim)
    assert widths[1] == widths[0] + 6 + 8  # the critic sees pose and layout on top
    assert set(policy.pi_features_extractor.extractors) == {"image", "gnss", "attitude"}


def test_a_critic_without_the_image_is_an_mlp_of_the_keys_it_names(rng):
    policy = _policy(critic_keys=("gnss", "pose", "layout"))
    assert set(policy.vf_features_extractor.extractors) == {"gnss", "pose", "layout"}
    assert policy.vf_features_extractor.features_dim == 3 + 6 + 8
    cnns = [m for m in policy.modules() if isinstance(m, torch.nn.Conv2d)]
    assert len(cnns) == 3  # NatureCNN's three layers, the actor's only
    obs = _batch(rng)
    with torch.no_grad():
        image = {**obs, "image": 255 - obs["image"]}  # the critic does not read it
        assert torch.equal(policy.predict_values(obs), policy.predict_values(image))


@pytest.mark.parametrize("actor, critic", [((), ()), (("image", "speed"), ()), (tuple(SPACE.spaces), ()),
                                           (("image", "gnss"), ("gnss",)), (("image",), ("pose", "speed"))])
def test_the_critic_must_see_what_the_actor_does_not_and_keys_must_exist(actor, critic):
    with pytest.raises(ValueError, match=r"actor_keys and critic_keys must name keys of the observation"):
        AsymmetricActorCriticPolicy(SPACE, ACTIONS, lambda _: 3e-4, actor_keys=actor, critic_keys=critic)


@pytest.mark.parametrize("config, net", [("pixels_critic", "nature"), ("pixels_keypoints", "keypoints")])
def test_a_tiny_asymmetric_run_trains_loads_and_evaluates(load_script, tmp_path, config, net):
    from uav_struct_env.training.image_features import KeypointCNN
    from uav_struct_env.training.policy_files import load_ppo
    from uav_struct_env.wrappers import TRAIN_CONFIGS, make_train_env

    train = load_script(EXAMPLES / "train_viewpoint_ppo.py")
    out = tmp_path / "run"
    train.main(out=str(out), config=config, total_timesteps=64, n_envs=1, num_cpus=0, n_steps=16,
               batch_size=32, n_epochs=1, max_cycles=4, checkpoint_every=64, progress_bar=False, seed=5)
    record = json.loads((out / "train.json").read_text())
    assert record["train_config"]["actor_keys"] == ["image", "gnss", "attitude"]
    assert record["train_config"].get("image_net", "nature") == net
    env = make_train_env(config, max_cycles=4)
    try:
        model = load_ppo(out / "model.zip", env.observation_space("uav_0"), env.action_space("uav_0"))
        assert isinstance(model.policy, AsymmetricActorCriticPolicy)
        assert model.policy.actor_keys == TRAIN_CONFIGS[config].actor_keys
        assert model.policy.critic_keys == TRAIN_CONFIGS[config].critic_keys
        assert model.policy.image_net == net
        image = model.policy.pi_features_extractor.extractors["image"]
        assert isinstance(image, KeypointCNN) == (net == "keypoints")
    finally:
        env.close()
    summary = load_script(EXAMPLES / "evaluate_policy.py").main(model=str(out), policies=("ppo",), episodes=1,
                                                                max_cycles=3)
    assert summary["env_config"]["actor_keys"] == ["image", "gnss", "attitude"]
    assert summary["results"]["ppo"]["final_step"]["n"] == 4
