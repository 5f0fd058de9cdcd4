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
wall clock, agent-steps per second, and how the run was made: ``software`` and the ``settings``
line, which describe every other file of the folder too), ``progress.jsonl`` (per rollout:
training episode return and final-step localization, also on the progress bar and in
TensorBoard), ``checkpoints/step_<N>/``
(model folders every ``--checkpoint-every`` agent-steps, for ``evaluate_policy.py
--checkpoints``' learning curve) and ``tb/`` under ``--out`` only (every option is checked, and
``--out`` too, before training starts).

Ctrl-C (SIGINT) or SIGTERM stops a run at the next env step: it is saved at its last rollout
boundary (``model.zip``, a checkpoint, ``train.json`` with the steps done and ``interrupted``)
and the script exits with one line, status 130 (SIGINT) or 143 (SIGTERM).
``--resume RUN`` continues such a run from its last checkpoint with the same seed stream: every
rollout starts from env resets seeded from ``(--seed, rollout index)``, and a checkpoint holds
the weights, the optimizer, the normalization statistics and the random generators' states, so
the resumed run reaches the uninterrupted run's weights (to float rounding; tests/examples).
``--overwrite`` removes the earlier run's files (checkpoints and TensorBoard logs included)
before training; a second run into an ``--out`` that a running one is writing is refused.

    .venv/bin/python examples/train_viewpoint_ppo.py --resume runs/ppo_state
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import json
import os
import signal
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Any

from uav_struct_env.outputs import (
    OutputBusyError,
    atomic_path,
    atomic_write_json,
    atomic_write_text,
    prepare_output_dir,
    real_folder,
    remove_earlier_run,
)
from uav_struct_env.validate import (
    INPUT_ERRORS,
    CommandParser,
    check_option,
    check_output_dir,
    image_size_argument,
    refuse,
)

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
    "torch_threads": 1,
    "progress_bar": True,
    "bootstrap_time_limit": True,
    "resume": None,
    "sites": None,
}

#: Env fields an option overrides (``--max-cycles``, ``--image-size``); none: the configuration's own.
ENV_OPTIONS: dict[str, Any] = {"max_cycles": None, "image_size": None}

#: The options ``--resume`` takes from its command line; every other one is the run's recorded one.
RESUME_OPTIONS = ("total_timesteps", "minutes", "progress_bar")


def make_vec_env(config: str, n_envs: int, num_cpus: int, seed: int, max_cycles: int | None = None,
                 bootstrap_time_limit: bool = True, sites: tuple[str, ...] | None = None,
                 image_size: tuple[int, int] | None = None):
    """SuperSuit vector env over ``n_envs`` copies of the wrapped env (4 agent slots each).

    Copy ``k`` is seeded ``seed + k``, every copy its own seed however the copies are spread over
    the ``num_cpus`` subprocesses (:func:`_seed_copies`). With ``sites`` (names as
    :func:`site_overrides` reads them) copy ``k`` stands on ``sites[k % len(sites)]``; without,
    every copy on the configuration's site. Infos carry ``localization`` of each
    step only (:class:`~uav_struct_env.wrappers.StepInfos`): what the progress reads at an
    episode's end is then its final step's, not the next episode's reset, which SuperSuit merges
    over it; and the exchange with the subprocesses carries no landmark truth. With
    ``bootstrap_time_limit`` the infos also say where an episode ended at its time limit, so SB3
    bootstraps the value there instead of treating the limit as a terminal state.
    """
    from functools import partial

    from stable_baselines3.common.vec_env import VecMonitor
    from supersuit.vector import MakeCPUAsyncConstructor
    from supersuit.vector.sb3_vector_wrapper import SB3VecEnvWrapper

    overrides = _env_overrides(max_cycles, image_size)
    fns = [partial(_copy_env, config, {**overrides, **o}, bootstrap_time_limit)
           for o in copy_sites(sites, n_envs)]
    first = fns[0]()  # the spaces every copy shares (SuperSuit's concat_vec_envs_v1 does the same)
    spaces = first.observation_space, first.action_space
    first.close()
    vec = SB3VecEnvWrapper(MakeCPUAsyncConstructor(min(num_cpus, n_envs))(fns, *spaces))
    _seed_copies(vec.venv, seed, n_envs)  # SB3's PPO(seed=...) would call vec.seed(), which SuperSuit lacks
    return VecMonitor(vec)


def _env_overrides(max_cycles: int | None, image_size: tuple[int, int] | None) -> dict[str, Any]:
    """The env fields ``--max-cycles`` and ``--image-size`` override (those given)."""
    given = {"max_cycles": max_cycles, "image_size": None if image_size is None else tuple(image_size)}
    return {k: v for k, v in given.items() if v is not None}


def _copy_env(config: str, overrides: dict[str, Any], bootstrap_time_limit: bool):
    """One env copy as SuperSuit's vector env of its four agent slots."""
    import supersuit as ss

    from uav_struct_env.wrappers import StepInfos, make_train_env

    env = StepInfos(make_train_env(config, **overrides), keys=("localization",),
                    time_limit=bootstrap_time_limit)
    return ss.pettingzoo_env_to_vec_env_v1(env)


def copy_sites(sites: tuple[str, ...] | None, n_envs: int) -> list[dict[str, Any]]:
    """Per env copy, its site's env overrides: copy ``k`` on ``sites[k % len(sites)]`` (none: ``{}``)."""
    return [site_overrides(sites[k % len(sites)]) if sites else {} for k in range(n_envs)]


def site_overrides(site: str) -> dict[str, Any]:
    """The env overrides of a ``--sites`` item: ``paper`` (the configuration's textures), ``random:N``
    (the building ``evaluate_policy.py --site random --site-seed N`` evaluates on: ``site="random"``
    drawn from ``texture_seed`` N) or a site / IFC file."""
    if site.startswith("random:"):
        return {"site": "random", "texture_seed": int(site[len("random:"):])}
    return {"site": site}


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
    explains why the two returns differ). With ``minutes`` the bar's total (and so its ETA) is
    the step count the run is projected to reach when its time is up, if that comes first.
    ``start`` is the step count a resumed run starts from (``progress.jsonl`` is then extended).
    """

    def __new__(cls, total: int, minutes: float | None, show: bool, log_path, start: int = 0):
        from stable_baselines3.common.callbacks import BaseCallback

        class Progress(_ProgressSteps, BaseCallback):
            pass

        return Progress(total, minutes, show, log_path, start)


class _ProgressSteps:
    """The steps of :class:`_Progress` (mixed into SB3's ``BaseCallback``, imported when training)."""

    def __init__(self, total: int, minutes: float | None, show: bool, log_path, start: int) -> None:
        super().__init__()
        self.total, self.minutes, self.show, self.log_path, self.start = total, minutes, show, log_path, start

    def _on_training_start(self) -> None:
        from collections import deque

        self.t0 = time.perf_counter()
        self.collect_s, self.update_total_s = 0.0, 0.0
        self.rollout_t0, self.update_t0, self.update_s = self.t0, None, None
        self.finals: deque = deque(maxlen=100)
        if not self.start:
            self.log_path.unlink(missing_ok=True)  # a new file, never through a planted link
        self.bar = None
        if self.show:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=self.total, initial=self.start, unit="step", smoothing=0.05)

    def _on_step(self) -> bool:
        for done, info in zip(self.locals["dones"], self.locals["infos"], strict=True):
            if done and "localization" in info:
                loc = info["localization"]
                self.finals.append((loc["success"], loc["translation_error_m"]))
        if self.bar is not None:
            self.bar.update(self.training_env.num_envs)
        return self.minutes is None or time.perf_counter() - self.t0 <= 60.0 * self.minutes

    def _on_rollout_start(self) -> None:
        self.rollout_t0 = time.perf_counter()
        if self.update_t0 is not None:  # the update since the last rollout ended
            self.update_s = self.rollout_t0 - self.update_t0
            self.update_total_s += self.update_s

    def _row(self, now: float, rollout_s: float) -> dict[str, Any]:
        """The ``progress.jsonl`` row of the rollout that just ended."""
        import numpy as np

        returns = [e["r"] for e in self.model.ep_info_buffer]
        ok = [e for s, e in self.finals if s]
        return {
            "agent_steps": int(self.num_timesteps),
            "wall_clock_s": round(now - self.t0, 2),
            "rollout_s": round(rollout_s, 3),
            "update_s": None if self.update_s is None else round(self.update_s, 3),
            "episode_return_mean": float(np.mean(returns)) if returns else None,
            "final_success_rate": len(ok) / len(self.finals) if self.finals else None,
            "final_translation_median_m": float(np.median(ok)) if ok else None,
        }

    def _on_rollout_end(self) -> None:
        now = time.perf_counter()
        rollout_s = now - self.rollout_t0
        self.collect_s += rollout_s
        self.update_t0 = now
        row = self._row(now, rollout_s)
        for key, value in row.items():
            if key not in ("agent_steps", "rollout_s", "update_s") and value is not None:
                self.logger.record(f"uav/{key}", value)
        with open(self.log_path, "a") as log:
            log.write(json.dumps(row) + "\n")
        self._bar_total(now)
        if self.bar is not None and row["episode_return_mean"] is not None:
            self.bar.set_postfix(ret=f"{row['episode_return_mean']:.2f}",
                                 loc=f"{row['final_success_rate'] or 0:.2f}",
                                 err=f"{row['final_translation_median_m'] or float('nan'):.2f}m")

    def _bar_total(self, now: float) -> None:
        """With ``minutes``: the bar ends where the time budget is projected to end the run."""
        if self.bar is None or self.minutes is None or self.num_timesteps <= self.start:
            return
        rate = (self.num_timesteps - self.start) / max(now - self.t0, 1e-9)
        left_s = max(60.0 * self.minutes - (now - self.t0), 0.0)
        self.bar.total = int(min(self.total, self.num_timesteps + rate * left_s))
        self.bar.refresh()

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.close()


#: Test hook: with ``UAV_STRUCT_TRAIN_INTERRUPT_AT=N`` in the environment the trainer sends itself
#: SIGINT once ``N`` agent-steps are done (an interruption at a known step, for the resume test).
INTERRUPT_HOOK = "UAV_STRUCT_TRAIN_INTERRUPT_AT"

#: What a run writes into ``--out``; ``--overwrite`` removes these first.
TRAIN_FILES = ("train.json", "model.zip", "normalization.npz", "vecnormalize.pkl", "progress.jsonl",
               "checkpoints", "tb")


class _StopRequest:
    """SIGINT and SIGTERM during training, noted and acted on at the next env step.

    The handler only records the signal: the rollout stops at the next step
    (:class:`_Boundaries`), so the run is saved at its last rollout boundary without a traceback.
    Env subprocesses are started with SIGINT ignored and SIGTERM at its default
    (:meth:`children`): a terminal's Ctrl-C, sent to the whole process group, reaches only the
    trainer. The previous handlers come back on exit.
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> _StopRequest:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._note)
        return self

    def __exit__(self, *exc: Any) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _note(self, signum: int, frame: Any) -> None:
        if self.signum is None:
            self.signum = signum

    @contextlib.contextmanager
    def children(self):
        """Around the start of env subprocesses (forked: they inherit the handlers)."""
        if not self._previous:
            yield
            return
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        try:
            yield
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, self._note)


class _Snapshot:
    """The training state at a rollout boundary: what a resumed run restores.

    (Plain classes here: the tests load this script without registering it as a module, which
    ``dataclasses`` needs.)
    """

    def __init__(self, steps: int, obs_rms: Any, ret_rms: Any, rng: Any) -> None:
        self.steps, self.obs_rms, self.ret_rms, self.rng = steps, obs_rms, ret_rms, rng


def _snapshot(model, vec) -> _Snapshot:
    from uav_struct_env.training.policy_files import capture_rng_state

    return _Snapshot(int(model.num_timesteps), copy.deepcopy(vec.obs_rms), copy.deepcopy(vec.ret_rms),
                     capture_rng_state())


def _rewind(model, vec, snap: _Snapshot) -> None:
    """Back to the boundary ``snap`` after a rollout stopped part-way (its steps are dropped)."""
    model.num_timesteps = snap.steps
    vec.obs_rms, vec.ret_rms = copy.deepcopy(snap.obs_rms), copy.deepcopy(snap.ret_rms)


def _save_checkpoint(folder, model, vec, snap: _Snapshot) -> None:
    """``step_<steps>/``: ``model.zip`` and ``normalization.npz`` (what ``evaluate_policy.py`` reads)
    and ``vecnormalize.pkl`` and ``resume.npz`` (what ``--resume`` reads; written last).

    ``model`` and ``vec`` must be at the boundary ``snap``.
    """
    from uav_struct_env.training.policy_files import (
        NORMALIZATION_FILE,
        RESUME_FILE,
        save_normalization,
        save_rng_state,
    )

    target = real_folder(folder / f"step_{snap.steps:09d}")
    with atomic_path(target / "model.zip") as tmp:
        model.save(tmp)
    save_normalization(vec, target / NORMALIZATION_FILE)
    with atomic_path(target / "vecnormalize.pkl") as tmp:
        vec.save(str(tmp))
    save_rng_state(snap.rng, target / RESUME_FILE)


def rollout_seed(seed: int, rollout: int) -> int:
    """The env seed of rollout ``rollout`` of a run seeded ``seed`` (copy ``k`` gets it ``+ k``)."""
    import numpy as np

    return int(np.random.SeedSequence([seed, rollout]).generate_state(1)[0] % 2**31)


def _reseed(model, vec, seed: int, n_envs: int, rollout: int) -> None:
    """Start every env copy on a fresh episode seeded from the run's seed stream.

    Each rollout starts from such seeded resets (an episode cut at a rollout's end is bootstrapped
    from its value, as SB3 does for every rollout's last step): a run resumed at a rollout
    boundary then sees the very episodes the uninterrupted run saw.
    """
    import numpy as np

    _seed_copies(vec.venv.venv.venv, rollout_seed(seed, rollout), n_envs)  # VecNormalize/VecMonitor/SB3
    model._last_obs = model.env.reset()
    model._last_episode_starts = np.ones((model.env.num_envs,), dtype=bool)


class _RunState:
    """What the callbacks share with :func:`main`: the stop request and the last boundary."""

    def __init__(self, stop: _StopRequest, saved: int) -> None:
        self.stop, self.saved = stop, saved
        self.snapshot: _Snapshot | None = None
        self.stopped = False


class _Boundaries:
    """At every rollout start: snapshot the state, checkpoint every ``every`` agent-steps, reseed.

    On every step: stop the rollout when a signal arrived (or the :data:`INTERRUPT_HOOK` step is
    reached, which sends SIGINT). Checkpoints are model folders ``checkpoints/step_<steps>/``
    (:func:`_save_checkpoint`), for ``evaluate_policy.py --checkpoints``' learning curve and for
    ``--resume``.
    """

    def __new__(cls, opt: dict[str, Any], folder, vec, state: _RunState):
        from stable_baselines3.common.callbacks import BaseCallback

        every, hook = opt["checkpoint_every"], os.environ.get(INTERRUPT_HOOK)

        class Boundaries(BaseCallback):
            def _on_rollout_start(self) -> None:
                snap = state.snapshot = _snapshot(self.model, vec)
                if snap.steps // every > state.saved:
                    state.saved = snap.steps // every
                    _save_checkpoint(folder, self.model, vec, snap)
                per_rollout = self.model.n_steps * self.model.env.num_envs
                _reseed(self.model, vec, opt["seed"], opt["n_envs"], snap.steps // per_rollout)

            def _on_step(self) -> bool:
                if hook and state.stop.signum is None and self.num_timesteps >= int(hook):
                    os.kill(os.getpid(), signal.SIGINT)
                state.stopped = state.stop.signum is not None
                return not state.stopped

        return Boundaries()


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
    if opt["image_size"] is not None:
        check_image_size_option(opt["config"], opt["image_size"])
    if opt["minutes"] is not None:
        check_option("minutes", opt["minutes"], 0, lo_open=True)
    check_option("learning_rate", opt["learning_rate"], 0, lo_open=True)
    check_option("gamma", opt["gamma"], 0, 1)
    check_option("ent_coef", opt["ent_coef"], 0)
    check_option("log_std_init", opt["log_std_init"])
    check_option("torch_threads", opt["torch_threads"], 1, integer=True)
    if not isinstance(opt["bootstrap_time_limit"], bool):
        raise ConfigError(f"bootstrap_time_limit must be True or False, got {opt['bootstrap_time_limit']!r}")
    for k, width in enumerate(opt["net_arch"]):
        check_option(f"net_arch[{k}]", width, 1, integer=True)
    if opt["sites"] is not None:
        check_sites(opt["sites"], opt["n_envs"])
    if opt["resume"] is not None:
        last_checkpoint(opt["resume"])
    check_output_dir(opt["out"], overwrite=opt["overwrite"] or opt["resume"] is not None)


def check_image_size_option(config: str, image_size: Any) -> None:
    """``--image-size``: a configuration that observes images, and a size its renderer draws.

    (The size itself: ``uav_struct_env.envs.config.check_image_size``, through ``make_config``.)

    Raises:
        ConfigError: naming the configuration without images, or the size and the limit it breaks.
    """
    from uav_struct_env.envs.config import make_config
    from uav_struct_env.errors import ConfigError
    from uav_struct_env.wrappers import TRAIN_CONFIGS

    train = TRAIN_CONFIGS[config]
    if not train.env.get("observe_image", True) or train.wrapper.get("drop_image", False):
        raise ConfigError(f"--image-size applies to a configuration that observes images; {config!r} has "
                          "none (image, pixels, pixels_critic, pixels_keypoints and pixels_precise do)")
    make_config(train.preset, **{**train.env, "image_size": image_size})  # the env's own limits


def check_sites(sites: Any, n_envs: int) -> None:
    """``--sites``: distinct ``paper``, ``random:N`` or site / IFC files, at most one per env copy.

    Raises:
        ConfigError: naming the bad item, or more sites than ``n_envs`` (a site without a copy).
    """
    from uav_struct_env.errors import ConfigError
    from uav_struct_env.study.sweep import parse_sites

    if not isinstance(sites, (list, tuple)) or not sites or not all(isinstance(s, str) for s in sites):
        raise ConfigError(f"sites must be a non-empty list of site names, got {sites!r}")
    if tuple(parse_sites(",".join(sites))) != tuple(sites):
        raise ConfigError(f"sites must be single sites (paper, random:N or a file), got {list(sites)}")
    if len(sites) > n_envs:
        raise ConfigError(f"--sites names {len(sites)} sites but --n-envs is {n_envs}: each site "
                          "needs at least one env copy")


def last_checkpoint(run: str | Path) -> Path:
    """The run's last checkpoint that ``--resume`` can continue from.

    Raises:
        UsageError: ``run`` is not a run folder of this script, or holds no such checkpoint.
    """
    from uav_struct_env.errors import UsageError
    from uav_struct_env.training.policy_files import RESUME_FILE

    run = Path(run)
    if not (run / "train.json").is_file():
        raise UsageError(f"--resume {str(run)!r} is not a run folder of train_viewpoint_ppo.py "
                         "(no train.json)")
    done = sorted(d for d in run.glob("checkpoints/step_*") if (d / RESUME_FILE).is_file())
    if not done:
        raise UsageError(f"--resume {str(run)!r} holds no checkpoint to continue from; start it "
                         "again with --overwrite")
    return done[-1]


def resolve_options(kwargs: dict[str, Any]) -> dict[str, Any]:
    """All options of a run: ``kwargs`` over :data:`DEFAULTS`, or with ``resume`` the run's recorded
    options (its ``train.json``) with only :data:`RESUME_OPTIONS` taken from ``kwargs``.

    Raises:
        ValueError: an unknown option, or a ``resume`` folder whose ``train.json`` is unreadable.
    """
    unknown = sorted(set(kwargs) - set(DEFAULTS) - set(ENV_OPTIONS))
    if unknown:
        raise ValueError(f"unknown options {unknown}; valid: {sorted({**DEFAULTS, **ENV_OPTIONS})}")
    base = {**DEFAULTS, **ENV_OPTIONS}
    if kwargs.get("resume") is None:
        return {**base, **kwargs}
    run = Path(kwargs["resume"])
    try:
        recorded = json.loads((run / "train.json").read_text())["options"]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ValueError(f"--resume {str(run)!r}: cannot read its train.json: {err}") from None
    recorded = {k: v for k, v in recorded.items() if k in base}
    recorded["net_arch"] = tuple(recorded.get("net_arch", base["net_arch"]))
    if recorded.get("image_size") is not None:
        recorded["image_size"] = tuple(recorded["image_size"])
    given = {k: v for k, v in kwargs.items() if k in RESUME_OPTIONS}
    return {**base, **recorded, **given, "out": str(run), "resume": str(run), "overwrite": False}


def main(**kwargs: Any) -> dict[str, Any]:
    """Train (or with ``resume`` continue a run) and save; returns the ``train.json`` summary.

    Keys: see :data:`DEFAULTS`. SIGINT or SIGTERM stops the run at the next env step: it is
    saved at its last rollout boundary (``model.zip``, a checkpoint, ``train.json`` whose
    ``interrupted`` names the signal) and the summary is returned.
    """
    opt = resolve_options(kwargs)
    check_options(opt)
    # An earlier run in "out" is refused unless overwrite=True (the error names --overwrite).
    out = prepare_output_dir(opt["out"], overwrite=opt["overwrite"] or opt["resume"] is not None)
    if opt["overwrite"]:
        remove_earlier_run(out, TRAIN_FILES)  # the old run's checkpoints and logs too
    with _StopRequest() as stop:
        return _train(opt, out, stop)


def _build(opt: dict[str, Any], out: Path, stop: _StopRequest):
    """The vector env and the PPO model: new, or restored from the resumed run's last checkpoint."""
    import numpy as np
    from stable_baselines3 import PPO
    from stable_baselines3.common.preprocessing import is_image_space
    from stable_baselines3.common.vec_env import VecNormalize

    from uav_struct_env.training.policy_files import RESUME_FILE, load_rng_state, restore_rng_state
    from uav_struct_env.wrappers import TRAIN_CONFIGS

    with stop.children():
        vec = make_vec_env(opt["config"], opt["n_envs"], opt["num_cpus"], opt["seed"],
                           opt["max_cycles"], opt["bootstrap_time_limit"], opt["sites"], opt["image_size"])
    tb = str(real_folder(out / "tb"))  # written inside --out, never through a link
    if opt["resume"] is not None:
        ckpt = last_checkpoint(opt["resume"])
        vec = VecNormalize.load(str(ckpt / "vecnormalize.pkl"), vec)
        model = PPO.load(ckpt / "model.zip", env=vec, device="cpu", tensorboard_log=tb)
        restore_rng_state(load_rng_state(ckpt / RESUME_FILE))  # after PPO.load drew its init weights
        model._last_obs = np.zeros(1)  # learn() must not reset: each rollout starts with seeded resets
        return vec, model
    # every vector key normalized; an image stays uint8 for the CNN, which scales it itself
    vectors = [k for k, s in vec.observation_space.spaces.items() if not is_image_space(s)]
    vec = VecNormalize(vec, norm_obs=True, norm_reward=True, gamma=opt["gamma"], norm_obs_keys=vectors)
    policy, policy_kwargs = "MultiInputPolicy", {"net_arch": list(opt["net_arch"]),
                                                 "log_std_init": opt["log_std_init"]}
    config = TRAIN_CONFIGS[opt["config"]]
    if config.actor_keys:  # the policy reads these keys, the value function critic_keys (or all)
        from uav_struct_env.training.asymmetric import AsymmetricActorCriticPolicy

        policy = AsymmetricActorCriticPolicy
        policy_kwargs.update(actor_keys=list(config.actor_keys), critic_keys=list(config.critic_keys),
                             image_net=config.image_net)
    model = PPO(policy, vec, n_steps=opt["n_steps"], batch_size=opt["batch_size"],
                n_epochs=opt["n_epochs"], learning_rate=opt["learning_rate"], gamma=opt["gamma"],
                ent_coef=opt["ent_coef"], tensorboard_log=tb, device="cpu", verbose=0,
                policy_kwargs=policy_kwargs)
    return vec, model


def _train(opt: dict[str, Any], out: Path, stop: _StopRequest) -> dict[str, Any]:
    import torch
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.utils import set_random_seed

    from uav_struct_env.provenance import software

    set_random_seed(opt["seed"])
    warnings.filterwarnings("ignore", "The `render_mode` attribute is not defined")
    torch.set_num_threads(opt["torch_threads"])
    made_by = software()  # the code as training starts (the checkout may change while it runs)
    vec, model = _build(opt, out, stop)
    start = int(model.num_timesteps) if opt["resume"] is not None else 0
    if start:
        _trim_progress(out / "progress.jsonl", start)
    else:
        _write_summary(out, opt, made_by, {"agent_steps": 0, "finished": False})
    state = _RunState(stop, saved=start // opt["checkpoint_every"])
    progress = _Progress(opt["total_timesteps"], opt["minutes"], opt["progress_bar"],
                         out / "progress.jsonl", start=start)
    folder = real_folder(out / "checkpoints")
    t0 = time.perf_counter()
    model.learn(total_timesteps=opt["total_timesteps"] - start, tb_log_name="ppo",
                callback=CallbackList([_Boundaries(opt, folder, vec, state), progress]),
                reset_num_timesteps=start == 0)
    wall = time.perf_counter() - t0
    final = _final_boundary(model, vec, state)
    if final.steps > start and not (folder / f"step_{final.steps:09d}").exists():
        _save_checkpoint(folder, model, vec, final)
    _save_final(out, model, vec)
    vec.close()
    steps = final.steps - start
    record = {
        "agent_steps": final.steps,
        "wall_clock_s": wall,
        "agent_steps_per_s": steps / wall if wall > 0 else float("nan"),
        # where the wall clock went: collecting rollouts (the env processes stepping, the policy
        # acting) and the gradient updates between them (the env processes idle)
        "collect_s": progress.collect_s,
        "update_total_s": progress.update_total_s,
        "n_agent_slots": vec.num_envs,
        "finished": stop.signum is None,
        "resumed_from": start or None,
        "interrupted": None if stop.signum is None else signal.Signals(stop.signum).name,
    }
    return _write_summary(out, opt, made_by, record)


def _final_boundary(model, vec, state: _RunState) -> _Snapshot:
    """The run's end state: its last boundary if a rollout stopped part-way, else the state now."""
    if state.snapshot is not None and not model.rollout_buffer.full:
        _rewind(model, vec, state.snapshot)
        return state.snapshot
    return _snapshot(model, vec)


def _save_final(out: Path, model, vec) -> None:
    from uav_struct_env.training.policy_files import NORMALIZATION_FILE, save_normalization

    with atomic_path(out / "model.zip") as tmp:
        model.save(tmp)
    with atomic_path(out / "vecnormalize.pkl") as tmp:
        vec.save(str(tmp))
    save_normalization(vec, out / NORMALIZATION_FILE)


def _write_summary(out: Path, opt: dict[str, Any], made_by: Any, record: dict[str, Any]) -> dict[str, Any]:
    """``train.json``: the options, ``record`` and, so that a later change of the named config
    does not change this record, what ``--config`` named when this run trained and the code."""
    from uav_struct_env.provenance import settings_line

    shown = {k: v for k, v in opt.items() if k not in ("out", "overwrite", "progress_bar")}
    summary = {
        "options": {k: (list(v) if isinstance(v, tuple) else v) for k, v in opt.items()},
        **record,
        "train_config": _resolved_config(opt["config"], opt["max_cycles"], opt["image_size"]),
        "software": made_by,
        "settings": settings_line(shown, made_by),
    }
    atomic_write_json(out / "train.json", summary, indent=2)
    return summary


def _trim_progress(path: Path, steps: int) -> None:
    """Keep the ``progress.jsonl`` rows up to ``steps`` (a resumed run writes the later ones again)."""
    if not path.is_file():
        return
    rows = [line for line in path.read_text().splitlines() if json.loads(line)["agent_steps"] <= steps]
    atomic_write_text(path, "".join(f"{line}\n" for line in rows))


def _resolved_config(name: str, max_cycles: int | None,
                     image_size: tuple[int, int] | None = None) -> dict[str, Any]:
    """The configuration trained on (the named one with ``--max-cycles``, ``--image-size``), JSON-ready.

    ``evaluate_policy.py`` rebuilds the env from it, so a run keeps its meaning when the named
    configuration changes later (as ``state`` did from ``paper`` to ``robust`` association).
    """
    from uav_struct_env.wrappers import TRAIN_CONFIGS

    c = TRAIN_CONFIGS[name]
    overrides = _env_overrides(max_cycles, image_size)
    return (c.replace(env=overrides) if overrides else c).as_dict()


def _parse(argv: list[str] | None = None) -> dict[str, Any]:
    p = CommandParser(prog="train_viewpoint_ppo.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=DEFAULTS["out"], help="output folder")
    p.add_argument("--overwrite", action="store_true",
                   help="train into an --out folder that already holds files (else refused)")
    p.add_argument("--config", default=DEFAULTS["config"],
                   help="TRAIN_CONFIGS name: state | image | pixels | pixels_critic (the policy reads "
                        "pixels' keys, its value function state's) | pixels_keypoints (the same, its image "
                        "CNN read out as keypoints) | pixels_precise (pixels_critic with the "
                        "log_error reward)")
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
    p.add_argument("--image-size", type=image_size_argument, default=None, metavar="WxH",
                   help="override the observed image's size (a configuration with images; the batched "
                        "renderer draws up to 160x120)")
    p.add_argument("--seed", type=int, default=DEFAULTS["seed"])
    p.add_argument("--torch-threads", type=int, default=DEFAULTS["torch_threads"],
                   help="threads of the policy's updates (1 suits the state MLP; the env copies' "
                   "processes idle while an image policy's CNN updates, so 2 cores can both work there)")
    p.add_argument("--no-progress-bar", dest="progress_bar", action="store_false")
    p.add_argument("--bootstrap-time-limit", action=argparse.BooleanOptionalAction,
                   default=DEFAULTS["bootstrap_time_limit"],
                   help="bootstrap the value where an episode ends at its time limit (SB3's "
                        "TimeLimit.truncated; on by default); --no-bootstrap-time-limit: the limit "
                        "counts as a terminal state, as before 2026-11-27")
    p.add_argument("--sites", default=None, metavar="LIST",
                   help="train on several buildings: comma-separated paper, random:N, random:A-B "
                        "(the buildings evaluate_policy.py --site random --site-seed N draws), site or "
                        "IFC files; env copy k stands on the (k mod count)-th (default: the "
                        "configuration's site, the paper's)")
    p.add_argument("--resume", default=None, metavar="RUN",
                   help="continue the run in folder RUN from its last checkpoint, with its recorded "
                   "options and seed stream (only --total-timesteps, --minutes and "
                   "--no-progress-bar may be given anew)")
    args = vars(p.parse_args(argv))
    args["net_arch"] = tuple(args["net_arch"])
    if args["sites"] is not None:  # "paper,random:100-102" -> its sites (a bad list: refused in check_sites)
        from uav_struct_env.errors import ConfigError
        from uav_struct_env.study.sweep import parse_sites

        try:
            args["sites"] = parse_sites(args["sites"])
        except ConfigError as err:
            p.error(f"--sites: {err}")
    if args["resume"] is not None:  # the run's own options, but for those given here
        return {"resume": args["resume"],
                **{k: args[k] for k in RESUME_OPTIONS if args[k] != DEFAULTS[k]}}
    return args


def _run(argv: list[str] | None = None) -> int:
    """The command: train, print the summary; one line and status 130/143 after SIGINT/SIGTERM."""
    prog = "train_viewpoint_ppo.py"
    options = _parse(argv)
    try:  # every input before any work
        check_options(resolve_options(options))
    except INPUT_ERRORS as err:
        return refuse(prog, err)
    try:
        summary = main(**options)
    except OutputBusyError as err:  # another run took --out since the check
        return refuse(prog, err)
    except OSError as err:  # e.g. the disk filled up
        return refuse(prog, err, status=1)
    if summary["interrupted"] is not None:
        out = summary["options"]["out"]
        print(f"{prog}: interrupted by {summary['interrupted']} after {summary['agent_steps']} "
              f"agent-steps; saved in {out} (continue with --resume {out})", file=sys.stderr)
        return 128 + signal.Signals[summary["interrupted"]].value
    print(json.dumps({k: v for k, v in summary.items() if k != "options"}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(_run())
