"""The vector env runs the same episodes as K single envs, autoresets as documented, refuses bad input."""

from __future__ import annotations

import numpy as np
import pytest

import uav_struct_env
from uav_struct_env.errors import ConfigError, ResetNeededError
from uav_struct_env.vector import FINAL_OBSERVATION, ParallelVectorEnv, make_vector_env
from uav_struct_env.wrappers import make_train_env

pytestmark = pytest.mark.filterwarnings("ignore:The `render_mode` attribute is not defined")

K, SEED, STEPS = 3, 7, 36  # 36 steps of 30-step episodes: every env autoresets once
OVERRIDES = {"max_cycles": 30}


def numbers(tree, prefix=""):
    """Every numeric leaf of a nested info dict as ``{path: array}`` (strings and None left out)."""
    out = {}
    items = tree.items() if isinstance(tree, dict) else []
    for key, value in items:
        path = f"{prefix}/{key}"
        if isinstance(value, dict):
            out.update(numbers(value, path))
        elif value is not None and np.asarray(value).dtype.kind in "biuf":
            out[path] = np.asarray(value)
    return out


def assert_same(a, b, what):
    na, nb = numbers(a), numbers(b)
    assert na.keys() == nb.keys(), what
    for key in na:
        np.testing.assert_array_equal(na[key], nb[key], err_msg=f"{what}: {key}")


def single_trajectory(k, actions, site):
    """Env ``k`` alone: reset with SEED + k, stepped with its rows of ``actions``, reset on its end."""
    env = make_train_env("state", site=site, texture_seed=k, **OVERRIDES)
    agents = env.possible_agents
    obs, _ = env.reset(seed=SEED + k)
    steps = [(obs, None)]
    for t in range(len(actions)):
        rows = actions[t][k * len(agents):(k + 1) * len(agents)]
        obs, rew, term, trunc, info = env.step(dict(zip(agents, rows, strict=True)))
        final = None
        if not env.agents:
            final, (obs, _) = obs, env.reset()
        steps.append((obs, (rew, term, trunc, info, final)))
    env.close()
    return steps


def test_k_envs_run_the_trajectories_of_k_single_envs():
    rng = np.random.default_rng(0)
    sites = ["paper", "random", "random"]  # the two random envs draw different sites
    vec = make_vector_env("state", K, site=sites, **OVERRIDES)
    A = vec.agents_per_env
    actions = [rng.uniform(-1, 1, (K * A, 5)).astype(np.float32) for _ in range(STEPS)]
    obs, _ = vec.reset(seed=SEED)
    got = [(obs, None)]
    for a in actions:
        obs, rew, term, trunc, info = vec.step(a)
        got.append((obs, (rew, term, trunc, info)))
    vec.close()
    ends = 0
    for k in range(K):
        for t, (s_obs, s_step) in enumerate(single_trajectory(k, actions, sites[k])):
            v_obs, v_step = got[t]
            for i, agent in enumerate(vec.possible_agents):
                slot = k * A + i
                for key, value in s_obs[agent].items():
                    np.testing.assert_array_equal(v_obs[key][slot], value, err_msg=f"env {k} t {t} {key}")
                if s_step is None:
                    continue
                rew, term, trunc, info, final = s_step
                assert v_step[0][slot] == np.float32(rew[agent])
                assert (v_step[1][slot], v_step[2][slot]) == (term[agent], trunc[agent])
                v_info = dict(v_step[3][slot])
                v_final = v_info.pop(FINAL_OBSERVATION, None)
                assert_same(v_info, info[agent], f"env {k} t {t} {agent} info")
                assert (v_final is None) == (final is None)
                if final is not None:
                    ends += 1
                    assert_same(v_final, final[agent], f"env {k} t {t} {agent} final observation")
    assert ends >= K * A  # every env ended an episode (crash or the 30-step limit) and went on


def test_slots_are_env_major_and_sites_differ():
    vec = make_vector_env("state", 2, site="random")
    assert vec.num_slots == 8 and vec.slot(1, "uav_2") == 6
    sites = [env.unwrapped.site for env in vec.envs]
    assert sites[0].landmarks("column_tops").xyz.tolist() != sites[1].landmarks("column_tops").xyz.tolist()
    obs, infos = vec.reset(seed=0)
    assert obs["gnss"].shape == (8, 3) and len(infos) == 8
    vec.close()


def test_bad_input_is_refused_with_the_value():
    with pytest.raises(ConfigError, match="non-empty sequence of env constructors"):
        ParallelVectorEnv([])
    with pytest.raises(ConfigError, match=r"one site per env \(2\)"):
        make_vector_env("state", 2, site=["paper"])
    vec = make_vector_env("state", 1)
    with pytest.raises(ResetNeededError, match="before reset"):
        vec.step(np.zeros((4, 5)))
    vec.reset(seed=0)
    with pytest.raises(ConfigError, match=r"one row per slot \(4\), got shape \(3, 5\)"):
        vec.step(np.zeros((3, 5)))
    with pytest.raises(ConfigError, match="seed must be None or an int >= 0, got -1"):
        vec.reset(seed=-1)
    vec.close()


def test_agents_that_leave_one_by_one_are_refused():
    def paper():
        return uav_struct_env.parallel_env("paper", observe_image=False, max_cycles=100)

    vec = ParallelVectorEnv([paper])
    assert vec.envs[0].unwrapped.config.on_crash == "agent"
    vec.reset(seed=0)
    # uav_0 climbs out of the geofence at full speed; the others hover
    actions = np.zeros((4, 5), np.float32)
    actions[0] = 1.0
    with pytest.raises(ConfigError, match="every agent to finish together"):
        for _ in range(100):
            vec.step(actions)
