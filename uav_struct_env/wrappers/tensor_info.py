"""``TensorInfo``: each agent's info as flat, fixed-shape numbers, for libraries that stack infos.

TorchRL's ``PettingZooWrapper`` turns every info entry of every agent into a tensor of a fixed
shape, read once at reset: the env's own info (pose matrices beside ``None`` reasons, landmark
dicts of varying length) and ``reward_terms`` (whose keys change with the outcome) cannot be.
``TensorInfo(env, keys=("localization",))`` keeps only the named entries, a dict flattened to
``"<key>.<name>"`` entries (``localization.success``, ``localization.translation_error_m``...),
each a number or a numeric array whose shape must stay the one it had at reset.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from uav_struct_env.errors import ConfigError
from uav_struct_env.wrappers.base import ParallelWrapper

__all__ = ["TensorInfo"]


class TensorInfo(ParallelWrapper):
    """Keep the info entries ``keys``, flattened to numbers (see the module docstring).

    Raises:
        ConfigError: ``keys`` is empty or not strings; at reset or step, an agent's info lacks a
            key, holds a value that is not numeric, or changes the layout it had at reset.
    """

    def __init__(self, env: Any, keys: Sequence[str] = ("localization",)) -> None:
        super().__init__(env)
        if isinstance(keys, str) or not keys or not all(isinstance(k, str) for k in keys):
            raise ConfigError(f"keys must be a non-empty sequence of info key names, got {keys!r}")
        self.keys = tuple(keys)
        self._layout: dict[str, tuple[int, ...]] | None = None

    def _flat(self, agent: str, info: dict) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for key in self.keys:
            if key not in info:
                raise ConfigError(f"info of {agent!r} has no {key!r}; its keys are {sorted(info)}")
            value = info[key]
            for name, v in (value.items() if isinstance(value, dict) else [(None, value)]):
                full = key if name is None else f"{key}.{name}"
                arr = np.asarray(v)
                if arr.dtype.kind not in "biuf":
                    raise ConfigError(f"info[{full!r}] of {agent!r} is {v!r}, not a number or numeric array; "
                                      "TensorInfo keeps numbers only")
                out[full] = arr
        return out

    def _convert(self, infos: dict[str, dict], at_reset: bool) -> dict[str, dict]:
        flat = {a: self._flat(a, info) for a, info in infos.items()}
        for agent, entries in flat.items():
            layout = {k: v.shape for k, v in entries.items()}
            if at_reset and self._layout is None:
                self._layout = layout
            elif layout != self._layout:
                raise ConfigError(f"the info of {agent!r} changed its layout from {self._layout} to "
                                  f"{layout}; a tensor library needs the same keys and shapes every step")
        return flat

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset; infos reduced to the numeric entries of ``keys``."""
        obs, infos = self.env.reset(seed=seed, options=options)
        return obs, self._convert(infos, at_reset=True)

    def step(self, actions: dict[str, Any]):
        """Step; infos reduced to the numeric entries of ``keys``."""
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        return obs, rewards, terminations, truncations, self._convert(infos, at_reset=False)
