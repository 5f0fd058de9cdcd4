"""StepInfos: what a SuperSuit vector env reports at an episode's end is that episode's final step."""

import pickle

import numpy as np
import pytest

from uav_struct_env.errors import ConfigError
from uav_struct_env.wrappers import StepInfos, make_train_env

ss = pytest.importorskip("supersuit")


def _episode_ends(env, steps=20):
    """(terminal observation's ``localized``, info's ``localization.success``) at every episode end
    of copy 0 of a SuperSuit vector env over two copies of ``env``, random actions."""
    vec = ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(env), 2, num_cpus=0,
                                base_class="stable_baselines3")
    vec.reset()
    rng = np.random.default_rng(0)
    ends = []
    for _ in range(steps):
        _, _, dones, infos = vec.step(rng.uniform(-1, 1, (vec.num_envs, 5)).astype(np.float32))
        for k in np.flatnonzero(dones):
            ends.append((bool(infos[k]["terminal_observation"]["localized"][0] > 0.5),
                         bool(infos[k]["localization"]["success"])))
    vec.close()
    return ends


def test_at_an_episode_end_the_info_is_the_final_steps_not_the_next_resets():
    ends = _episode_ends(StepInfos(make_train_env("state", max_cycles=5)))
    assert len(ends) >= 4 * 8  # 4 episode ends of 8 agent slots
    assert all(localized == success for localized, success in ends)
    # Why: without it SuperSuit merges the next episode's reset infos over the final step's
    # (measured: 18-21 of the 32 ends differ, so the check above can fail)
    plain = _episode_ends(make_train_env("state", max_cycles=5))
    assert any(localized != success for localized, success in plain)


def test_step_infos_keep_the_named_entries_and_reset_infos_are_empty():
    full = make_train_env("state", max_cycles=5)
    env = StepInfos(full, keys=("localization", "reward_terms"))
    obs, infos = env.reset(seed=3)
    assert infos == {a: {} for a in obs}
    _, _, _, _, infos = env.step({a: np.zeros(5, np.float32) for a in env.agents})
    assert {a: sorted(i) for a, i in infos.items()} == {a: ["localization", "reward_terms"] for a in obs}
    assert isinstance(infos["uav_0"]["localization"]["success"], bool)
    full.reset(seed=3)
    *_, before = full.step({a: np.zeros(5, np.float32) for a in full.agents})
    assert len(pickle.dumps(infos)) < len(pickle.dumps(before)) / 3  # what the pipes carry


def test_bad_keys_and_missing_entries_are_refused():
    with pytest.raises(ConfigError, match=r"keys must be a non-empty sequence of info key names, got 'loc"):
        StepInfos(make_train_env("state"), keys="localization")
    env = StepInfos(make_train_env("state", max_cycles=5), keys=("localization", "no_such_entry"))
    env.reset(seed=0)
    with pytest.raises(ConfigError, match=r"info of 'uav_0' has no \['no_such_entry'\]; its keys are \["):
        env.step({a: np.zeros(5, np.float32) for a in env.agents})


def test_time_limit_marks_truncations_and_not_crashes():
    env = StepInfos(make_train_env("state", max_cycles=3), time_limit=True)
    env.reset(seed=0)
    marks = []
    while env.agents:
        *_, infos = env.step({a: np.zeros(5, np.float32) for a in env.agents})
        marks.append(sorted({i["TimeLimit.truncated"] for i in infos.values()}))
    assert marks == [[False], [False], [True]]  # hovering: the episode ends at its limit
    # a crash terminates every agent (on_crash="all"): not a time limit, nothing to bootstrap
    env = StepInfos(make_train_env("state"), time_limit=True)
    env.reset(seed=0)
    down = np.array([0, 0, -1, 0, 0], np.float32)  # full descent, below the geofence's floor
    while env.agents:
        _, _, term, _, infos = env.step({a: down for a in env.agents})
    assert all(term.values()) and not any(i["TimeLimit.truncated"] for i in infos.values())
    with pytest.raises(ConfigError, match="time_limit must be True or False, got 'yes'"):
        StepInfos(make_train_env("state"), time_limit="yes")
