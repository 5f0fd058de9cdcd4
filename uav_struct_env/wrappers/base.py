"""The base of this package's wrappers: PettingZoo's, with the space dicts of the wrapper itself.

``BaseParallelWrapper`` forwards unknown attributes to the wrapped env, so the
``observation_spaces`` / ``action_spaces`` dicts that RLlib, TorchRL and skrl read would be the
inner env's (without the keys a wrapper adds or drops). Here they are built from the wrapper's
own ``observation_space(agent)`` / ``action_space(agent)``.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils import BaseParallelWrapper

__all__ = ["ParallelWrapper"]


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
