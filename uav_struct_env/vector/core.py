"""``ParallelVectorEnv``: K PettingZoo parallel envs stepped in one process, each agent a slot.

The K envs (copies of one configuration, with their own seeds and sites) must share their
agents' observation and action spaces. Every agent of every env is one *slot*, env-major:
slot ``k * A + i`` is agent ``possible_agents[i]`` of env ``k`` (``A`` agents per env), as in
SuperSuit's markov vector env. Observations come back stacked per key, ``(K * A, ...)``.

Seeds: ``reset(seed=s)`` resets env ``k`` with seed ``s + k``; ``reset(seed=None)`` and every
automatic reset continue each env's own generator (the env's ``reset(seed=None)``), so a vector
env and K single envs reset with ``s + k`` and then with None run the same episodes.

Autoreset (same step, SB3's and SuperSuit's convention): when env ``k``'s episode ends (all of
its agents terminated or truncated, which the env's ``on_crash="all"`` makes happen together), the
step that ends it returns, for each of its slots,

* ``terminations`` / ``truncations``: the final step's;
* ``infos[slot]``: the final step's info, plus ``"final_observation"``: the episode's last
  observation of that agent;
* the observation: the first observation of the next episode (the env was reset in that step);
  its reset info is in :attr:`ParallelVectorEnv.reset_infos` ``[slot]``.

An env whose agents end one by one (``on_crash="agent"``) cannot fill its slots and is refused.

:meth:`ParallelVectorEnv.step_envs` is the one place where the K envs step (and so render their
cameras, through the env as today): a batched renderer that draws every camera of every env in
one call belongs there.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from uav_struct_env.errors import ConfigError, ResetNeededError

__all__ = ["FINAL_OBSERVATION", "ParallelVectorEnv"]

#: The info key of an episode's last observation, in the info of the step that ended it.
FINAL_OBSERVATION = "final_observation"

StepResult = tuple[dict, dict, dict, dict, dict]
#: ``(obs, rewards, terminations, truncations, infos)`` of :meth:`ParallelVectorEnv.step`.
VectorStep = tuple[Any, np.ndarray, np.ndarray, np.ndarray, list[dict]]


def _same_spaces(envs: Sequence[Any]) -> tuple[list[str], Any, Any]:
    """The shared agents and spaces of ``envs``; ConfigError where they differ."""
    first = envs[0]
    agents = list(first.possible_agents)
    obs_space = first.observation_space(agents[0])
    act_space = first.action_space(agents[0])
    for k, env in enumerate(envs):
        if list(env.possible_agents) != agents:
            raise ConfigError(
                f"every env of a vector env needs the agents {agents}, env {k} has {env.possible_agents}"
            )
        for agent in agents:
            if env.observation_space(agent) != obs_space or env.action_space(agent) != act_space:
                raise ConfigError(
                    f"every agent of every env needs the same spaces; env {k}'s {agent!r} has "
                    f"{env.observation_space(agent)} / {env.action_space(agent)}, expected "
                    f"{obs_space} / {act_space}"
                )
    return agents, obs_space, act_space


class ParallelVectorEnv:
    """K parallel envs in one process, agents as slots (see the module docstring).

    Args:
        env_fns: one callable per env, each returning a PettingZoo ``ParallelEnv`` (a wrapped
            ``uav_struct_v0`` env, e.g. ``lambda: make_train_env("state")``).

    Attributes:
        envs: the K envs, in slot order.
        possible_agents: the agents of every env.
        num_envs: K.
        num_slots: K times the agents per env.
        reset_infos: per slot, the info of its env's last reset (an autoreset's included).

    Raises:
        ConfigError: no env, or envs whose agents or spaces differ.
    """

    def __init__(self, env_fns: Sequence[Callable[[], Any]]) -> None:
        if isinstance(env_fns, (str, bytes)) or not env_fns or not all(callable(f) for f in env_fns):
            raise ConfigError(f"env_fns must be a non-empty sequence of env constructors, got {env_fns!r}")
        self.envs = [fn() for fn in env_fns]
        self.possible_agents, self.observation_space, self.action_space = _same_spaces(self.envs)
        self.num_envs = len(self.envs)
        self.agents_per_env = len(self.possible_agents)
        self.num_slots = self.num_envs * self.agents_per_env
        self.reset_infos: list[dict] = [{} for _ in range(self.num_slots)]
        self._was_reset = False

    def slot(self, env_index: int, agent: str) -> int:
        """The slot of ``agent`` of env ``env_index``."""
        return env_index * self.agents_per_env + self.possible_agents.index(agent)

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, list[dict]]:
        """Reset every env (env ``k`` with ``seed + k``); stacked observations and per-slot infos."""
        bad = isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0
        if seed is not None and bad:
            raise ConfigError(f"seed must be None or an int >= 0, got {seed!r}")
        results = [
            env.reset(seed=None if seed is None else int(seed) + k, options=options)
            for k, env in enumerate(self.envs)
        ]
        obs = [o for o, _ in results]
        self.reset_infos = self._per_slot([i for _, i in results])
        self._was_reset = True
        return self._stack(obs), [dict(i) for i in self.reset_infos]

    def step(self, actions: Any) -> VectorStep:
        """Step every env with ``actions`` (one row per slot); autoreset the envs whose episode ended.

        Returns:
            ``(obs, rewards, terminations, truncations, infos)``: observations stacked per key
            ``(num_slots, ...)``, float32 rewards and bool flags ``(num_slots,)``, per-slot infos
            (autoreset: module docstring).

        Raises:
            ResetNeededError: before the first :meth:`reset`.
            ConfigError: ``actions`` without one row per slot, or an env whose agents did not
                all finish together.
        """
        if not self._was_reset:
            raise ResetNeededError("step() before reset(): call reset(seed=...) first")
        actions = np.asarray(actions)
        if actions.ndim == 0 or len(actions) != self.num_slots:
            raise ConfigError(
                f"actions must have one row per slot ({self.num_slots}), got shape {actions.shape}"
            )
        n = self.agents_per_env
        per_env = [
            dict(zip(self.possible_agents, actions[k * n:(k + 1) * n], strict=True))
            for k in range(self.num_envs)
        ]
        results = self.step_envs(per_env)
        return self._collect(results)

    def step_envs(self, actions: list[dict[str, Any]]) -> list[StepResult]:
        """Step env ``k`` with ``actions[k]``: the K envs' ``step`` results, in order.

        Every env renders its own cameras inside its step here; this is the seam where a batched
        renderer draws the step's cameras of all K envs in one call.
        """
        return [env.step(a) for env, a in zip(self.envs, actions, strict=True)]

    def _collect(self, results: list[StepResult]) -> VectorStep:
        n = self.num_slots
        rewards = np.zeros(n, np.float32)
        terminations = np.zeros(n, bool)
        truncations = np.zeros(n, bool)
        infos: list[dict] = []
        observations = []
        for k, (obs, rew, term, trunc, info) in enumerate(results):
            self._check_complete(k, obs)
            base = k * self.agents_per_env
            for i, agent in enumerate(self.possible_agents):
                rewards[base + i] = rew[agent]
                terminations[base + i] = term[agent]
                truncations[base + i] = trunc[agent]
                infos.append(info[agent])
            if not self.envs[k].agents:  # the episode ended: keep its last observation, reset
                for i, agent in enumerate(self.possible_agents):
                    infos[base + i][FINAL_OBSERVATION] = obs[agent]
                obs, reset_info = self.envs[k].reset()
                for i, agent in enumerate(self.possible_agents):
                    self.reset_infos[base + i] = reset_info[agent]
            observations.append(obs)
        return self._stack(observations), rewards, terminations, truncations, infos

    def _check_complete(self, k: int, obs: dict) -> None:
        left = self.envs[k].agents
        if len(obs) != self.agents_per_env or (left and len(left) != self.agents_per_env):
            raise ConfigError(
                f"env {k} returned observations of {sorted(obs)} and goes on with {left}, not with "
                f"all its agents {self.possible_agents}: a vector env needs every agent to finish together "
                f"{self.possible_agents}: a vector env needs every agent to finish together "
                "(build the env with on_crash='all', as every training configuration does)"
            )

    def _per_slot(self, per_env: list[dict]) -> list[dict]:
        return [per_env[k][agent] for k in range(self.num_envs) for agent in self.possible_agents]

    def _stack(self, per_env: list[dict]) -> dict[str, np.ndarray] | np.ndarray:
        """Observations of every slot stacked: per key for Dict observations, else one array."""
        rows = [o[agent] for o in per_env for agent in self.possible_agents]
        if isinstance(rows[0], dict):
            return {key: np.stack([r[key] for r in rows]) for key in rows[0]}
        return np.stack(rows)

    def close(self) -> None:
        """Close every env."""
        for env in self.envs:
            env.close()
