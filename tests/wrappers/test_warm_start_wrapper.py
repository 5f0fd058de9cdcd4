"""The wrapper's warm start: each frame's association starts from the previous estimate moved by
the commanded action; the poses are those of the full search wherever both localize."""

import numpy as np
import pytest

from uav_struct_env.errors import ConfigError
from uav_struct_env.wrappers import TRAIN_CONFIGS, LocalizationWrapper, make_localization_env, make_train_env


def _flight(warm: bool, seed: int, steps: int = 12):
    """Per step and agent: (success, warm_started, pose obs) of a seeded random flight."""
    config = TRAIN_CONFIGS["state"].replace(wrapper={"warm_start": warm}, env={"max_cycles": steps})
    env = make_train_env(config)
    rng = np.random.default_rng(seed)
    obs, infos = env.reset(seed=seed)
    out = [{a: (infos[a]["localization"]["success"], infos[a]["localization"]["warm_started"],
                obs[a]["pose"]) for a in obs}]
    while env.agents:
        # slow turns and drifts: the views change, the layout stays in sight
        acts = {a: (0.3 * rng.uniform(-1, 1, 5)).astype(np.float32) for a in env.agents}
        obs, _, _, _, infos = env.step(acts)
        out.append({a: (infos[a]["localization"]["success"], infos[a]["localization"]["warm_started"],
                        obs[a]["pose"]) for a in obs})
    env.close()
    return out


def test_training_configs_warm_start_and_match_the_full_search():
    assert all(c.wrapper["warm_start"] for c in TRAIN_CONFIGS.values())
    warm_steps = searched_after_success = 0
    for seed in (3, 4):
        warm, full = _flight(True, seed), _flight(False, seed)
        assert len(warm) == len(full)
        assert not any(w for _, w, _ in warm[0].values())  # nothing to start from at reset
        for t, (ws, fs) in enumerate(zip(warm, full, strict=True)):
            for agent, (ok_w, started, pose_w) in ws.items():
                ok_f, started_f, pose_f = fs[agent]
                assert not started_f
                assert ok_w or not ok_f, (seed, t, agent)  # never loses a pose the search finds
                if ok_w and ok_f:  # the same pairs, so the same pose (float32 observation)
                    np.testing.assert_allclose(pose_w, pose_f, atol=2e-5)
                if t and warm[t - 1].get(agent, (False,))[0]:
                    warm_steps += started
                    searched_after_success += not started
    # most frames after a pose are answered by the warm start (34 of 44 here; the rest saw a
    # column top enter or leave the image, which the full search then handled)
    assert warm_steps >= 30 and warm_steps >= 0.7 * (warm_steps + searched_after_success)


def test_warm_start_flag_is_checked():
    env = make_localization_env("column_tops", env_overrides={"max_cycles": 4, "observe_image": False})
    with pytest.raises(ConfigError, match="warm_start must be True or False, got 'yes'"):
        LocalizationWrapper(env.unwrapped, warm_start="yes")


def test_the_warm_start_benchmark_compares_every_warm_frame_with_the_full_search(load_script, capsys):
    from pathlib import Path

    from uav_struct_env.stack import LocalizationStack

    bench = load_script(Path(__file__).resolve().parents[2] / "benchmarks" / "warm_start.py")
    before = LocalizationStack.localize
    out = bench.main(policy="hold", steps=240, seed=1)
    assert LocalizationStack.localize is before  # the comparison is undone
    assert 0 < out["answered"] <= out["frames"] and out["warm_wrong"] == out["full_wrong"] == 0
    assert out["full_success"] <= out["warm_success"] <= out["frames"]
    assert out["same"] >= out["full_success"] - len(out["differ"]) and out["max_pose_gap_m"] < 1e-4
    assert "answered by it (no search)" in capsys.readouterr().out


def test_the_warm_start_works_beside_the_pose_filter():
    config = TRAIN_CONFIGS["state"].replace(wrapper={"temporal": True}, env={"max_cycles": 6})
    poses = {}
    for warm in (True, False):
        env = make_train_env(config.replace(wrapper={"warm_start": warm}))
        obs, infos = env.reset(seed=2)
        started = []
        while env.agents:
            obs, _, _, _, infos = env.step({a: np.zeros(5, np.float32) for a in env.agents})
            started += [infos[a]["localization"]["warm_started"] for a in obs]
            assert all("filtered_translation_error_m" in infos[a]["localization"] for a in obs)
        poses[warm] = {a: obs[a]["pose"] for a in obs}
        assert any(started) == warm
        env.close()
    for agent, pose in poses[True].items():  # the same fixes, so the same filtered poses
        np.testing.assert_allclose(pose, poses[False][agent], atol=2e-5)
