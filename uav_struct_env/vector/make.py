"""``make_vector_env``: K wrapped envs of a training configuration, on one site or on K sites."""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any

from localization.checks import check_number
from uav_struct_env.errors import ConfigError
from uav_struct_env.vector.core import ParallelVectorEnv
from uav_struct_env.wrappers.configs import TrainConfig, make_train_env

__all__ = ["make_vector_env"]


def _sites(site: Any, num_envs: int, texture_seed: int) -> list[dict[str, Any]]:
    """Per env, the ``site`` / ``texture_seed`` overrides."""
    if isinstance(site, str):  # "paper", "random" or a file: one per env, textures (and "random") by seed
        return [{"site": site, "texture_seed": texture_seed + k} for k in range(num_envs)]
    if not isinstance(site, Sequence) or len(site) != num_envs:
        raise ConfigError(
            f"site must be a name ('paper', 'random', a site file) or one site per env "
            f"({num_envs}), got {site!r}"
        )
    return [{"site": s, "texture_seed": texture_seed + k} for k, s in enumerate(site)]


def make_vector_env(
    config: str | TrainConfig = "state",
    num_envs: int = 4,
    *,
    site: str | Sequence[Any] = "paper",
    texture_seed: int = 0,
    wrap: Any = None,
    **env_overrides: Any,
) -> ParallelVectorEnv:
    """A :class:`ParallelVectorEnv` of ``num_envs`` copies of :func:`make_train_env` ``(config)``.

    Args:
        config: a :data:`~uav_struct_env.wrappers.TRAIN_CONFIGS` name or a :class:`TrainConfig`.
        num_envs: K, the envs stepped together.
        site: ``"paper"``, ``"random"`` (env ``k`` draws its own site from ``texture_seed + k``),
            a site file, or a sequence of K sites (:class:`~uav_struct_env.site.Site` or names).
        texture_seed: env ``k``'s ``texture_seed`` is ``texture_seed + k`` (its textures differ).
        wrap: applied to each wrapped env (e.g. ``StepInfos`` or ``FlattenObservation``), or None.
        **env_overrides: env fields of the configuration, overridden (as ``make_train_env``).

    Raises:
        ConfigError: ``num_envs`` < 1, a site sequence of another length, a bad configuration.
    """
    check_number("num_envs", num_envs, 1, integer=True, error=ConfigError)
    check_number("texture_seed", texture_seed, 0, integer=True, error=ConfigError)
    fns = []
    for per_env in _sites(site, int(num_envs), int(texture_seed)):
        fn = partial(make_train_env, config, **{**env_overrides, **per_env})
        fns.append(fn if wrap is None else partial(_wrapped, fn, wrap))
    return ParallelVectorEnv(fns)


def _wrapped(fn: Any, wrap: Any) -> Any:
    return wrap(fn())
