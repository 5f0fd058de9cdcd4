"""Smoke runs of the training and evaluation examples with tiny settings."""

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("supersuit")

from uav_struct_env.errors import ConfigError, UsageError  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture(scope="module")
def example(load_script):
    """``example(name)``: ``examples/<name>.py`` as a fresh module."""
    return lambda name: load_script(EXAMPLES / f"{name}.py")


@pytest.fixture(scope="module")
def trained(tiny_ppo_run):
    """``(out, summary)``: 256 agent-steps, seed 3, checkpoints every 128 (tests/conftest.py)."""
    return tiny_ppo_run


def test_train_writes_model_normalization_logs_and_checkpoints(trained):
    out, summary = trained
    assert summary["agent_steps"] >= 256 and summary["n_agent_slots"] == 4
    for name in ("model.zip", "normalization.npz", "vecnormalize.pkl", "train.json"):
        assert (out / name).is_file(), name
    record = json.loads((out / "train.json").read_text())
    assert record["options"]["seed"] == 3
    # the run carries what its --config meant then, and the code that trained it
    from uav_struct_env.wrappers import TRAIN_CONFIGS

    assert record["train_config"]["wrapper"] == TRAIN_CONFIGS["state"].wrapper
    assert record["train_config"]["wrapper"]["association"] == "robust"  # the training default
    assert record["train_config"]["env"]["max_cycles"] == 8  # --max-cycles, as trained
    assert record["software"]["package"] == "uav-struct-env" and record["software"]["version"]
    steps = sorted(d.name for d in (out / "checkpoints").glob("step_*"))
    assert steps == ["step_000000128", "step_000000256"]
    for d in steps:  # model folders the evaluator reads without unpickling
        assert {f.name for f in (out / "checkpoints" / d).iterdir()} == {
            "model.zip", "normalization.npz", "vecnormalize.pkl", "resume.npz"}
    rows = [json.loads(line) for line in (out / "progress.jsonl").read_text().splitlines()]
    assert [r["agent_steps"] for r in rows] == [128, 256]  # two rollouts of 32 steps x 4 slots
    assert rows[-1]["agent_steps"] >= 256 and rows[-1]["episode_return_mean"] is not None
    # where the wall clock went: each rollout, and the update between the two
    assert rows[0]["update_s"] is None and rows[1]["update_s"] > 0
    assert all(r["rollout_s"] > 0 for r in rows)
    assert record["collect_s"] == pytest.approx(sum(r["rollout_s"] for r in rows), abs=2e-3)
    assert record["update_total_s"] == pytest.approx(rows[1]["update_s"], abs=1e-3)
    assert record["collect_s"] + record["update_total_s"] <= record["wall_clock_s"]
    assert 0.0 <= rows[-1]["final_success_rate"] <= 1.0
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


def test_evaluate_compares_all_policies_on_the_same_seeds(example, trained, tmp_path, monkeypatch):
    out, _ = trained
    evaluate = example("evaluate_policy")
    resets = _record_resets(monkeypatch)
    summary = evaluate.main(
        model=str(out),
        episodes=2,
        max_cycles=2,
        plot=str(tmp_path / "eval.png"),
        json_out=str(tmp_path / "eval.json"),
    )
    assert set(summary["results"]) == {"ppo", "random", "hold", "orbit", "greedy"}
    assert summary["seeds"] == [10_000, 10_001]
    for r in summary["results"].values():
        assert r["final_step"]["n"] == 8  # 2 episodes x 4 agents
    # Every policy started its episodes from the same seeds, in order, and so from the same
    # scenes (identical first observations); the two seeds give two different scenes.
    assert [seed for seed, _ in resets] == [10_000, 10_001] * 5
    starts = [first for _, first in resets]
    assert starts[0] != starts[1]
    assert starts == starts[:2] * 5
    assert (tmp_path / "eval.png").stat().st_size > 1000
    assert json.loads((tmp_path / "eval.json").read_text())["seeds"] == [10_000, 10_001]


def test_evaluate_builds_the_env_each_run_recorded(example, trained, tmp_path):
    """A run is evaluated in the configuration it recorded, not in what its name means today."""
    out, _ = trained
    evaluate = example("evaluate_policy")
    old = tmp_path / "trained_with_paper"
    shutil.copytree(out, old)
    record = json.loads((old / "train.json").read_text())
    record["train_config"]["wrapper"]["association"] = "paper"
    (old / "train.json").write_text(json.dumps(record))
    summary = evaluate.main(model=str(old), policies=("ppo",), episodes=1)
    assert summary["env_config"]["wrapper"]["association"] == "paper"
    assert summary["env_config"]["env"]["max_cycles"] == 8  # as trained, not the config's 30
    over = evaluate.main(model=str(old), policies=("ppo",), episodes=1, association="robust", max_cycles=2)
    assert over["env_config"]["wrapper"]["association"] == "robust"
    assert over["env_config"]["env"]["max_cycles"] == 2
    # a checkpoint folder finds its run's train.json two levels up
    step = sorted((old / "checkpoints").glob("step_*"))[0]
    from_step = evaluate.main(model=str(step), policies=("ppo",), episodes=1, max_cycles=2)
    assert from_step["env_config"]["wrapper"]["association"] == "paper"
    with pytest.raises(UsageError, match="trained in different configurations.*evaluate them separately"):
        evaluate.main(model=[str(out), str(old)], policies=("ppo",), episodes=1)
    # both, under one named configuration
    both = evaluate.main(model=[str(out), str(old)], policies=("ppo",), episodes=1, config="state",
                         max_cycles=2)
    assert both["env_config"]["wrapper"]["association"] == "robust"
    with pytest.raises(ConfigError, match="association must be 'paper' or 'robust', got 'best'"):
        evaluate.main(model=str(out), policies=("ppo",), episodes=1, association="best")
    # a run from before the configuration was recorded: the named one as it is now
    del record["train_config"]
    (old / "train.json").write_text(json.dumps(record))
    unrecorded = evaluate.main(model=str(old), policies=("ppo",), episodes=1, max_cycles=2)
    assert unrecorded["env_config"]["name"] == "state"
    assert unrecorded["env_config_source"].startswith("the runs recorded no configuration")
    # with a recorded run, in its configuration, and the source names the run that recorded none
    mixed = evaluate.main(model=[str(out), str(old)], policies=("ppo",), episodes=1, max_cycles=2)
    assert mixed["env_config"]["wrapper"]["association"] == "robust"
    assert mixed["env_config_source"] == (f"recorded by the run(s) in train.json; {old} recorded none "
                                          "and are evaluated in it too")
    (old / "train.json").write_text("{not json")
    with pytest.raises(UsageError, match="is not a train.json written by train_viewpoint_ppo.py"):
        evaluate.main(model=str(old), policies=("ppo",), episodes=1)


def test_train_config_round_trips_through_json():
    from uav_struct_env.wrappers import TRAIN_CONFIGS, TrainConfig

    for config in TRAIN_CONFIGS.values():
        back = TrainConfig.from_dict(json.loads(json.dumps(config.as_dict())))
        assert back == config and isinstance(back.env["image_size"], tuple)
    with pytest.raises(ConfigError, match="must be a mapping with keys"):
        TrainConfig.from_dict({"name": "state", "env": {}})


def test_several_training_runs_are_evaluated_and_pooled_with_their_spread(example, trained, tmp_path):
    out, _ = trained
    runs = [tmp_path / "seed_a", tmp_path / "seed_b"]
    for run in runs:  # the same weights twice: the spread across runs must be zero
        shutil.copytree(out, run)
    evaluate = example("evaluate_policy")
    summary = evaluate.main(model=[str(r) for r in runs], policies=("ppo", "hold"), episodes=1,
                            max_cycles=3)
    res = summary["results"]
    assert list(res) == ["ppo:seed_a", "ppo:seed_b", "ppo", "hold"]
    assert res["ppo"]["final_step"]["n"] == 8 and res["ppo:seed_a"]["final_step"]["n"] == 4
    spread = res["ppo"]["across_runs"]
    assert spread["success_rate"]["runs"] == 2 and spread["success_rate"]["std"] == 0.0
    assert spread["success_rate"]["mean"] == res["ppo:seed_a"]["final_step"]["success_rate"]
    # distances to the building centre: the same starts for every policy; hold barely moves
    starts = {n: r["start_distance_median_m"] for n, r in res.items()}
    assert len(set(starts.values())) == 1 and 5.0 < starts["hold"] < 100.0
    assert abs(res["hold"]["end_distance_median_m"] - starts["hold"]) < 1.0
    with pytest.raises(ValueError, match="distinct names"):
        evaluate.main(model=[str(runs[0]), str(runs[0])], policies=("ppo",), episodes=1, max_cycles=2)


def test_bad_options_are_named(example):
    with pytest.raises(ValueError, match="unknown options \\['episods'\\]"):
        example("evaluate_policy").main(episods=3)
    with pytest.raises(ValueError, match="needs model="):
        example("evaluate_policy").main(policies=("ppo",))
    with pytest.raises(ValueError, match="unknown options \\['lr'\\]"):
        example("train_viewpoint_ppo").main(lr=1e-3)
    with pytest.raises(ConfigError, match="bootstrap_time_limit must be True or False, got 1"):
        example("train_viewpoint_ppo").main(bootstrap_time_limit=1)
    with pytest.raises(UsageError, match="torch_threads must be"):
        example("train_viewpoint_ppo").main(torch_threads=0)


def test_image_size_overrides_the_frame_is_recorded_and_is_refused_where_it_cannot_apply(example):
    train = example("train_viewpoint_ppo")
    assert train._parse(["--image-size", "96x54"])["image_size"] == (96, 54)
    assert train._parse([])["image_size"] is None
    vec = train.make_vec_env("pixels", n_envs=1, num_cpus=0, seed=0, max_cycles=2, image_size=(96, 54))
    try:
        assert vec.observation_space["image"].shape == (54, 96, 3)
        obs = vec.reset()
        assert obs["image"].shape == (4, 54, 96, 3)
    finally:
        vec.close()
    record = train._resolved_config("pixels_precise", None, (96, 54))
    assert record["env"]["image_size"] == [96, 54] and record["env"]["renderer"] == "batch"
    assert train._resolved_config("pixels_precise", None)["env"]["image_size"] == [64, 36]
    with pytest.raises(ConfigError, match="applies to a configuration that observes images; 'state'"):
        train.main(config="state", image_size=(128, 72))
    with pytest.raises(ConfigError, match="up to 160 x 120 px .* got image_size 320 x 180"):
        train.main(config="pixels", image_size=(320, 180))
    width = r"image_size\[0\] \(width\) must be an int in \[16, 8192\], got 96.0"
    with pytest.raises(ConfigError, match=width):
        train.main(config="pixels", image_size=(96.0, 54))
    with pytest.raises(ConfigError, match="image_size must be \\(width, height\\) in pixels, got '96x54'"):
        train.main(config="pixels", image_size="96x54")


def test_the_trainer_marks_time_limits_for_bootstrapping_unless_told_not_to(example):
    train = example("train_viewpoint_ppo")
    assert train.DEFAULTS["bootstrap_time_limit"] is True
    assert train._parse([])["bootstrap_time_limit"] is True
    assert train._parse(["--no-bootstrap-time-limit"])["bootstrap_time_limit"] is False
    for bootstrap in (False, True):
        vec = train.make_vec_env("state", n_envs=1, num_cpus=0, seed=0, max_cycles=2,
                                 bootstrap_time_limit=bootstrap)
        vec.reset()
        try:
            for _ in range(2):
                _, _, dones, infos = vec.step(np.zeros((vec.num_envs, 5), np.float32))
        finally:
            vec.close()
        assert dones.all()
        assert [i.get("TimeLimit.truncated") for i in infos] == [True if bootstrap else None] * 4


def test_evaluate_on_another_building(example, trained, tmp_path):
    out, _ = trained
    evaluate = example("evaluate_policy")
    summary = evaluate.main(model=str(out), policies=("ppo", "hold"), episodes=1, max_cycles=2,
                            site="random", site_seed=2, json_out=str(tmp_path / "e.json"))
    assert summary["env_config"]["env"]["site"] == "random"
    assert summary["env_config"]["env"]["texture_seed"] == 2
    assert summary["env_config_source"].endswith("; --site random; --site-seed 2")
    paper = evaluate.main(model=str(out), policies=("hold",), episodes=1, max_cycles=2)
    # the starts are placed around the other building: not the paper's start distances
    assert (summary["results"]["hold"]["start_distance_median_m"]
            != paper["results"]["hold"]["start_distance_median_m"])
    with pytest.raises(ConfigError, match=r"site must be 'paper', 'random', a Site or an existing "
                       r"\*.json / \*.ifc file, got 'nowhere.ifc'"):
        evaluate.main(policies=("hold",), site="nowhere.ifc")
    with pytest.raises(ValueError, match="site_seed"):
        evaluate.main(policies=("hold",), site="random", site_seed=-1)


def test_evaluate_reads_the_model_folder_without_unpickling(example, trained, tmp_path):
    import pickle

    import numpy as np

    from uav_struct_env.training.policy_files import load_normalization

    out, _ = trained
    with open(out / "vecnormalize.pkl", "rb") as f:  # the test's own file: trusted
        vec_normalize = pickle.load(f)
    norm = load_normalization(out / "normalization.npz")
    rng = np.random.default_rng(0)
    batch = {k: rng.normal(size=(4, *v.shape)).astype(np.float32) for k, v in norm.mean.items()}
    expected, got = vec_normalize.normalize_obs(batch), norm(batch)
    for k in expected:
        assert got[k].dtype == expected[k].dtype and np.array_equal(got[k], expected[k]), k

    legacy = tmp_path / "legacy"  # a folder from before normalization.npz: pickle only on request
    legacy.mkdir()
    for name in ("model.zip", "vecnormalize.pkl"):
        shutil.copy(out / name, legacy / name)
    evaluate = example("evaluate_policy")
    with pytest.raises(ValueError, match="has vecnormalize.pkl but no normalization.npz.*--trust-pickle"):
        evaluate.main(model=str(legacy), policies=("ppo",), episodes=1, max_cycles=2)
    summary = evaluate.main(model=str(legacy), policies=("ppo",), episodes=1, max_cycles=2,
                            trust_pickle=True)
    assert summary["results"]["ppo"]["final_step"]["n"] == 4


def test_a_model_with_an_unknown_pickled_entry_is_refused(trained, tmp_path):
    from uav_struct_env.training.policy_files import load_ppo
    from uav_struct_env.wrappers import make_train_env

    out, _ = trained
    with zipfile.ZipFile(out / "model.zip") as src:
        entries = {n: src.read(n) for n in src.namelist()}
    data = json.loads(entries["data"])
    data["payload"] = {":type:": "<class 'object'>", ":serialized:": "gARLAS4="}
    entries["data"] = json.dumps(data).encode()
    bad = tmp_path / "model.zip"
    with zipfile.ZipFile(bad, "w") as dst:
        for n, b in entries.items():
            dst.writestr(n, b)
    env = make_train_env("state")
    agent = env.possible_agents[0]
    with pytest.raises(ValueError, match=r"pickled entries \['payload'\] that cannot be read safely"):
        load_ppo(bad, env.observation_space(agent), env.action_space(agent))
    env.close()


def _run(script, *args):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    return subprocess.run([sys.executable, str(EXAMPLES / script), *args], capture_output=True,
                          text=True, timeout=120, env=env)


def test_example_mistakes_are_one_line_and_status_2(tmp_path):
    done = _run("evaluate_policy.py", "--model", str(tmp_path / "missing"), "--policies", "ppo")
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"evaluate_policy.py: error: --model '{tmp_path / 'missing' / 'model.zip'}' does not exist; "
        "expected an existing model.zip"
    ]
    (tmp_path / "file").write_text("x")
    done = _run("train_viewpoint_ppo.py", "--out", str(tmp_path / "file" / "run"))
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert f"--out '{tmp_path / 'file' / 'run'}' cannot be created: '{tmp_path / 'file'}' is not a folder" \
        in done.stderr
    assert list(tmp_path.iterdir()) == [tmp_path / "file"]


def test_evaluate_writes_nothing_unless_asked(example):
    evaluate = example("evaluate_policy")
    assert evaluate.DEFAULTS["plot"] is None and evaluate.DEFAULTS["json_out"] is None


def test_checkpoints_evaluate_into_a_learning_curve_with_a_band_over_runs(example, trained, tmp_path):
    out, _ = trained
    second = tmp_path / "seed4"
    example("train_viewpoint_ppo").main(out=str(second), total_timesteps=128, n_envs=1, num_cpus=0,
                                     n_steps=32, batch_size=64, n_epochs=1, max_cycles=8,
                                     checkpoint_every=64, progress_bar=False, seed=4)
    evaluate = example("evaluate_policy")
    summary = evaluate.main(checkpoints=(str(out), str(second)), episodes=1, max_cycles=4,
                            plot=str(tmp_path / "curve.png"), json_out=str(tmp_path / "curve.json"))
    curves = summary["learning_curve"]
    assert [p["agent_steps"] for p in curves[str(out)]] == [128, 256]
    # one rollout of 4 x 32 (checkpoint every 64): checkpoints are taken at rollout boundaries, so
    # only its end
    assert [p["agent_steps"] for p in curves[str(second)]] == [128]
    for points in curves.values():
        for p in points:
            assert 0.0 <= p["final_success_rate"] <= 1.0 and np.isfinite(p["mean_return"])
    assert (tmp_path / "curve.png").stat().st_size > 1000
    # The same checkpoint evaluates to the same numbers as the model folder it is.
    direct = evaluate.main(model=str(out / "checkpoints" / "step_000000256"), policies=("ppo",),
                           episodes=1, max_cycles=4)
    assert direct["results"]["ppo"]["mean_return"] == pytest.approx(curves[str(out)][1]["mean_return"])
    with pytest.raises(UsageError, match="holds no checkpoints/step_<N>/model.zip"):
        evaluate.main(checkpoints=(str(tmp_path),), episodes=1)


# num_cpus=2 starts two SuperSuit worker processes (a long library run: `make test-slow`)
@pytest.mark.parametrize("num_cpus", [pytest.param(2, marks=pytest.mark.slow), 0])
def test_every_env_copy_gets_its_own_seed_however_they_share_processes(example, num_cpus):
    # Copy k must play the episodes of a single env seeded seed + k: SuperSuit alone seeds the
    # copies of process i with seed + i + j, so with two copies in one process seeds repeat.
    from uav_struct_env.wrappers import make_train_env

    train = example("train_viewpoint_ppo")
    single = make_train_env("state")
    expected = []
    for k in range(3):
        single.reset(seed=7 + k)
        obs, _ = single.reset()  # the copy's second episode, from its seeded generator
        expected.append(np.concatenate([obs[a]["gnss"] for a in single.possible_agents]))
    single.close()
    # two processes (two copies, then one), or none
    vec = train.make_vec_env("state", n_envs=3, num_cpus=num_cpus, seed=7)
    try:
        gnss = vec.reset()["gnss"].reshape(3, -1)
    finally:
        vec.close()
    for k in range(3):
        np.testing.assert_array_equal(gnss[k], expected[k], err_msg=f"copy {k}, num_cpus={num_cpus}")


def test_the_throughput_benchmark_replays_a_trained_policy_the_same_on_bare_and_wrapped_env(
        trained, load_script):
    bench = load_script(Path(__file__).resolve().parents[2] / "benchmarks" / "wrapper_throughput.py")
    from uav_struct_env.wrappers import make_train_env

    out, _ = trained
    wrapped = make_train_env("state", max_cycles=6)
    episodes = bench.record(wrapped, str(out), 2, seed=5)
    assert [len(e) for e in episodes] == [6, 6]
    again = bench.record(wrapped, str(out), 1, seed=5)[0]  # deterministic policy, seeded episodes
    assert again[3]["uav_2"].tolist() == episodes[0][3]["uav_2"].tolist()
    # the same flights on the bare env (no wrapper): the replayed actions, not the observations
    ends = []
    for env in (wrapped, wrapped.unwrapped):
        env.reset(seed=5)
        for acts in episodes[0]:
            *_, infos = env.step(acts)
        ends.append(np.stack([infos[a]["world_from_cam"] for a in sorted(infos)]))
    np.testing.assert_array_equal(ends[0], ends[1])
    rate, n, cpu = bench.measure(wrapped, 4 * 6 + 1, episodes, seed=5)  # into the second episode
    assert n == 4 * 7 and rate > 0 and cpu > 0
    with pytest.raises(UsageError, match=r"--model '.*nowhere'"):
        bench.record(wrapped, str(out / "nowhere"), 1, seed=5)
    wrapped.close()


def test_the_learning_curve_ends_at_the_final_model_where_no_checkpoint_holds_it(example, trained, tmp_path):
    out, _ = trained
    run = tmp_path / "run"
    shutil.copytree(out, run)
    evaluate = example("evaluate_policy")
    assert [s for s, _ in evaluate.checkpoint_folders(run)] == [128, 256]  # the last checkpoint is it
    shutil.rmtree(run / "checkpoints" / "step_000000256")  # a run from before the trainer saved it
    assert evaluate.checkpoint_folders(run) == [(128, run / "checkpoints" / "step_000000128"), (256, run)]


def test_a_policy_from_pixels_trains_and_the_evaluator_reads_it_back(example, tmp_path):
    """The ``pixels`` configuration: the image reaches the CNN as uint8 (not normalized) and the
    safe loader rebuilds the model channel-first, predicting what SB3's own loader predicts."""
    from stable_baselines3 import PPO

    from uav_struct_env.training.policy_files import load_normalization, load_ppo
    from uav_struct_env.wrappers import make_train_env

    out = tmp_path / "pixels"
    summary = example("train_viewpoint_ppo").main(
        out=str(out), config="pixels", total_timesteps=64, n_envs=1, num_cpus=0, n_steps=16, batch_size=16,
        n_epochs=1, max_cycles=4, progress_bar=False, seed=2)
    assert summary["agent_steps"] == 64
    assert set(load_normalization(out / "normalization.npz").mean) == {"gnss", "attitude"}
    env = make_train_env("pixels", max_cycles=4)
    try:
        agent = env.possible_agents[0]
        obs, _ = env.reset(seed=1)
        ours = load_ppo(out / "model.zip", env.observation_space(agent), env.action_space(agent))
        sb3 = PPO.load(out / "model.zip", device="cpu")
        batch = {k: v[None] for k, v in obs[agent].items()}
        np.testing.assert_array_equal(ours.predict(batch, deterministic=True)[0],
                                      sb3.predict(batch, deterministic=True)[0])
    finally:
        env.close()


def test_sites_put_each_env_copy_on_its_building_and_the_evaluator_names_a_training_building(
        example, trained, tmp_path):
    # copy k stands on sites[k] and plays the episodes of a single env there seeded 7 + k
    from uav_struct_env.wrappers import make_train_env

    train = example("train_viewpoint_ppo")
    sites = ("paper", "random:100")
    assert train._parse(["--sites", "paper,random:100-101"])["sites"] == ("paper", "random:100", "random:101")
    assert train.copy_sites(sites, 3) == [{"site": "paper"}, {"site": "random", "texture_seed": 100},
                                          {"site": "paper"}]
    assert train.copy_sites(None, 2) == [{}, {}]
    vec = train.make_vec_env("state", n_envs=2, num_cpus=0, seed=7, sites=sites)
    try:
        gnss = vec.reset()["gnss"].reshape(2, -1)
    finally:
        vec.close()
    for k, site in enumerate(sites):
        single = make_train_env("state", **train.site_overrides(site))
        single.reset(seed=7 + k)
        obs, _ = single.reset()  # the copy's second episode, from its seeded generator
        single.close()
        np.testing.assert_array_equal(
            gnss[k], np.concatenate([obs[a]["gnss"] for a in single.possible_agents]), err_msg=f"copy {k}")
    assert not np.array_equal(gnss[0], gnss[1])  # the starts are placed around another building
    with pytest.raises(ConfigError, match=r"--sites names 2 sites but --n-envs is 1"):
        train.check_sites(list(sites), 1)
    with pytest.raises(ConfigError, match=r"each site must be paper, random:N.*got 'moon'"):
        train.check_sites(["paper", "moon"], 4)
    # a run that trained on random:100: evaluated there, the evaluation says so
    out, _ = trained
    record = json.loads((out / "train.json").read_text())
    run = tmp_path / "run"
    shutil.copytree(out, run)
    record["options"]["sites"] = list(sites)
    (run / "train.json").write_text(json.dumps(record))
    evaluate = example("evaluate_policy")
    config, source = evaluate.env_config({**evaluate.DEFAULTS, "model": str(run), "policies": ("ppo",),
                                          "site": "random", "site_seed": 100})
    assert source.endswith("(a building these runs trained on: train.json's --sites)")
    _, source = evaluate.env_config({**evaluate.DEFAULTS, "model": str(run), "policies": ("ppo",),
                                     "site": "random", "site_seed": 3})
    assert "trained on" not in source
