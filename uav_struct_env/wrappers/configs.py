"""Named training configurations and a factory for wrapped environments.

``TRAIN_CONFIGS`` (frozen :class:`TrainConfig`) are the documented observation configs that train
on 2 CPU cores (docs/training.md):

* ``"state"``: state-only. No frame is rendered (``observe_image=False``): landmark visibility is
  ray-cast (:mod:`uav_struct_env.sim.raycast`); the policy sees ``gnss``, ``attitude``, ``pose``,
  ``pose_std``, ``localized`` and ``layout``. Column tops, robust association (the one that
  fails rather than accept wrong identities) on a clean projection detector (1 px noise at the
  paper's resolution) started from each agent's previous pose and commanded motion
  (``warm_start``), ``error`` reward, 30-step episodes, random
  starts 15-35 m out turned by up to +-60 deg of heading (some start views miss part of the
  structure).
* ``"image"``: the same plus a low-resolution 64 x 36 RGB ``image`` (``MultiInputPolicy`` with
  SB3's NatureCNN, several times slower per step to learn from), drawn by the batched renderer
  (``renderer="batch"``, :mod:`uav_struct_env.sim.batch`: the same body at 99+ % of pixels and the
  same landmark visibility as TinyRenderer, ``benchmarks/batch_render.py``).
* ``"pixels"``: the ``image`` configuration's env and reward, but the policy sees only what a UAV
  has before any localization: the 64 x 36 ``image``, ``gnss`` and ``attitude`` (no ``pose``,
  ``pose_std``, ``localized`` or ``layout``: the projection detector that makes them reads the
  simulator's landmark truth). A viewpoint policy from the camera (issue 41, item 4).
* ``"pixels_critic"``: the ``image`` configuration's env, reward and observation, of which the
  policy reads only the ``pixels`` keys (``actor_keys``: ``image``, ``gnss``, ``attitude``); the
  value function, used only in training, reads the ``state`` configuration's keys
  (``critic_keys``: an MLP, so the update trains one CNN)
  (:class:`uav_struct_env.training.asymmetric.AsymmetricActorCriticPolicy`, an asymmetric
  actor-critic). The trained policy is a policy from pixels as ``pixels``' is.
* ``"pixels_keypoints"``: ``pixels_critic`` with a small-frame CNN read out as keypoints (a
  spatial softmax) in place of NatureCNN, whose strides leave a 64 x 36 frame a 1 x 4 map
  (``image_net="keypoints"``, :mod:`uav_struct_env.training.image_features`).
* ``"pixels_precise"``: ``pixels_critic`` with the ``log_error`` reward (each pose-error term on a
  log scale, :class:`~uav_struct_env.wrappers.rewards.LogErrorReward`): ending closer to the
  building, a few hundredths of a metre less error per step, pays about 7x what it does in
  ``error`` (a probe, docs/training.md).
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from dataclasses import dataclass, field
from typing import Any

from uav_struct_env.errors import ConfigError
from uav_struct_env.wrappers.localization import LocalizationWrapper

__all__ = ["IMAGE_NETS", "TRAIN_CONFIGS", "TrainConfig", "make_localization_env", "make_train_env"]


#: TrainConfig's fields that name observation keys for the policy's two sides.
_POLICY_KEYS = ("actor_keys", "critic_keys")

#: The image networks a configuration's policy may use (``TrainConfig.image_net``): SB3's NatureCNN,
#: or the small-frame CNN read out as keypoints (:mod:`uav_struct_env.training.image_features`).
IMAGE_NETS = ("nature", "keypoints")


@dataclass(frozen=True)
class TrainConfig:
    """An environment configuration for training: env overrides + wrapper options.

    ``wrapper`` holds :class:`~uav_struct_env.wrappers.LocalizationWrapper` keyword arguments;
    ``actor_keys``, when given, the observation keys the trained policy reads, and
    ``critic_keys`` (empty: every key) those its value function reads, in training only (an
    asymmetric actor-critic); ``image_net`` the policy's image network (one of
    :data:`IMAGE_NETS`; other than ``"nature"`` only with ``actor_keys``); a
    ``"mode"`` key (the former name of ``"association"``, as saved configurations may hold it) is
    read as ``"association"`` with a FutureWarning, for one release.
    """

    name: str
    env: dict[str, Any] = field(default_factory=dict)
    wrapper: dict[str, Any] = field(default_factory=dict)
    preset: str = "train"
    actor_keys: tuple[str, ...] = ()
    critic_keys: tuple[str, ...] = ()
    image_net: str = "nature"

    def __post_init__(self) -> None:
        object.__setattr__(self, "actor_keys", tuple(self.actor_keys))
        object.__setattr__(self, "critic_keys", tuple(self.critic_keys))
        if self.image_net not in IMAGE_NETS or (self.image_net != "nature" and not self.actor_keys):
            raise ConfigError(f"image_net must be one of {list(IMAGE_NETS)} (other than 'nature' only with "
                              f"actor_keys), got {self.image_net!r} with actor_keys {list(self.actor_keys)}")
        if "mode" in self.wrapper:  # the former name of association=, for one release
            warnings.warn(
                "the wrapper option 'mode' is renamed 'association' (as in StackSpec and Localizer); "
                "'mode' will be removed in the next release", FutureWarning, stacklevel=3,
            )
            wrapper = {k: v for k, v in self.wrapper.items() if k != "mode"}
            object.__setattr__(self, "wrapper", {**wrapper, "association": self.wrapper["mode"]})

    def replace(
        self, env: dict[str, Any] | None = None, wrapper: dict[str, Any] | None = None
    ) -> TrainConfig:
        """A copy with some env / wrapper options overridden."""
        return dataclasses.replace(
            self, env={**self.env, **(env or {})}, wrapper={**self.wrapper, **(wrapper or {})}
        )

    def as_dict(self) -> dict[str, Any]:
        """The configuration as JSON-ready data (tuples as lists); :meth:`from_dict` reads it.

        ``actor_keys``, ``critic_keys`` and ``image_net`` only where given (a configuration without
        them reads as before).
        """
        data = {"name": self.name, "preset": self.preset, "env": self.env, "wrapper": self.wrapper}
        data.update({k: getattr(self, k) for k in _POLICY_KEYS if getattr(self, k)})
        if self.image_net != "nature":
            data["image_net"] = self.image_net
        return json.loads(json.dumps(data))

    @classmethod
    def from_dict(cls, data: Any) -> TrainConfig:
        """The configuration :meth:`as_dict` wrote (the env's and wrapper's lists back to tuples).

        Raises:
            ConfigError: if ``data`` is not such a mapping.
        """
        keys = {"name", "preset", "env", "wrapper"}
        if (not isinstance(data, dict) or not keys <= set(data) <= keys | set(_POLICY_KEYS) | {"image_net"}
                or not all(isinstance(data[k], dict) for k in ("env", "wrapper"))
                or not all(isinstance(data.get(k, []), list) for k in _POLICY_KEYS)
                or not isinstance(data.get("image_net", "nature"), str)):
            raise ConfigError(
                f"a training configuration must be a mapping with keys {sorted(keys)} (env and "
                f"wrapper mappings) and optionally {' and '.join(_POLICY_KEYS)} (lists) and image_net "
                f"(a name), got {data!r}"
            )
        env, wrapper = ({k: tuple(v) if isinstance(v, list) else v for k, v in data[part].items()}
                        for part in ("env", "wrapper"))
        policy = {k: tuple(str(x) for x in data.get(k, ())) for k in _POLICY_KEYS}
        return cls(str(data["name"]), env, wrapper, str(data["preset"]), **policy,
                   image_net=data.get("image_net", "nature"))


_STATE_ENV = {
    "image_size": (128, 72),
    "max_cycles": 30,
    "start_yaw_jitter": math.radians(60.0),
    "render_mode": "rgb_array",  # SuperSuit/SB3 read env.render_mode
}
_WRAPPER = {
    "landmarks": "column_tops",
    "detector": "projection",
    "association": "robust",
    "reward": "error",
    "warm_start": True,
}

_IMAGE_ENV = {**_STATE_ENV, "image_size": (64, 36), "renderer": "batch"}
_IMAGE_WRAPPER = {**_WRAPPER, "drop_image": False}

# image's env, reward and observation; the policy reads pixels' keys, the value function state's
_PIXELS_CRITIC = TrainConfig(
    "pixels_critic", env=dict(_IMAGE_ENV), wrapper=dict(_IMAGE_WRAPPER),
    actor_keys=("image", "gnss", "attitude"),
    critic_keys=("gnss", "attitude", "pose", "pose_std", "localized", "layout"),
)

TRAIN_CONFIGS: dict[str, TrainConfig] = {
    "state": TrainConfig(
        "state", env={**_STATE_ENV, "observe_image": False}, wrapper={**_WRAPPER, "drop_image": True}
    ),
    "image": TrainConfig("image", env=dict(_IMAGE_ENV), wrapper=dict(_IMAGE_WRAPPER)),
    # image's env and reward; the observation without what the localization makes
    "pixels": TrainConfig(
        "pixels", env=dict(_IMAGE_ENV),
        wrapper={**_IMAGE_WRAPPER, "drop_keys": ("pose", "pose_std", "localized", "layout")},
    ),
    "pixels_critic": _PIXELS_CRITIC,
    # pixels_critic with the small-frame CNN read out as keypoints in place of NatureCNN
    "pixels_keypoints": dataclasses.replace(
        _PIXELS_CRITIC, name="pixels_keypoints", env=dict(_IMAGE_ENV), wrapper=dict(_IMAGE_WRAPPER),
        image_net="keypoints",
    ),
    # pixels_critic with the pose-error terms on a log scale (the same per halving of the error)
    "pixels_precise": dataclasses.replace(
        _PIXELS_CRITIC, name="pixels_precise", env=dict(_IMAGE_ENV),
        wrapper={**_IMAGE_WRAPPER, "reward": "log_error"},
    ),
}


def make_localization_env(
    landmarks: str = "column_tops",
    preset: str = "train",
    env_overrides: dict[str, Any] | None = None,
    **wrapper_kwargs: Any,
) -> LocalizationWrapper:
    """A ``uav_struct_v0`` env (``preset`` + overrides) that provides ``landmarks``' truth, wrapped.

    ``landmark_sets`` is set to include ``landmarks`` (the ``train`` preset has none).
    """
    import uav_struct_env

    overrides = dict(env_overrides or {})
    sets = tuple(overrides.pop("landmark_sets", ()))
    if landmarks not in sets:
        sets = (*sets, landmarks)
    env = uav_struct_env.parallel_env(preset, landmark_sets=sets, **overrides)
    return LocalizationWrapper(env, landmarks=landmarks, **wrapper_kwargs)


def make_train_env(config: str | TrainConfig = "state", **env_overrides: Any) -> LocalizationWrapper:
    """The wrapped env of a named :data:`TRAIN_CONFIGS` entry (env fields may be overridden)."""
    if isinstance(config, str):
        if config not in TRAIN_CONFIGS:
            raise ConfigError(f"config must be one of {sorted(TRAIN_CONFIGS)}, got {config!r}")
        config = TRAIN_CONFIGS[config]
    wrapper = dict(config.wrapper)
    landmarks = wrapper.pop("landmarks", "column_tops")
    return make_localization_env(
        landmarks, preset=config.preset, env_overrides={**config.env, **env_overrides}, **wrapper
    )
