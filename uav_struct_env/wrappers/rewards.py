"""Rewards as small objects, and ``RewardWrapper`` that applies one per agent and step.

A reward is any object with ``terms(frame, crashed) -> dict[str, float]`` (:class:`Reward`):
the reward is the sum of its terms, and ``info["reward_terms"]`` holds them (merged with the
terms of rewards below). ``frame`` is the agent's :class:`~uav_struct_env.stack.FrameLocalization`
of this step (from a :class:`~uav_struct_env.wrappers.localize.LocalizePoses` below), ``crashed``
whether the agent was terminated by its own geofence exit or collision (not an agent that
``on_crash="all"`` terminates for a teammate's crash, ``"teammate_crash"``). Built in:

* :class:`ErrorReward` (``"error"``, needs ground truth, simulation only): ``alive``
  (+``alive_bonus``), ``translation`` (-min(translation error, ``error_cap``)), ``rotation``
  (-min(``rotation_weight`` x rotation error in deg, ``error_cap``)) when localized, else
  ``failure`` (-``failure_penalty``);
* :class:`LogErrorReward` (``"log_error"``): the same terms, each pose-error term on a log scale
  (the same per halving of the error, steepest near zero);
* :class:`UncertaintyReward` (``"uncertainty"``, deployable, no ground truth): ``alive``,
  ``uncertainty`` (-min(predicted position RMS std = sqrt(trace of the covariance's position
  block), cap)) when localized, else ``failure``;
* both: ``crash`` (-``crash_penalty``) when the agent itself crashed.

``alive_bonus`` defaults to ``failure_penalty`` so a failed step scores 0 and a good fix scores
close to ``alive_bonus``: every step is worth at least as much as ending the episode, so a
policy never learns to crash to stop a negative reward stream (with ``on_crash="all"`` a crash
ends everyone's episode). Set ``alive_bonus=0`` for the bare "minus error" reward.

Downstream worker tracking adds its own terms: ``WorkerTracking(env, reward="tracking")``
(:mod:`~uav_struct_env.wrappers.tracking`) adds ``tracking_coverage`` and ``tracking_error``
(workers seen by at least two cameras, their triangulation error) to every agent's reward.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from localization.checks import check_choice, check_number
from uav_struct_env.envs.uav_struct import TEAMMATE_CRASH
from uav_struct_env.errors import ConfigError
from uav_struct_env.stack import FrameLocalization
from uav_struct_env.wrappers.base import ParallelWrapper, find_wrapper
from uav_struct_env.wrappers.localize import LocalizePoses

__all__ = [
    "REWARDS",
    "AnchorReward",
    "ErrorReward",
    "Reward",
    "RewardWrapper",
    "UncertaintyReward",
    "make_reward",
]


@runtime_checkable
class Reward(Protocol):
    """Anything with ``terms(frame, crashed) -> dict[str, float]``; the reward is their sum."""

    def terms(self, frame: FrameLocalization, crashed: bool) -> dict[str, float]:
        """The reward's terms for one agent and step."""
        ...


def _nonneg(name: str, value: Any) -> float:
    return check_number(name, value, 0.0, error=ConfigError, type_error=ConfigError)


class AnchorReward:
    """The shared part of the built-in rewards: ``alive``, ``failure`` and ``crash`` terms.

    Subclasses add the terms of a successful localization in :meth:`quality_terms`.

    Args:
        failure_penalty: subtracted when localization fails (>= 0).
        error_cap: cap on each quality term; default ``failure_penalty`` (a bad fix never
            scores below a failure).
        alive_bonus: constant term per step; default ``failure_penalty``.
        crash_penalty: subtracted when the agent is terminated.
    """

    def __init__(
        self,
        *,
        failure_penalty: float = 1.0,
        error_cap: float | None = None,
        alive_bonus: float | None = None,
        crash_penalty: float = 1.0,
    ) -> None:
        self.failure_penalty = _nonneg("failure_penalty", failure_penalty)
        self.error_cap = _nonneg("error_cap", failure_penalty if error_cap is None else error_cap)
        self.alive_bonus = _nonneg("alive_bonus", failure_penalty if alive_bonus is None else alive_bonus)
        self.crash_penalty = _nonneg("crash_penalty", crash_penalty)

    def quality_terms(self, frame: FrameLocalization) -> dict[str, float]:
        """The terms of a successful localization (none here)."""
        return {}

    def terms(self, frame: FrameLocalization, crashed: bool) -> dict[str, float]:
        """``alive``, then the quality terms or ``failure``, then ``crash`` when crashed."""
        out = {"alive": self.alive_bonus}
        if not frame.estimate.success:
            out["failure"] = -self.failure_penalty
        else:
            out.update(self.quality_terms(frame))
        if crashed:
            out["crash"] = -self.crash_penalty
        return out


class ErrorReward(AnchorReward):
    """Minus the capped pose error (ground truth: simulation only); see the module docstring.

    Args:
        rotation_weight: metres of reward per degree of rotation error.
        **kwargs: :class:`AnchorReward` arguments.
    """

    name = "error"

    def __init__(self, *, rotation_weight: float = 0.1, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.rotation_weight = _nonneg("rotation_weight", rotation_weight)

    def error_term(self, x: float) -> float:
        """The term of an error ``x`` (m, or ``rotation_weight`` x deg): ``-min(x, error_cap)``."""
        return -min(x, self.error_cap)

    def quality_terms(self, frame: FrameLocalization) -> dict[str, float]:
        """``translation`` and ``rotation``, each :meth:`error_term` of its error."""
        return {
            "translation": self.error_term(frame.translation_error_m),
            "rotation": self.error_term(self.rotation_weight * frame.rotation_error_deg),
        }


class LogErrorReward(ErrorReward):
    """:class:`ErrorReward` with each pose-error term on a log scale: the same per halving.

    ``-error_cap * min(log1p(x / scale_m) / log1p(error_cap / scale_m), 1)`` for ``x`` the
    translation error (m) and ``rotation_weight`` x the rotation error (deg): 0 at no error and
    ``-error_cap`` from ``error_cap`` metres on, as the linear terms, but near zero about 22 times
    steeper (``scale_m`` = 1 cm, cap 1 m): 0.015 -> 0.030 m costs 0.10 per step instead of 0.015,
    so that a policy is paid for ending closer to the building where every fix is centimetres.

    Args:
        scale_m: the error (m) below which a term is nearly linear (> 0).
        **kwargs: :class:`ErrorReward` arguments.
    """

    name = "log_error"

    def __init__(self, *, scale_m: float = 0.01, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.scale_m = check_number("scale_m", scale_m, 0.0, lo_open=True, error=ConfigError)

    def error_term(self, x: float) -> float:
        """The term of an error ``x`` on the log scale (the class docstring)."""
        if self.error_cap == 0.0:
            return 0.0
        s = self.scale_m
        return -self.error_cap * min(float(np.log1p(x / s) / np.log1p(self.error_cap / s)), 1.0)


class UncertaintyReward(AnchorReward):
    """Minus the capped predicted position std (deployable, no ground truth)."""

    name = "uncertainty"

    def quality_terms(self, frame: FrameLocalization) -> dict[str, float]:
        """``uncertainty``."""
        std = float(np.sqrt(max(np.trace(frame.estimate.covariance[:3, :3]), 0.0)))
        return {"uncertainty": -min(std if np.isfinite(std) else self.error_cap, self.error_cap)}


#: Built-in rewards by name.
REWARDS: dict[str, type[AnchorReward]] = {
    "error": ErrorReward, "log_error": LogErrorReward, "uncertainty": UncertaintyReward,
}


def make_reward(reward: str | Reward, **kwargs: Any) -> Reward:
    """A reward object from a name of :data:`REWARDS` (with its arguments) or a :class:`Reward`.

    ``rotation_weight`` applies to ``"error"`` and ``"log_error"`` only and is ignored by the others.
    """
    if not isinstance(reward, str):
        if not isinstance(reward, Reward):
            raise ConfigError(
                f"reward must be one of {tuple(REWARDS)} or an object with terms(frame, crashed), "
                f"got {reward!r}"
            )
        return reward
    check_choice("reward", reward, tuple(REWARDS), error=ConfigError)
    if not issubclass(REWARDS[reward], ErrorReward):
        kwargs.pop("rotation_weight", None)
    return REWARDS[reward](**kwargs)


class RewardWrapper(ParallelWrapper):
    """Set each agent's reward to the sum of ``reward``'s terms; terms go to ``info``.

    Args:
        env: a wrapper chain that contains a :class:`LocalizePoses`.
        reward: a :class:`Reward` object or a name of :data:`REWARDS` (default arguments).

    Raises:
        ConfigError: for an unknown reward or without a :class:`LocalizePoses` below.
    """

    def __init__(self, env: Any, reward: str | Reward = "error") -> None:
        super().__init__(env)
        self._loc = find_wrapper(env, LocalizePoses)
        if self._loc is None:
            raise ConfigError("RewardWrapper needs a LocalizePoses wrapper below it")
        self.reward = make_reward(reward)

    def step(self, actions: dict[str, Any]):
        """Step the env and compute every agent's reward from its terms."""
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        for agent in obs:
            terms = dict(infos[agent].get("reward_terms", {}))
            crashed = bool(terminations.get(agent, False)) and (
                infos[agent].get("termination_reason") != TEAMMATE_CRASH
            )
            terms.update(self.reward.terms(self._loc.last_frames[agent], crashed))
            infos[agent]["reward_terms"] = terms
            rewards[agent] = float(sum(terms.values()))
        return obs, rewards, terminations, truncations, infos
