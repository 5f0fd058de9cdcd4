"""``TorchRLVectorEnv``: a :class:`~uav_struct_env.vector.ParallelVectorEnv` as a batched TorchRL env.

A TorchRL ``EnvBase`` of batch size ``[K]`` whose agents form one group ``"uav"``, as TorchRL's
``PettingZooWrapper`` groups them (tensors ``[K, A, ...]``): ``("uav", "observation")``,
``("uav", "action")``, ``("uav", "reward")`` and ``("uav", "done" | "terminated" | "truncated")``
per agent, ``"done"`` / ``"terminated"`` / ``"truncated"`` ``[K, 1]`` per env, and
``("uav", "info", "<key>.<name>")`` for the numeric entries of the info dicts ``info_keys``
(:class:`~uav_struct_env.wrappers.TensorInfo`'s names). Observations must be one vector per
agent: build the envs with ``wrap=FlattenObservation``.

TorchRL resets finished envs itself (its collectors call ``reset`` with a ``"_reset"`` mask),
so the vector env's autoreset is hidden: a step returns each finished env's final observation
and the reset it already made is handed out at TorchRL's ``reset`` of that env. Seeds as the
vector env's: ``set_seed(s)`` then ``reset()`` resets env ``k`` with ``s + k``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDict
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from uav_struct_env.errors import ConfigError
from uav_struct_env.vector.core import FINAL_OBSERVATION, ParallelVectorEnv

__all__ = ["TorchRLVectorEnv"]

GROUP = "uav"
FLAGS = ("done", "terminated", "truncated")


def _info_numbers(info: dict, keys: Sequence[str]) -> dict[str, float]:
    """The numeric entries of ``info[key]`` for ``key`` in ``keys``, named ``"<key>.<name>"``."""
    out = {}
    for key in keys:
        value = info[key]
        for name, v in (value.items() if isinstance(value, dict) else [(None, value)]):
            if np.asarray(v).dtype.kind in "biuf":
                out[key if name is None else f"{key}.{name}"] = float(v)
    return out


def _bounded(space: spaces.Box, batch: tuple[int, ...]) -> Bounded:
    """A float32 ``Bounded`` spec of ``space`` for every one of ``batch`` agents."""
    shape = (*batch, *space.shape)
    low = torch.as_tensor(space.low, dtype=torch.float32).expand(shape).clone()
    high = torch.as_tensor(space.high, dtype=torch.float32).expand(shape).clone()
    return Bounded(low, high, shape, dtype=torch.float32)


class TorchRLVectorEnv(EnvBase):
    """TorchRL's batched env over a :class:`ParallelVectorEnv` (see the module docstring).

    Raises:
        ConfigError: the agents' observation is not a flat ``Box`` or the action not a ``Box``.
    """

    def __init__(self, vec: ParallelVectorEnv, info_keys: Sequence[str] = ("localization",)) -> None:
        obs_space, act_space = vec.observation_space, vec.action_space
        if not isinstance(obs_space, spaces.Box) or len(obs_space.shape) != 1:
            raise ConfigError(
                f"TorchRLVectorEnv needs one observation vector per agent, got {obs_space}: build the "
                "envs with make_vector_env(..., wrap=FlattenObservation)"
            )
        if not isinstance(act_space, spaces.Box):
            raise ConfigError(f"TorchRLVectorEnv needs a Box action space, got {act_space}")
        super().__init__(batch_size=torch.Size([vec.num_envs]))
        self.vec, self.info_keys = vec, tuple(info_keys)
        self._seed: int | None = None
        obs, infos = vec.reset()  # the info entries' names
        self._info_names = list(_info_numbers(infos[0], self.info_keys))
        #: what the next reset hands out, and which envs it has reset already (the vector env's autoreset)
        self._next, self._fresh = (obs, infos), np.zeros(vec.num_envs, bool)
        self._stepped = False
        self._make_specs(obs_space, act_space)

    def _make_specs(self, obs_space: spaces.Box, act_space: spaces.Box) -> None:
        k, a = self.vec.num_envs, self.vec.agents_per_env
        shape = (k, a)
        group = Composite(
            observation=_bounded(obs_space, shape),
            info=Composite({n: Unbounded(shape, dtype=torch.float64) for n in self._info_names}, shape=shape),
            shape=shape,
        )
        self.observation_spec = Composite({GROUP: group}, shape=(k,))
        self.action_spec = Composite({GROUP: Composite(action=_bounded(act_space, shape), shape=shape)},
                                     shape=(k,))
        self.reward_spec = Composite(
            {GROUP: Composite(reward=Unbounded((*shape, 1)), shape=shape)}, shape=(k,)
        )
        flags = {f: Categorical(2, (*shape, 1), dtype=torch.bool) for f in FLAGS}
        env_flags = {f: Categorical(2, (k, 1), dtype=torch.bool) for f in FLAGS}
        self.done_spec = Composite({GROUP: Composite(flags, shape=shape), **env_flags}, shape=(k,))

    def _tensors(self, obs: np.ndarray, infos: list[dict]) -> TensorDict:
        k, a = self.vec.num_envs, self.vec.agents_per_env
        info = {
            n: torch.as_tensor(np.array([_info_numbers(i, self.info_keys)[n] for i in infos]).reshape(k, a))
            for n in self._info_names
        }
        group = TensorDict(
            {"observation": torch.as_tensor(obs).reshape(k, a, -1),
             "info": TensorDict(info, batch_size=(k, a))},
            batch_size=(k, a),
        )
        return TensorDict({GROUP: group}, batch_size=(k,))

    def _reset(self, tensordict: TensorDict | None = None, **kwargs: Any) -> TensorDict:
        """Reset every env, or (a ``"_reset"`` mask after a step) the masked ones."""
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is None or not self._stepped:
            self._next = self.vec.reset(seed=self._seed)
            self._seed, self._stepped = None, True
        else:
            self._reset_unfinished(mask.reshape(self.vec.num_envs, -1).any(1).cpu().numpy())
        self._fresh[:] = False
        out = self._tensors(*self._next)
        flags = {f: torch.zeros((self.vec.num_envs, self.vec.agents_per_env, 1), dtype=torch.bool)
                 for f in FLAGS}
        out[GROUP].update(flags)
        out.update({f: torch.zeros((self.vec.num_envs, 1), dtype=torch.bool) for f in flags})
        return out

    def _step(self, tensordict: TensorDict) -> TensorDict:
        actions = tensordict[GROUP, "action"].reshape(self.vec.num_slots, -1).cpu().numpy()
        obs, rewards, terminations, truncations, infos = self.vec.step(actions)
        k, a = self.vec.num_envs, self.vec.agents_per_env
        self._next = (obs.copy(), [self.vec.reset_infos[s] if FINAL_OBSERVATION in i else i
                                   for s, i in enumerate(infos)])
        self._fresh = np.array([FINAL_OBSERVATION in infos[j * a] for j in range(k)])
        final = obs.copy()
        for slot, info in enumerate(infos):
            if FINAL_OBSERVATION in info:
                final[slot] = info[FINAL_OBSERVATION]
        out = self._tensors(final, infos)
        term = torch.as_tensor(terminations).reshape(k, a, 1)
        trunc = torch.as_tensor(truncations).reshape(k, a, 1)
        out[GROUP].update({"reward": torch.as_tensor(rewards).reshape(k, a, 1),
                           "terminated": term, "truncated": trunc, "done": term | trunc})
        out.update({"terminated": term.all(1), "truncated": trunc.all(1) & ~term.all(1),
                    "done": (term | trunc).all(1)})
        return out

    def _reset_unfinished(self, envs: np.ndarray) -> None:
        """Reset the envs in ``envs`` that the vector env did not reset at the last step."""
        obs, infos = self._next
        a = self.vec.agents_per_env
        for k in np.flatnonzero(envs & ~self._fresh):
            env_obs, env_infos = self.vec.envs[k].reset()
            for i, agent in enumerate(self.vec.possible_agents):
                obs[k * a + i], infos[k * a + i] = env_obs[agent], env_infos[agent]

    def _set_seed(self, seed: int | None) -> None:
        self._seed = seed

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Close every env."""
        self.vec.close()
        super().close(raise_if_closed=raise_if_closed)
