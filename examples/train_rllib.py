"""Train one viewpoint policy shared by the four UAVs with Ray RLlib PPO, on one machine or a cluster.

The env is a documented training config of :data:`uav_struct_env.wrappers.TRAIN_CONFIGS`
(``state`` by default; ``on_crash="all"`` terminates every agent on a crash, which RLlib's
wrapper needs to end the episode), its Dict observation flattened to one vector
(:class:`uav_struct_env.wrappers.FlattenObservation`), as RLlib's ``ParallelPettingZooEnv``.
Multi-agent PPO with parameter sharing: one RLModule, ``shared``, acts for all four agents and
learns from all their experience. Observations are normalized by RLlib's ``MeanStdFilter``
connector (its statistics are saved in the checkpoints). ``--num-env-runners N`` samples in N Ray
actors (0: in this process); ``--address`` joins a running Ray cluster (``auto``, ``host:6379``)
instead of starting a local Ray instance, whose nodes need this package installed.

    pip install -e '.[ray]'
    .venv/bin/python examples/train_rllib.py --out runs/rllib_state --num-env-runners 2 --minutes 30

Writes under ``--out`` only: ``checkpoints/iter_<N>/`` (RLlib ``Algorithm.save_to_path``
folders, every ``--checkpoint-every`` iterations and at the end; restore with
``Algorithm.from_checkpoint``), ``progress.jsonl`` (per training iteration: agent-steps, the mean
training episode return -- RLlib's, summed over the four agents -- and episodes) and
``train.json`` (options, agent-steps, wall clock, agent-steps per second).
A progress bar shows agent-steps and the mean training episode return. ``--seed`` seeds RLlib
(torch and every env runner's env resets, ``seed + runner index``).
"""

from __future__ import annotations

import json
import sys
import time
import warnings
from typing import Any

from uav_struct_env.outputs import atomic_write_json, prepare_output_dir, real_folder
from uav_struct_env.validate import INPUT_ERRORS, CommandParser, check_option, check_output_dir, refuse

#: The name the env is registered under with Ray Tune.
ENV_NAME = "uav_struct_train"
#: The one RLModule every agent maps to (parameter sharing).
SHARED = "shared"

DEFAULTS: dict[str, Any] = {
    "out": "runs/rllib_state",
    "overwrite": False,
    "config": "state",
    "total_timesteps": 400_000,
    "minutes": None,
    "num_env_runners": 2,
    "address": None,
    "train_batch_size": 2048,
    "minibatch_size": 256,
    "num_epochs": 10,
    "learning_rate": 3e-4,
    "gamma": 0.95,
    "net_arch": (64, 64),
    "checkpoint_every": 10,
    "max_cycles": None,
    "seed": 0,
    "progress_bar": True,
}


def make_env(env_config: dict[str, Any]):
    """The RLlib env: ``ParallelPettingZooEnv(FlattenObservation(make_train_env(...)))``.

    ``env_config``: ``config`` (a TRAIN_CONFIGS name) and optional ``max_cycles``.
    """
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    from uav_struct_env.wrappers import FlattenObservation, make_train_env

    overrides = {} if env_config.get("max_cycles") is None else {"max_cycles": env_config["max_cycles"]}
    return ParallelPettingZooEnv(FlattenObservation(make_train_env(env_config["config"], **overrides)))


def _shared(agent_id, episode=None, **kwargs) -> str:
    return SHARED


def ppo_config(opt: dict[str, Any]):
    """The RLlib ``PPOConfig`` of these options (one shared module for every agent)."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.connectors.env_to_module import MeanStdFilter
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig

    return (
        PPOConfig()
        .environment(ENV_NAME, env_config={"config": opt["config"], "max_cycles": opt["max_cycles"]})
        .env_runners(
            num_env_runners=opt["num_env_runners"],
            num_envs_per_env_runner=1,
            num_cpus_per_env_runner=1,
            env_to_module_connector=lambda env, spaces=None, device=None: MeanStdFilter(multi_agent=True),
        )
        .multi_agent(policies={SHARED}, policy_mapping_fn=_shared, count_steps_by="agent_steps")
        .training(
            train_batch_size_per_learner=opt["train_batch_size"],
            minibatch_size=opt["minibatch_size"],
            num_epochs=opt["num_epochs"],
            lr=opt["learning_rate"],
            gamma=opt["gamma"],
        )
        .rl_module(model_config=DefaultModelConfig(fcnet_hiddens=list(opt["net_arch"])))
        .learners(num_learners=0)
        .debugging(seed=opt["seed"])
    )


def check_options(opt: dict[str, Any]) -> None:
    """Every option and ``out``, before Ray starts or anything is written.

    Raises:
        UsageError / ConfigError / OutputExistsError: naming the option and what was expected.
    """
    from uav_struct_env.errors import ConfigError
    from uav_struct_env.wrappers import TRAIN_CONFIGS

    if opt["config"] not in TRAIN_CONFIGS:
        raise ConfigError(f"config must be one of {sorted(TRAIN_CONFIGS)}, got {opt['config']!r}")
    if TRAIN_CONFIGS[opt["config"]].actor_keys:  # RLlib's default module would read every key
        raise ConfigError(
            f"config {opt['config']!r} is an asymmetric actor-critic (the policy reads "
            f"{list(TRAIN_CONFIGS[opt['config']].actor_keys)}): train it with "
            "examples/train_viewpoint_ppo.py; here use state, image or pixels"
        )
    for name, lo in (("total_timesteps", 1), ("num_env_runners", 0), ("train_batch_size", 2),
                     ("minibatch_size", 2), ("num_epochs", 1), ("checkpoint_every", 1), ("seed", 0)):
        check_option(name, opt[name], lo, integer=True)
    if opt["minibatch_size"] > opt["train_batch_size"]:
        raise ConfigError(f"minibatch_size ({opt['minibatch_size']}) must not exceed train_batch_size "
                          f"({opt['train_batch_size']})")
    if opt["max_cycles"] is not None:
        check_option("max_cycles", opt["max_cycles"], 1, integer=True)
    if opt["minutes"] is not None:
        check_option("minutes", opt["minutes"], 0, lo_open=True)
    check_option("learning_rate", opt["learning_rate"], 0, lo_open=True)
    check_option("gamma", opt["gamma"], 0, 1)
    for k, width in enumerate(opt["net_arch"]):
        check_option(f"net_arch[{k}]", width, 1, integer=True)
    if opt["address"] is not None and not (isinstance(opt["address"], str) and opt["address"].strip()):
        raise ConfigError(f"address must be a Ray cluster address (auto, host:6379), got {opt['address']!r}")
    check_output_dir(opt["out"], overwrite=opt["overwrite"])


def _metric(result: dict, *path: str, default: float = float("nan")) -> float:
    for key in path:
        if not isinstance(result, dict) or key not in result:
            return default
        result = result[key]
    return float(result)


def main(**kwargs: Any) -> dict[str, Any]:
    """Train and checkpoint; returns the ``train.json`` summary. Keys: see :data:`DEFAULTS`."""
    unknown = sorted(set(kwargs) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown options {unknown}; valid: {sorted(DEFAULTS)}")
    opt = {**DEFAULTS, **kwargs}
    check_options(opt)
    import os

    import ray
    from ray.tune.registry import register_env
    from tqdm import tqdm

    out = prepare_output_dir(opt["out"], overwrite=opt["overwrite"])
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    started = not ray.is_initialized()
    if started:
        if opt["address"] is None:  # a local instance: one CPU per env runner, and the driver
            ray.init(num_cpus=max(os.cpu_count() or 1, opt["num_env_runners"] + 1),
                     include_dashboard=False, log_to_driver=False,
                     runtime_env={"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}})
        else:
            ray.init(address=opt["address"], log_to_driver=False)
    register_env(ENV_NAME, make_env)
    algo = ppo_config(opt).build_algo()
    checkpoints = real_folder(out / "checkpoints")
    bar = tqdm(total=opt["total_timesteps"], unit="agent-step", desc="rllib ppo",
               disable=not opt["progress_bar"], file=sys.stderr)
    steps, iteration, t0 = 0, 0, time.perf_counter()
    try:
        with (out / "progress.jsonl").open("w") as log:
            while steps < opt["total_timesteps"]:
                if opt["minutes"] is not None and time.perf_counter() - t0 > 60 * opt["minutes"]:
                    break
                result = algo.train()
                iteration += 1
                # agent-steps through the shared module (RLlib's env steps count each step once)
                steps = int(_metric(result, "env_runners", "num_module_steps_sampled_lifetime", SHARED,
                                    default=steps))
                ret = _metric(result, "env_runners", "episode_return_mean")
                row = {"iteration": iteration, "agent_steps": steps,
                       "episode_return_mean": ret if ret == ret else None,
                       "episodes": int(_metric(result, "env_runners", "num_episodes_lifetime", default=0)),
                       "wall_clock_s": round(time.perf_counter() - t0, 2)}
                log.write(json.dumps(row) + "\n")
                log.flush()
                bar.update(min(steps, opt["total_timesteps"]) - bar.n)
                bar.set_postfix(ret=f"{ret:.2f}", it=iteration)
                if iteration % opt["checkpoint_every"] == 0:
                    algo.save_to_path(str(checkpoints / f"iter_{iteration:06d}"))
        wall = time.perf_counter() - t0
        final = checkpoints / f"iter_{iteration:06d}"
        if not final.exists():
            algo.save_to_path(str(final))
    finally:
        bar.close()
        algo.stop()
        if started:
            ray.shutdown()
    summary = {
        "options": {k: (list(v) if isinstance(v, tuple) else v) for k, v in opt.items()},
        "iterations": iteration,
        "agent_steps": steps,
        "wall_clock_s": wall,
        "agent_steps_per_s": steps / wall if wall > 0 else float("nan"),
        "checkpoint": str(final),
    }
    atomic_write_json(out / "train.json", summary, indent=2)
    return summary


def _parse(argv: list[str] | None = None) -> dict[str, Any]:
    p = CommandParser(prog="train_rllib.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=DEFAULTS["out"], help="output folder")
    p.add_argument("--overwrite", action="store_true",
                   help="train into an --out folder that already holds files (else refused)")
    p.add_argument("--config", default=DEFAULTS["config"], help="TRAIN_CONFIGS name: state | image | pixels "
                   "(not pixels_critic or pixels_keypoints: SB3 only)")
    p.add_argument("--total-timesteps", type=int, default=DEFAULTS["total_timesteps"],
                   help="stop after this many agent-steps")
    p.add_argument("--minutes", type=float, default=None, help="stop after this wall-clock time")
    p.add_argument("--num-env-runners", type=int, default=DEFAULTS["num_env_runners"],
                   help="Ray actors sampling the env (0: sample in this process)")
    p.add_argument("--address", default=None,
                   help="join this running Ray cluster (auto, host:6379) instead of a local instance")
    p.add_argument("--train-batch-size", type=int, default=DEFAULTS["train_batch_size"],
                   help="agent-steps per PPO update")
    p.add_argument("--minibatch-size", type=int, default=DEFAULTS["minibatch_size"])
    p.add_argument("--num-epochs", type=int, default=DEFAULTS["num_epochs"])
    p.add_argument("--learning-rate", type=float, default=DEFAULTS["learning_rate"])
    p.add_argument("--gamma", type=float, default=DEFAULTS["gamma"])
    p.add_argument("--net-arch", type=int, nargs="+", default=list(DEFAULTS["net_arch"]))
    p.add_argument("--checkpoint-every", type=int, default=DEFAULTS["checkpoint_every"],
                   help="training iterations between checkpoints")
    p.add_argument("--max-cycles", type=int, default=None, help="override the episode length")
    p.add_argument("--seed", type=int, default=DEFAULTS["seed"])
    p.add_argument("--no-progress-bar", dest="progress_bar", action="store_false")
    args = vars(p.parse_args(argv))
    args["net_arch"] = tuple(args["net_arch"])
    return args


if __name__ == "__main__":
    options = _parse()
    try:  # every input before any work
        check_options({**DEFAULTS, **options})
    except INPUT_ERRORS as err:
        sys.exit(refuse("train_rllib.py", err))
    try:
        summary = main(**options)
    except OSError as err:  # e.g. the disk filled up
        sys.exit(refuse("train_rllib.py", err, status=1))
    print(json.dumps({k: v for k, v in summary.items() if k != "options"}, indent=2))
