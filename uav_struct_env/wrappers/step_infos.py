"""``StepInfos``: only the named info entries, and only from steps, for SuperSuit's vector envs.

SuperSuit's ``MarkovVectorEnv`` (``pettingzoo_env_to_vec_env_v1``) resets an env copy inside the
step that ends its episode and merges the reset's infos *over* the final step's: an entry both
return (``info["localization"]``) then describes the next episode's first frame, not the final
step it sits beside (with its ``terminal_observation``). Its ``ProcConcatVec`` also pickles every
info through a pipe and deep-copies it in the training process, every step and agent; the env's
own info (landmark truth, pose matrices) is 2 KB pickled per agent and some seventy nested
objects to copy.

``StepInfos(env, keys=("localization",))`` returns, at every step, each agent's info reduced to
the entries ``keys`` and, at reset, empty infos: a trainer that reads ``info["localization"]`` at
``done`` reads the final step's, and the vector env carries a tenth of the bytes.

``time_limit=True`` adds ``info["TimeLimit.truncated"]``: True where the agent's episode was
truncated (the time limit) and not terminated (a crash). Stable-Baselines3 bootstraps the value
of such a final state (``reward + gamma * V(terminal_observation)``) only when this entry says
so, and SuperSuit does not set it: without it every time limit counts as the end of the world.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from uav_struct_env.errors import ConfigError
from uav_struct_env.wrappers.base import ParallelWrapper

__all__ = ["StepInfos"]


class StepInfos(ParallelWrapper):
    """Step infos reduced to the entries ``keys``; reset infos empty (see the module docstring).

    Raises:
        ConfigError: ``keys`` is empty or not strings, or ``time_limit`` not a bool; at a step,
            an agent's info lacks a key.
    """

    def __init__(
        self, env: Any, keys: Sequence[str] = ("localization",), *, time_limit: bool = False
    ) -> None:
        super().__init__(env)
        if isinstance(keys, str) or not keys or not all(isinstance(k, str) for k in keys):
            raise ConfigError(f"keys must be a non-empty sequence of info key names, got {keys!r}")
        if not isinstance(time_limit, bool):
            raise ConfigError(f"time_limit must be True or False, got {time_limit!r}")
        self.keys = tuple(keys)
        self.time_limit = time_limit

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset; every agent's info empty."""
        obs, _ = self.env.reset(seed=seed, options=options)
        return obs, {a: {} for a in obs}

    def step(self, actions: dict[str, Any]):
        """Step; each agent's info reduced to the entries ``keys``."""
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        out = {}
        for agent, info in infos.items():
            missing = [k for k in self.keys if k not in info]
            if missing:
                raise ConfigError(f"info of {agent!r} has no {missing}; its keys are {sorted(info)}")
            out[agent] = {k: info[k] for k in self.keys}
            if self.time_limit:
                out[agent]["TimeLimit.truncated"] = bool(truncations[agent] and not terminations[agent])
        return obs, rewards, terminations, truncations, out
