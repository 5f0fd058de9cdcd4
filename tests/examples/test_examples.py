"""Smoke runs of the training and evaluation examples with tiny settings."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("supersuit")

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def load(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("ppo")
    train = load("train_viewpoint_ppo")
    summary = train.main(
        out=str(out),
        total_timesteps=256,
        n_envs=1,
        num_cpus=0,
        n_steps=64,
        batch_size=64,
        n_epochs=1,
        max_cycles=8,
        checkpoint_every=128,
        progress_bar=False,
        seed=3,
    )
    return out, summary


def test_train_writes_model_normalization_logs_and_checkpoints(trained):
    out, summary = trained
    assert summary["agent_steps"] >= 256 and summary["n_agent_slots"] == 4
    for name in ("model.zip", "vecnormalize.pkl", "train.json"):
        assert (out / name).is_file(), name
    assert json.loads((out / "train.json").read_text())["options"]["seed"] == 3
    assert any((out / "checkpoints").glob("ppo_*_steps.zip"))
    assert any((out / "tb").rglob("events.out.tfevents*"))


def _record_resets(monkeypatch) -> list[tuple[int, bytes]]:
    """Make ``make_train_env`` return envs whose resets log ``(seed, first observations)``."""
    import uav_struct_env.wrappers as wrappers

    log: list[tuple[int, bytes]] = []
    make = wrappers.make_train_env

    def recording(*args, **kwargs):
        env = make(*args, **kwargs)
        reset = env.reset

        def logged_reset(*, seed=None, options=None):
            obs, infos = reset(seed=seed, options=options)
            first = b"".join(
                np.ascontiguousarray(obs[a][k]).tobytes() for a in sorted(obs) for k in sorted(obs[a])
            )
            log.append((seed, first))
            return obs, infos

        env.reset = logged_reset
        return env

    monkeypatch.setattr(wrappers, "make_train_env", recording)
    return log


def test_evaluate_compares_all_policies_on_the_same_seeds(trained, tmp_path, monkeypatch):
    out, _ = trained
    evaluate = load("evaluate_policy")
    resets = _record_resets(monkeypatch)
    summary = evaluate.main(
        model=str(out),
        episodes=2,
        max_cycles=6,
        plot=str(tmp_path / "eval.png"),
        json_out=str(tmp_path / "eval.json"),
    )
    assert set(summary["results"]) == {"ppo", "random", "hold", "orbit"}
    assert summary["seeds"] == [10_000, 10_001]
    for r in summary["results"].values():
        assert r["final_step"]["n"] == 8  # 2 episodes x 4 agents
    # Every policy started its episodes from the same seeds, in order, and so from the same
    # scenes (identical first observations); the two seeds give two different scenes.
    assert [seed for seed, _ in resets] == [10_000, 10_001] * 4
    starts = [first for _, first in resets]
    assert starts[0] != starts[1]
    assert starts == starts[:2] * 4
    assert (tmp_path / "eval.png").stat().st_size > 1000
    assert json.loads((tmp_path / "eval.json").read_text())["seeds"] == [10_000, 10_001]


def test_bad_options_are_named():
    with pytest.raises(ValueError, match="unknown options \\['episods'\\]"):
        load("evaluate_policy").main(episods=3)
    with pytest.raises(ValueError, match="needs model="):
        load("evaluate_policy").main(policies=("ppo",))
    with pytest.raises(ValueError, match="unknown options \\['lr'\\]"):
        load("train_viewpoint_ppo").main(lr=1e-3)
