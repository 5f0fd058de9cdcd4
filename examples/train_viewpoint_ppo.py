"""Train one viewpoint policy shared by the four UAVs with stable-baselines3 PPO.

The env is a documented training config of :data:`uav_struct_env.wrappers.TRAIN_CONFIGS`
(``state`` by default: state-only observations, anchor-quality ``error`` reward, 30-step episodes,
random starts 15-35 m out with up to +-60 deg of heading error). SuperSuit turns the four agents
into four slots of one vector env (``pettingzoo_env_to_vec_env_v1``) and stacks ``n_envs`` copies
in ``num_cpus`` subprocesses (``concat_vec_envs_v1``; by default 8 copies in 2 processes, 32 agent
slots: on 2 cores, several copies per process carry more agent-steps per exchange with the
trainer than one copy per process, docs/benchmarks.md); an episode that ends at its time limit is
marked ``TimeLimit.truncated`` (:class:`~uav_struct_env.wrappers.StepInfos`), so SB3 bootstraps
the value there instead of training the limit as a terminal state (``--no-bootstrap-time-limit``:
as before 2026-11-27; docs/training.md); observations and rewards are normalized
(``VecNormalize``, saved beside the model: ``normalization.npz`` holds the observation statistics
as plain arrays, which ``evaluate_policy.py`` reads without unpickling anything; SB3's own
``vecnormalize.pkl`` is kept for resuming training with ``VecNormalize.load``).

    .venv/bin/python examples/train_viewpoint_ppo.py --out runs/ppo_state --minutes 30
    .venv/bin/tensorboard --logdir runs/ppo_state/tb

Writes ``model.zip``, ``normalization.npz``, ``vecnormalize.pkl``, ``train.json`` (options, steps,
wall clock, agent-steps per second), ``progress.jsonl`` (per rollout: training episode return and
final-step localization, also on the progress bar and in TensorBoard), ``checkpoints/step_<N>/``
(model folders every ``--checkpoint-every`` agent-steps, for ``evaluate_policy.py
--checkpoints``' learning curve) and ``tb/`` under ``--out`` only (every option is checked, and
``--out`` too, before training starts).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from typing import Any

from uav_struct_env.outputs import atomic_path, atomic_write_json, prepare_output_dir, real_folder
from uav_struct_env.validate import INPUT_ERRORS, CommandParser, check_option, check_output_dir, refuse

DEFAULTS: dict[str, Any] = {
    "out": "runs/ppo_state",
    "overwrite": False,
    "config": "state",
    "total_timesteps": 400_000,
    "minutes": None,
    "n_envs": 8,
    "num_cpus": 2,
    "n_steps": 128,
    "batch_size": 512,
    "n_epochs": 10,
    "learning_rate": 3e-4,
    "gamma": 0.95,
    "ent_coef": 0.0,
    "net_arch": (64, 64),
    "log_std_init": -1.0,
    "checkpoint_every": 50_000,
    "seed": 0,
    "progress_bar": True,
    "bootstrap_time_limit": True,
}


def make_vec_env(config: str, n_envs: int, num_cpus: int, seed: int, max_cycles: int | None = None,
                 bootstrap_time_limit: bool = True):
    """SuperSuit vector env over ``n_envs`` copies of the wrapped env (4 agent slots each).

    Copy ``k`` is seeded ``seed + k``, every copy its own seed however the copies are spread over
    the ``num_cpus`` subprocesses (:func:`_seed_copies`). Infos carry ``localization`` of each
    step only (:class:`~uav_struct_env.wrappers.StepInfos`): what the progress reads at an
    episode's end is then its final step's, not the next episode's reset, which SuperSuit merges
    over it; and the exchange with the subprocesses carries no landmark truth. With
    ``bootstrap_time_limit`` the infos also say where an episode ended at its time limit, so SB3
    bootstraps the value there instead of treating the limit as a terminal state.
    """
    import supersuit as ss
    from stable_baselines3.common.vec_env import VecMonitor

    from uav_struct_env.wrappers import StepInfos, make_train_env

    overrides = {} if max_cycles is None else {"max_cycles": max_cycles}
    env = StepInfos(make_train_env(config, **overrides), keys=("localization",),
                    time_limit=bootstrap_time_limit)
    vec = ss.pettingzoo_env_to_vec_env_v1(env)
    vec = ss.concat_vec_envs_v1(vec, n_envs, num_cpus=num_cpus, base_class="stable_baselines3")
    _seed_copies(vec.venv, seed, n_envs)  # SB3's PPO(seed=...) would call vec.seed(), which SuperSuit lacks
    return VecMonitor(vec)


def _seed_copies(venv, seed: int, n_envs: int) -> None:
    """Reset env copy ``k`` of SuperSuit's vector env ``venv`` with seed ``seed + k``.

    In one process (``ConcatVecEnv``) SuperSuit's own reset does that. Across subprocesses
    (``ProcConcatVec``) it gives process ``i`` the seed ``seed + i`` and that process's copy ``j``
    ``seed + i + j``: with two copies per process, copies 1 and 2 would share a seed and start
    the same episodes. Each process is sent SuperSuit's reset message with the seed of its first
    copy instead.
    """
    from supersuit.vector import ProcConcatVec

    if not isinstance(venv, ProcConcatVec):
        venv.reset(seed=seed)
        return
    slots = venv.num_envs // n_envs  # agent slots per copy
    for pipe, start in zip(venv.pipes, venv.idx_starts, strict=False):  # idx_starts has one more
        pipe.send(("reset", (seed + start // slots, None)))
    venv._receive_info()


class _Progress:
    """Progress a researcher can read, as an SB3 callback (and the optional wall-clock limit).

    After every rollout: the mean training episode return (raw rewards, the stochastic policy
    while it explores) and, over the last 100 agent-episodes, the final-step localization
    success rate and median translation error; on the progress bar, in TensorBoard
    (``uav/...``) and as one JSON line per rollout in ``progress.jsonl``, with where the wall
    clock went: ``rollout_s`` (this rollout: stepping the envs, the policy's actions, the
    checkpoints) and ``update_s`` (the gradient update between the previous rollout and this
    one, with SB3's logging; None for the first); ``train.json``'s ``collect_s`` and
    ``update_total_s`` are their sums (a last update after the last rollout is not in them). The deterministic
    evaluation of saved checkpoints is ``evaluate_policy.py --checkpoints`` (docs/training.md
    explains why the two returns differ).
    """

    def __new__(cls, total: int, minutes: float | None, show: bool, log_path):
        from collections import deque

        import numpy as np
        from stable_baselines3.common.callbacks import BaseCallback

        class Progress(BaseCallback):
            def _on_training_start(self) -> None:
                self.t0 = time.perf_counter()
                self.collect_s, self.update_total_s = 0.0, 0.0
                self.rollout_t0, self.update_t0, self.update_s = self.t0, None, None
                self.finals: deque = deque(maxlen=100)
                log_path.unlink(missing_ok=True)  # a new file, never through a planted link
                self.bar = None
                if show:
                    from tqdm.auto import tqdm

                    self.bar = tqdm(total=total, unit="step", smoothing=0.05)

            def _on_step(self) -> bool:
                for done, info in zip(self.locals["dones"], self.locals["infos"], strict=True):
                    if done and "localization" in info:
                        loc = info["localization"]
                        self.finals.append((loc["success"], loc["translation_error_m"]))
                if self.bar is not None:
                    self.bar.update(self.training_env.num_envs)
                if minutes is not None and time.perf_counter() - self.t0 > 60.0 * minutes:
                    return False
                return True

            def _on_rollout_start(self) -> None:
                self.rollout_t0 = time.perf_counter()
                if self.update_t0 is not None:  # the update since the last rollout ended
                    self.update_s = self.rollout_t0 - self.update_t0
                    self.update_total_s += self.update_s

            def _on_rollout_end(self) -> None:
                now = time.perf_counter()
                rollout_s = now - self.rollout_t0
                self.collect_s += rollout_s
                self.update_t0 = now
                returns = [e["r"] for e in self.model.ep_info_buffer]
                ok = [e for s, e in self.finals if s]
                row = {
                    "agent_steps": int(self.num_timesteps),
                    "wall_clock_s": round(now - self.t0, 2),
                    "rollout_s": round(rollout_s, 3),
                    "update_s": None if self.update_s is None else round(self.update_s, 3),
                    "episode_return_mean": float(np.mean(returns)) if returns else None,
                    "final_success_rate": len(ok) / len(self.finals) if self.finals else None,
                    "final_translation_median_m": float(np.median(ok)) if ok else None,
                }
                for key, value in row.items():
                    if key not in ("agent_steps", "rollout_s", "update_s") and value is not None:
                        self.logger.record(f"uav/{key}", value)
                with open(log_path, "a") as log:
                    log.write(json.dumps(row) + "\n")
                if self.bar is not None and row["episode_return_mean"] is not None:
                    self.bar.set_postfix(ret=f"{row['episode_return_mean']:.2f}",
                                         loc=f"{row['final_success_rate'] or 0:.2f}",
                                         err=f"{row['final_translation_median_m'] or float('nan'):.2f}m")

            def _on_training_end(self) -> None:
                if self.bar is not None:
                    self.bar.close()

        return Progress()


class _Checkpoints:
    """Every ``every`` agent-steps a model folder ``checkpoints/step_<steps>/``.

    It holds ``model.zip`` and ``normalization.npz``, which ``evaluate_policy.py`` reads without
    unpickling (SB3's own checkpoints would pickle the normalization).
    """

    def __new__(cls, every: int, folder, vec_normalize):
        from stable_baselines3.common.callbacks import BaseCallback

        from uav_struct_env.training.policy_files import NORMALIZATION_FILE, save_normalization

        class Checkpoints(BaseCallback):
            def _on_step(self) -> bool:
                if self.num_timesteps // every > getattr(self, "saved", 0):
                    self.saved = self.num_timesteps // every
                    target = real_folder(folder / f"step_{self.num_timesteps:09d}")
                    with atomic_path(target / "model.zip") as tmp:
                        self.model.save(tmp)
                    save_normalization(vec_normalize, target / NORMALIZATION_FILE)
                return True

        return Checkpoints()


def check_options(opt: dict[str, Any]) -> None:
    """Every option and ``out``, before anything is imported, trained or written.

    Raises:
        UsageError / OutputExistsError: naming the option and what was expected.
    """
    from uav_struct_env.errors import ConfigError
    from uav_struct_env.wrappers import TRAIN_CONFIGS

    if opt["config"] not in TRAIN_CONFIGS:
        raise ConfigError(f"config must be one of {sorted(TRAIN_CONFIGS)}, got {opt['config']!r}")
    for name, lo in (("total_timesteps", 1), ("n_envs", 1), ("num_cpus", 0), ("n_steps", 2),
                     ("batch_size", 2), ("n_epochs", 1), ("checkpoint_every", 1), ("seed", 0)):
        check_option(name, opt[name], lo, integer=True)
    if opt["max_cycles"] is not None:
        check_option("max_cycles", opt["max_cycles"], 1, integer=True)
    if opt["minutes"] is not None:
        check_option("minutes", opt["minutes"], 0, lo_open=True)
    check_option("learning_rate", opt["learning_rate"], 0, lo_open=True)
    check_option("gamma", opt["gamma"], 0, 1)
    check_option("ent_coef", opt["ent_coef"], 0)
    check_option("log_std_init", opt["log_std_init"])
    if not isinstance(opt["bootstrap_time_limit"], bool):
        raise ConfigError(f"bootstrap_time_limit must be True or False, got {opt['bootstrap_time_limit']!r}")
    for k, width in enumerate(opt["net_arch"]):
        check_option(f"net_arch[{k}]", width, 1, integer=True)
    check_output_dir(opt["out"], overwrite=opt["overwrite"])


def main(**kwargs: Any) -> dict[str, Any]:
    """Train and save; returns the ``train.json`` summary. Keys: see :data:`DEFAULTS`."""
    unknown = sorted(set(kwargs) - set(DEFAULTS) - {"max_cycles"})
    if unknown:
        raise ValueError(f"unknown options {unknown}; valid: {sorted(DEFAULTS)}")
    opt = {**DEFAULTS, "max_cycles": None, **kwargs}
    check_options(opt)
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.utils import set_random_seed
    from stable_baselines3.common.vec_env import VecNormalize

    from uav_struct_env.provenance import software
    from uav_struct_env.training.policy_files import NORMALIZATION_FILE, save_normalization

    # An earlier run in "out" is refused unless overwrite=True (the error names --overwrite).
    out = prepare_output_dir(opt["out"], overwrite=opt["overwrite"])
    set_random_seed(opt["seed"])
    warnings.filterwarnings("ignore", "The `render_mode` attribute is not defined")
    torch.set_num_threads(1)
    vec = make_vec_env(
        opt["config"], opt["n_envs"], opt["num_cpus"], opt["seed"], opt["max_cycles"],
        opt["bootstrap_time_limit"],
    )
    vec = VecNormalize(vec, norm_obs=True, norm_reward=True, gamma=opt["gamma"])
    policy = "MultiInputPolicy"
    model = PPO(
        policy,
        vec,
        n_steps=opt["n_steps"],
        batch_size=opt["batch_size"],
        n_epochs=opt["n_epochs"],
        learning_rate=opt["learning_rate"],
        gamma=opt["gamma"],
        ent_coef=opt["ent_coef"],
        policy_kwargs={"net_arch": list(opt["net_arch"]), "log_std_init": opt["log_std_init"]},
        tensorboard_log=str(real_folder(out / "tb")),  # written inside --out, never through a link
        device="cpu",
        verbose=0,
    )
    n = vec.num_envs
    progress = _Progress(opt["total_timesteps"], opt["minutes"], opt["progress_bar"],
                         out / "progress.jsonl")
    callbacks = CallbackList(
        [_Checkpoints(opt["checkpoint_every"], real_folder(out / "checkpoints"), vec), progress]
    )
    made_by = software()  # the code as training starts (the checkout may change while it runs)
    t0 = time.perf_counter()
    model.learn(total_timesteps=opt["total_timesteps"], callback=callbacks, tb_log_name="ppo")
    wall = time.perf_counter() - t0
    with atomic_path(out / "model.zip") as tmp:
        model.save(tmp)
    with atomic_path(out / "vecnormalize.pkl") as tmp:
        vec.save(str(tmp))
    save_normalization(vec, out / NORMALIZATION_FILE)
    vec.close()
    summary = {
        "options": {k: (list(v) if isinstance(v, tuple) else v) for k, v in opt.items()},
        "agent_steps": int(model.num_timesteps),
        "wall_clock_s": wall,
        "agent_steps_per_s": model.num_timesteps / wall if wall > 0 else float("nan"),
        # where the wall clock went: collecting rollouts (the env processes stepping, the policy
        # acting) and the gradient updates between them (the env processes idle)
        "collect_s": progress.collect_s,
        "update_total_s": progress.update_total_s,
        "n_agent_slots": n,
        # what --config named when this run trained (env overrides and wrapper options), and the
        # code that trained it: a later change of the named config does not change this record
        "train_config": _resolved_config(opt["config"], opt["max_cycles"]),
        "software": made_by,
    }
    atomic_write_json(out / "train.json", summary, indent=2)
    return summary


def _resolved_config(name: str, max_cycles: int | None) -> dict[str, Any]:
    """The configuration trained on (the named one with ``--max-cycles`` applied), JSON-ready.

    ``evaluate_policy.py`` rebuilds the env from it, so a run keeps its meaning when the named
    configuration changes later (as ``state`` did from ``paper`` to ``robust`` association).
    """
    from uav_struct_env.wrappers import TRAIN_CONFIGS

    c = TRAIN_CONFIGS[name]
    return (c if max_cycles is None else c.replace(env={"max_cycles": max_cycles})).as_dict()


def _parse(argv: list[str] | None = None) -> dict[str, Any]:
    p = CommandParser(prog="train_viewpoint_ppo.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=DEFAULTS["out"], help="output folder")
    p.add_argument("--overwrite", action="store_true",
                   help="train into an --out folder that already holds files (else refused)")
    p.add_argument("--config", default=DEFAULTS["config"], help="TRAIN_CONFIGS name: state | image")
    p.add_argument("--total-timesteps", type=int, default=DEFAULTS["total_timesteps"])
    p.add_argument("--minutes", type=float, default=None, help="stop after this wall-clock time")
    p.add_argument(
        "--n-envs", type=int, default=DEFAULTS["n_envs"], help="env copies (4 agents each)"
    )
    p.add_argument(
        "--num-cpus", type=int, default=DEFAULTS["num_cpus"], help="subprocesses (0: none)"
    )
    p.add_argument("--n-steps", type=int, default=DEFAULTS["n_steps"])
    p.add_argument("--batch-size", type=int, default=DEFAULTS["batch_size"])
    p.add_argument("--n-epochs", type=int, default=DEFAULTS["n_epochs"])
    p.add_argument("--learning-rate", type=float, default=DEFAULTS["learning_rate"])
    p.add_argument("--gamma", type=float, default=DEFAULTS["gamma"])
    p.add_argument("--ent-coef", type=float, default=DEFAULTS["ent_coef"])
    p.add_argument("--net-arch", type=int, nargs="+", default=list(DEFAULTS["net_arch"]))
    p.add_argument(
        "--log-std-init",
        type=float,
        default=DEFAULTS["log_std_init"],
        help="initial log std of the Gaussian actions (-1: std 0.37, starts near hovering)",
    )
    p.add_argument("--checkpoint-every", type=int, default=DEFAULTS["checkpoint_every"])
    p.add_argument("--max-cycles", type=int, default=None, help="override the episode length")
    p.add_argument("--seed", type=int, default=DEFAULTS["seed"])
    p.add_argument("--no-progress-bar", dest="progress_bar", action="store_false")
    p.add_argument("--bootstrap-time-limit", action=argparse.BooleanOptionalAction,
                   default=DEFAULTS["bootstrap_time_limit"],
                   help="bootstrap the value where an episode ends at its time limit (SB3's "
                        "TimeLimit.truncated; on by default); --no-bootstrap-time-limit: the limit "
                        "counts as a terminal state, as before 2026-11-27")
    args = vars(p.parse_args(argv))
    args["net_arch"] = tuple(args["net_arch"])
    return args


if __name__ == "__main__":
    options = _parse()
    try:  # every input before any work
        check_options({**DEFAULTS, "max_cycles": None, **options})
    except INPUT_ERRORS as err:
        sys.exit(refuse("train_viewpoint_ppo.py", err))
    try:
        summary = main(**options)
    except OSError as err:  # e.g. the disk filled up
        sys.exit(refuse("train_viewpoint_ppo.py", err, status=1))
    print(json.dumps({k: v for k, v in summary.items() if k != "options"}, indent=2))
