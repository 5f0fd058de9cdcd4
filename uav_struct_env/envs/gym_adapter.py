"""A Gymnasium single-agent view of the parallel environment.

:class:`SingleUavEnv` controls one agent (``agent``, default ``uav_0``) of any PettingZoo
parallel env built here — the bare ``uav_struct_v0`` or one wrapped in a
:class:`~uav_struct_env.wrappers.LocalizationWrapper` — while every other agent holds its
position (a zero action). Observation and action spaces are the controlled agent's; the reward,
``terminated`` and ``truncated`` are that agent's, and ``info`` is its info dict.

Registered with Gymnasium as ``uav_struct_env/UavStruct-v0`` (the bare env, keyword config)::

    import gymnasium as gym
    import uav_struct_env  # registers the id
    env = gym.make("uav_struct_env/UavStruct-v0", image_size=(128, 72), n_agents=1)
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from pettingzoo import ParallelEnv

__all__ = ["SingleUavEnv", "make_single"]


class SingleUavEnv(gym.Env):
    """One agent of a PettingZoo parallel env as a ``gymnasium.Env``.

    Args:
        parallel: the parallel env (it is owned: :meth:`close` closes it).
        agent: the controlled agent; default the first of ``possible_agents``.

    Raises:
        ValueError: if ``agent`` is not one of the env's agents.
    """

    def __init__(self, parallel: ParallelEnv, agent: str | None = None) -> None:
        if not isinstance(parallel, ParallelEnv):
            raise TypeError(
                f"parallel must be a pettingzoo ParallelEnv, got {type(parallel).__name__}"
            )
        agents = list(parallel.possible_agents)
        agent = agents[0] if agent is None else agent
        if agent not in agents:
            raise ValueError(f"agent must be one of {agents}, got {agent!r}")
        self.parallel = parallel
        self.agent = agent
        self.observation_space = parallel.observation_space(agent)
        self.action_space = parallel.action_space(agent)
        self.render_mode = getattr(parallel, "render_mode", None)
        self.metadata = {**getattr(parallel, "metadata", {}), "render_modes": ["rgb_array"]}
        self._hold = {a: np.zeros(parallel.action_space(a).shape, np.float32) for a in agents}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Reset the parallel env; returns the controlled agent's observation and info."""
        super().reset(seed=seed)
        obs, infos = self.parallel.reset(seed=seed, options=options)
        return obs[self.agent], infos[self.agent]

    def step(self, action):
        """Step with ``action`` for the controlled agent and a hold (zero) action for the rest."""
        actions = {a: self._hold[a] for a in self.parallel.agents if a != self.agent}
        actions[self.agent] = action
        obs, rewards, terms, truncs, infos = self.parallel.step(actions)
        return (
            obs[self.agent],
            float(rewards[self.agent]),
            bool(terms[self.agent]),
            bool(truncs[self.agent]),
            infos[self.agent],
        )

    def render(self):
        """The parallel env's frame (``render_mode="rgb_array"``)."""
        return self.parallel.render()

    def close(self) -> None:
        """Close the parallel env."""
        self.parallel.close()


def make_single(agent: str | None = None, **config: Any) -> SingleUavEnv:
    """Gymnasium entry point: ``SingleUavEnv(parallel_env(**config), agent)``."""
    from uav_struct_env.envs import parallel_env

    return SingleUavEnv(parallel_env(**config), agent)
