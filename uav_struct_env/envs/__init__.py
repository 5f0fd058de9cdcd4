"""PettingZoo environments: the four-UAV parallel env, its AEC form, presets and video helper."""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.conversions import parallel_to_aec, parallel_to_aec_wrapper

from uav_struct_env.envs.config import PRESETS, EnvConfig, make_config
from uav_struct_env.envs.uav_struct import ACTION_COMPONENTS, UavStructParallelEnv

__all__ = [
    "ACTION_COMPONENTS",
    "PRESETS",
    "EnvConfig",
    "UavStructParallelEnv",
    "env",
    "make_config",
    "parallel_env",
    "raw_env",
]


def parallel_env(preset: str | EnvConfig = "paper", **config: Any) -> UavStructParallelEnv:
    """The parallel environment: ``preset`` (``"paper"``, ``"train"`` or an EnvConfig) + overrides.

    Example:
        >>> env = parallel_env(stage="columns", image_size=(128, 72), noise="gnss_ins")
    """
    return UavStructParallelEnv(preset, **config)


def raw_env(preset: str | EnvConfig = "paper", **config: Any) -> parallel_to_aec_wrapper:
    """The AEC form without the order-enforcing wrapper."""
    return parallel_to_aec_wrapper(parallel_env(preset, **config))


def env(preset: str | EnvConfig = "paper", **config: Any):
    """The AEC form of :func:`parallel_env`.

    Built with ``pettingzoo.utils.conversions.parallel_to_aec``, which includes PettingZoo's
    ``OrderEnforcingWrapper``.
    """
    return parallel_to_aec(parallel_env(preset, **config))
