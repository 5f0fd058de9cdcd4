"""The base of this package's wrappers, and the one walk down a wrapper chain.

``BaseParallelWrapper`` forwards unknown attributes to the wrapped env, so the
``observation_spaces`` / ``action_spaces`` dicts that RLlib, TorchRL and skrl read would be the
inner env's (without the keys a wrapper adds or drops). Here they are built from the wrapper's
own ``observation_space(agent)`` / ``action_space(agent)``.

Every wrapper here, :class:`~uav_struct_env.wrappers.LocalizationWrapper` included, holds the
next layer inward as ``.env``: :func:`iter_chain` and :func:`find_wrapper` walk that attribute
and nothing else.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, TypeVar

from pettingzoo.utils import BaseParallelWrapper

__all__ = ["ParallelWrapper", "find_wrapper", "iter_chain"]

W = TypeVar("W")


class ParallelWrapper(BaseParallelWrapper):
    """``BaseParallelWrapper`` whose space dicts match its own spaces."""

    @property
    def observation_spaces(self) -> dict[str, Any]:
        """``{agent: observation_space(agent)}`` for every possible agent."""
        return {a: self.observation_space(a) for a in self.possible_agents}

    @property
    def action_spaces(self) -> dict[str, Any]:
        """``{agent: action_space(agent)}`` for every possible agent."""
        return {a: self.action_space(a) for a in self.possible_agents}


def iter_chain(env: Any) -> Iterator[Any]:
    """``env``, then each layer's ``.env`` inward, down to the env that wraps nothing."""
    while env is not None:
        yield env
        inner = getattr(env, "env", None)
        env = None if inner is env else inner


def find_wrapper(env: Any, cls: type[W]) -> W | None:
    """The outermost layer of type ``cls`` in ``env``'s wrapper chain (``env`` itself too), or None."""
    return next((layer for layer in iter_chain(env) if isinstance(layer, cls)), None)
