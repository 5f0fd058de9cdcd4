"""reset(seed) + the same actions reproduce observations, infos and rewards bit for bit."""

import functools
import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from env_helpers import SMALL

import uav_struct_env

N_STEPS = 50


def _update(h, value):
    """Feed a nested structure of dicts/arrays/scalars into a hash, keys in sorted order."""
    if isinstance(value, dict):
        for k in sorted(value, key=str):
            h.update(str(k).encode())
            _update(h, value[k])
    elif isinstance(value, np.ndarray):
        h.update(str((value.dtype, value.shape)).encode())
        h.update(np.ascontiguousarray(value).tobytes())
    else:
        h.update(repr(value).encode())


def rollout_digest(seed=0, n_steps=N_STEPS, preset="train", **overrides):
    """sha256 of every reset/step output of a rollout with seeded actions."""
    env = uav_struct_env.parallel_env(preset, **overrides)
    actions_rng = np.random.default_rng(1234)
    h = hashlib.sha256()
    obs, infos = env.reset(seed=seed)
    _update(h, {"obs": obs, "infos": infos})
    for _ in range(n_steps):
        # gentle random commands: the UAVs wander but stay inside the fence for 50 steps
        actions = {a: actions_rng.uniform(-0.3, 0.3, 5).astype(np.float32) for a in env.agents}
        out = env.step(actions)
        _update(h, dict(zip(("obs", "rew", "term", "trunc", "infos"), out, strict=True)))
    if env.agents != env.possible_agents:
        raise AssertionError(f"agents died before {n_steps} steps: {env.agents}")
    env.close()
    return h.hexdigest()


CONFIG = {**SMALL, "noise": "gnss_ins"}


@functools.cache
def seed_zero_digest() -> str:
    """``rollout_digest(0, **CONFIG)`` in this process, computed once for the tests that compare with it."""
    return rollout_digest(0, **CONFIG)


def test_same_seed_same_rollout_and_seed_zero_is_a_seed():
    a = seed_zero_digest()
    assert a == rollout_digest(0, **CONFIG)  # a second env of this process
    assert a != rollout_digest(1, **CONFIG)


def test_reset_without_seed_continues_the_stream():
    env = uav_struct_env.parallel_env("train", **CONFIG)
    o1, _ = env.reset(seed=0)
    o2, _ = env.reset()
    assert not np.array_equal(o1["uav_0"]["gnss"], o2["uav_0"]["gnss"])
    o3, _ = env.reset(seed=0)
    np.testing.assert_array_equal(o1["uav_0"]["gnss"], o3["uav_0"]["gnss"])
    np.testing.assert_array_equal(o1["uav_0"]["image"], o3["uav_0"]["image"])
    env.close()


def _digest_in_fresh_process(timeout: float, **config) -> str:
    """``rollout_digest(0, **config)`` computed in a new Python process."""
    here = Path(__file__).parent
    code = (
        f"import sys; sys.path.insert(0, {str(here)!r}); "
        "from test_determinism import rollout_digest; "
        f"print(rollout_digest(0, **{config!r}))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, check=True
    )
    return out.stdout.strip().splitlines()[-1]


def test_fresh_process_reproduces_the_rollout():
    assert _digest_in_fresh_process(300, **CONFIG) == seed_zero_digest()


@pytest.mark.slow
def test_default_config_50_steps_fresh_process():
    config = {"preset": "paper", "noise": "gnss_ins"}
    assert _digest_in_fresh_process(900, **config) == rollout_digest(0, **config)
