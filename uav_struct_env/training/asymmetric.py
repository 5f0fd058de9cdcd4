"""An actor-critic whose critic sees more than its actor: a policy from pixels, a value from the state.

A viewpoint policy from the camera (``TRAIN_CONFIGS["pixels_critic"]``) must decide from what a
UAV has before any localization: the image, GNSS and attitude. Its value function is only needed
while training, where the simulator knows more: the localized pose, its standard deviations and
the layout features the ``state`` policies learn from. Giving them to the critic alone (an
asymmetric actor-critic, Pinto et al., "Asymmetric Actor Critic for Image-Based Robot Learning",
RSS 2018) leaves the trained policy what it was -- a function of ``actor_keys`` only -- while the
advantages it is trained on come from a value that can see why a viewpoint localizes well.

:class:`AsymmetricActorCriticPolicy` is SB3's ``MultiInputPolicy`` with separate feature
extractors (``share_features_extractor=False``): the actor's over the observation's
``actor_keys``, the critic's over ``critic_keys`` (every key by default), each followed by its
own MLP of ``net_arch``.
``predict`` (what evaluation and deployment call) runs the actor's side only; a test holds its
actions unchanged when every other key changes. The critic may read a subset too
(``critic_keys``): without the image it is an MLP, and the update trains one CNN, not two.
``image_net`` chooses the image network: SB3's NatureCNN (``"nature"``), or the small-frame CNN
read out as keypoints (``"keypoints"``, :mod:`uav_struct_env.training.image_features`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from gymnasium import spaces
from stable_baselines3.common.policies import MultiInputActorCriticPolicy
from stable_baselines3.common.torch_layers import MlpExtractor
from torch import nn

from uav_struct_env.training.image_features import KeypointExtractor
from uav_struct_env.wrappers.configs import IMAGE_NETS

__all__ = ["AsymmetricActorCriticPolicy", "SplitMlpExtractor"]


class SplitMlpExtractor(nn.Module):
    """The policy's and the value's MLPs (``net_arch``) on features of different widths.

    SB3's :class:`~stable_baselines3.common.torch_layers.MlpExtractor` takes one input width for
    both; here the actor's features (``pi_dim``) and the critic's (``vf_dim``) differ.
    """

    def __init__(self, pi_dim: int, vf_dim: int, net_arch: Any, activation_fn: type[nn.Module],
                 device: Any = "auto") -> None:
        super().__init__()
        policy = MlpExtractor(pi_dim, net_arch, activation_fn, device)
        value = MlpExtractor(vf_dim, net_arch, activation_fn, device)
        self.policy_net, self.latent_dim_pi = policy.policy_net, policy.latent_dim_pi
        self.value_net, self.latent_dim_vf = value.value_net, value.latent_dim_vf

    def forward(self, features: Any) -> Any:
        """Not used: the extractors are never shared (features come as an (actor, critic) pair)."""
        pi_features, vf_features = features
        return self.forward_actor(pi_features), self.forward_critic(vf_features)

    def forward_actor(self, features: Any) -> Any:
        """The actor's latent from its features."""
        return self.policy_net(features)

    def forward_critic(self, features: Any) -> Any:
        """The critic's latent from its features."""
        return self.value_net(features)


class AsymmetricActorCriticPolicy(MultiInputActorCriticPolicy):
    """SB3's dict-observation actor-critic, its actor limited to ``actor_keys`` (module docstring).

    Args:
        observation_space: the env's ``spaces.Dict``.
        action_space, lr_schedule: as :class:`~stable_baselines3.common.policies.MultiInputActorCriticPolicy`.
        actor_keys: the observation keys the actor (the trained policy) reads.
        critic_keys: the observation keys the critic (the value function) reads; empty: every key.
        image_net: the image network, one of :data:`~uav_struct_env.wrappers.configs.IMAGE_NETS`
            (``"nature"``: the ``features_extractor_class`` SB3 gives, NatureCNN for images).
        **kwargs: :class:`~stable_baselines3.common.policies.MultiInputActorCriticPolicy`'s;
            ``share_features_extractor`` is always False.

    Raises:
        ValueError: if ``actor_keys`` is empty, either names a key the observation lacks, or the
            critic would see nothing the actor does not (then use ``MultiInputPolicy``); for an
            unknown ``image_net``.
    """

    def __init__(self, observation_space: spaces.Dict, action_space: spaces.Space, lr_schedule: Any,
                 actor_keys: Sequence[str] = (), critic_keys: Sequence[str] = (), image_net: str = "nature",
                 **kwargs: Any) -> None:
        if image_net not in IMAGE_NETS:
            raise ValueError(f"image_net must be one of {list(IMAGE_NETS)}, got {image_net!r}")
        self.image_net = image_net
        have = tuple(observation_space.spaces)
        actor, critic = tuple(actor_keys), tuple(critic_keys) or have
        known = set(actor) <= set(have) and set(critic) <= set(have)
        if not actor or not known or set(critic) <= set(actor):
            raise ValueError(
                f"actor_keys and critic_keys must name keys of the observation {sorted(have)}, the "
                f"critic's some the actor lacks; got actor_keys {list(actor)}, "
                f"critic_keys {list(critic_keys)}"
            )
        self.actor_keys, self.critic_keys = actor, critic
        kwargs["share_features_extractor"] = False
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build_mlp_extractor(self) -> None:
        """The extractors over ``actor_keys`` and ``critic_keys``, then the two MLPs on their widths."""
        self.pi_features_extractor = self._extractor(self.actor_keys)
        self.vf_features_extractor = self._extractor(self.critic_keys)
        self.features_extractor = self.pi_features_extractor
        self.mlp_extractor = SplitMlpExtractor(
            self.pi_features_extractor.features_dim, self.vf_features_extractor.features_dim,
            self.net_arch, self.activation_fn, self.device,
        )

    def _extractor(self, keys: tuple[str, ...]) -> nn.Module:
        """The policy's features extractor class over the observation's ``keys``."""
        space = spaces.Dict({k: self.observation_space.spaces[k] for k in keys})
        if self.image_net == "keypoints":
            return KeypointExtractor(space)
        return self.features_extractor_class(space, **self.features_extractor_kwargs)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "actor_keys": self.actor_keys,
                "critic_keys": self.critic_keys, "image_net": self.image_net}
