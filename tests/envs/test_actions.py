"""Action validation: bad actions raise ValueError naming the agent and the value."""

import numpy as np
import pytest
from env_helpers import small_parallel_env

from uav_struct_env.sim.uav import UavState


@pytest.fixture(scope="module")
def env():
    env = small_parallel_env(landmark_sets=(), on_crash="agent")
    yield env
    env.close()


@pytest.fixture
def fresh(env):
    env.reset(seed=0)
    return env


GOOD = np.zeros(5, np.float32)


@pytest.mark.parametrize(
    ("action", "match"),
    [
        (np.array([np.nan, 0, 0, 0, 0], np.float32), r"'uav_1' must be finite, got \[nan"),
        (np.array([0, 0, np.inf, 0, 0]), r"'uav_1' must be finite, got \[0.0, 0.0, inf"),
        (np.zeros(4, np.float32), r"'uav_1' must have shape \(5,\).*got shape \(4,\)"),
        (np.zeros((1, 5), np.float32), r"'uav_1' must have shape \(5,\).*got shape \(1, 5\)"),
        (np.array(["a"] * 5), r"'uav_1' must be a real numeric array.*dtype <U1"),
        (np.zeros(5, bool), r"'uav_1' must be a real numeric array.*dtype bool"),
        (np.zeros(5, complex), r"'uav_1' must be a real numeric array.*dtype complex128"),
        (None, r"'uav_1' must be a real numeric array.*got None"),
        ("up", r"'uav_1' must be a real numeric array.*got 'up'"),
    ],
)
def test_bad_action_raises_naming_agent_and_value(fresh, action, match):
    with pytest.raises(ValueError, match=match):
        fresh.step({"uav_0": GOOD, "uav_1": action})


def test_bad_action_moves_nothing(fresh):
    before = {a: fresh.uav_state(a) for a in fresh.agents}
    with pytest.raises(ValueError):
        fresh.step({"uav_0": np.ones(5, np.float32), "uav_1": np.full(5, np.nan)})
    assert {a: fresh.uav_state(a) for a in fresh.agents} == before
    assert fresh.num_cycles == 0


def test_unknown_agent(fresh):
    with pytest.raises(ValueError, match=r"unknown agent 'uav_7'"):
        fresh.step({"uav_7": GOOD})


def test_finished_agent(fresh):
    fresh._states["uav_2"] = UavState.make([0.0, 0.0, 130.0], 0.0, 0.5)  # above the fence
    _, _, term, _, info = fresh.step({})
    assert term["uav_2"] and info["uav_2"]["termination_reason"] == "above_max_altitude"
    assert "uav_2" not in fresh.agents
    with pytest.raises(ValueError, match=r"finished agent 'uav_2'.*got action array\(\[0"):
        fresh.step({"uav_2": GOOD})


def test_wrong_container(fresh):
    with pytest.raises(ValueError, match="actions must be a dict"):
        fresh.step([GOOD] * 4)


def test_out_of_range_is_clipped_and_ints_and_lists_accepted(env):
    env.reset(seed=3)
    env.step({a: np.array([9.0, -9.0, 3.0, 2.0, -7.0]) for a in env.agents})
    clipped = {a: env.uav_state(a) for a in env.agents}
    env.reset(seed=3)
    env.step({a: [1, -1, 1, 1, -1] for a in env.agents})
    assert {a: env.uav_state(a) for a in env.agents} == clipped


def test_missing_agents_hover(env):
    env.reset(seed=4)
    before = env.uav_state("uav_3")
    env.step({"uav_0": GOOD})
    assert env.uav_state("uav_3") == before
