"""``DropKeys``: remove observation keys after the wrappers below have used them.

The image, for state-only training: it is rendered and localized, then dropped.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from gymnasium import spaces

from uav_struct_env.errors import ConfigError
from uav_struct_env.wrappers.base import ParallelWrapper

__all__ = ["DropKeys"]


class DropKeys(ParallelWrapper):
    """Remove ``keys`` (default ``("image",)``) from every agent's Dict observation and space.

    Raises:
        ConfigError: for a key the observation space does not have.
    """

    def __init__(self, env: Any, keys: Sequence[str] = ("image",)) -> None:
        super().__init__(env)
        inner = env.observation_space(env.possible_agents[0]).spaces
        missing = [k for k in keys if k not in inner]
        if missing:
            raise ConfigError(f"cannot drop {missing}: the observation has {sorted(inner)}")
        self.keys = tuple(keys)
        self._observation_space = spaces.Dict({k: v for k, v in inner.items() if k not in self.keys})

    def observation_space(self, agent: str) -> spaces.Dict:
        """The cached observation space without the dropped keys."""
        self.env.observation_space(agent)
        return self._observation_space

    def _drop(self, obs: dict) -> None:
        for o in obs.values():
            for k in self.keys:
                o.pop(k, None)

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset the env and drop the keys."""
        obs, infos = self.env.reset(seed=seed, options=options)
        self._drop(obs)
        return obs, infos

    def step(self, actions: dict[str, Any]):
        """Step the env and drop the keys."""
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        self._drop(obs)
        return obs, rewards, terminations, truncations, infos
