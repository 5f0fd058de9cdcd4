"""``SB3VecEnv``: a :class:`~uav_struct_env.vector.ParallelVectorEnv` as a Stable-Baselines3 ``VecEnv``.

Every slot (agent of an env) is one of SB3's environments, as SuperSuit's
``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1`` make them, so ``PPO("MultiInputPolicy",
SB3VecEnv(vec))`` trains one policy shared by all agents, without SuperSuit and in one process.

What SB3 reads at the end of an episode, and SuperSuit does not give: each done slot's info
holds the final step's own info (not the next episode's reset info merged over it),
``"terminal_observation"`` (the episode's last observation) and ``"TimeLimit.truncated"`` (True
where the episode hit its time limit and was not terminated by a crash: SB3 then bootstraps the
value of the terminal observation). ``seed(s)`` (``PPO(seed=s)`` calls it) makes the next
``reset()`` reset env ``k`` with ``s + k``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from uav_struct_env.vector.core import FINAL_OBSERVATION, ParallelVectorEnv

__all__ = ["SB3VecEnv"]


class SB3VecEnv(VecEnv):
    """SB3's ``VecEnv`` over the slots of a :class:`ParallelVectorEnv` (see the module docstring)."""

    def __init__(self, vec: ParallelVectorEnv) -> None:
        self.vec = vec
        self._actions: np.ndarray | None = None
        super().__init__(vec.num_slots, vec.observation_space, vec.action_space)

    def _envs(self, indices: int | Iterable[int] | None) -> list[Any]:
        """The env of each slot in ``indices`` (SB3's ``VecEnvIndices``)."""
        slots = self._get_indices(indices)
        return [self.vec.envs[i // self.vec.agents_per_env] for i in slots]

    def reset(self) -> Any:
        """Reset every env (with the seeds of :meth:`seed`, once); the stacked observations."""
        obs, infos = self.vec.reset(seed=self._seeds[0])
        self.reset_infos = infos
        self._reset_seeds()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        """Keep the actions for :meth:`step_wait`."""
        self._actions = actions

    def step_wait(self) -> tuple[Any, np.ndarray, np.ndarray, list[dict]]:
        """Step every env; done slots carry ``terminal_observation`` and ``TimeLimit.truncated``."""
        obs, rewards, terminations, truncations, infos = self.vec.step(self._actions)
        dones = terminations | truncations
        for slot in np.flatnonzero(dones):
            info = infos[slot] = dict(infos[slot])
            info["terminal_observation"] = info.pop(FINAL_OBSERVATION)
            info["TimeLimit.truncated"] = bool(truncations[slot] and not terminations[slot])
        self.reset_infos = self.vec.reset_infos
        return obs, rewards, dones, infos

    def close(self) -> None:
        """Close every env."""
        self.vec.close()

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        """The attribute ``attr_name`` of each slot's env."""
        return [getattr(env, attr_name) for env in self._envs(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        """Set ``attr_name`` on each slot's env (an env shared by several slots gets it once per slot)."""
        for env in self._envs(indices):
            setattr(env, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call ``method_name`` on each slot's env."""
        return [getattr(env, method_name)(*method_args, **method_kwargs) for env in self._envs(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        """False: the slots are PettingZoo agents, never wrapped in a Gymnasium wrapper."""
        return [False] * len(self._get_indices(indices))

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """The next :meth:`reset` resets env ``k`` with ``seed + k``; the seed of each slot's env."""
        super().seed(seed)
        base = self._seeds[0]
        self._seeds = [base + i // self.vec.agents_per_env for i in range(self.num_envs)]
        return self._seeds
