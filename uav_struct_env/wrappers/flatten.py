"""``FlattenObservation``: every agent's Dict observation as one flat float32 ``Box``.

For libraries and policies that want a vector (RLlib's default models, skrl, TorchRL's MLPs):
the keys are concatenated in the Dict space's (sorted) key order with
:func:`gymnasium.spaces.flatten`; :attr:`FlattenObservation.layout` names the slice of each key.
Drop the image first (``LocalizationWrapper(..., drop_image=True)`` or an env with
``observe_image=False``) unless a flat image is really wanted.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from uav_struct_env.wrappers.base import ParallelWrapper

__all__ = ["FlattenObservation"]


class FlattenObservation(ParallelWrapper):
    """Flatten every agent's Dict observation to a float32 vector (see the module docstring)."""

    def __init__(self, env: Any) -> None:
        super().__init__(env)
        inner = env.observation_space(env.possible_agents[0])
        if not isinstance(inner, spaces.Dict):
            raise TypeError(f"FlattenObservation needs a Dict observation space, got {inner}")
        self._inner = inner
        flat = spaces.flatten_space(inner)
        self._observation_space = spaces.Box(flat.low.astype(np.float32), flat.high.astype(np.float32),
                                             dtype=np.float32)
        self.layout: dict[str, slice] = {}
        start = 0
        for key, sub in inner.spaces.items():
            n = spaces.flatdim(sub)
            self.layout[key] = slice(start, start + n)
            start += n

    def observation_space(self, agent: str) -> spaces.Box:
        """The flat space, shared by every agent."""
        self.env.observation_space(agent)
        return self._observation_space

    def _flatten(self, obs: dict) -> dict:
        return {a: spaces.flatten(self._inner, o).astype(np.float32) for a, o in obs.items()}

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset and flatten."""
        obs, infos = self.env.reset(seed=seed, options=options)
        return self._flatten(obs), infos

    def step(self, actions: dict[str, Any]):
        """Step and flatten."""
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        return self._flatten(obs), rewards, terminations, truncations, infos
