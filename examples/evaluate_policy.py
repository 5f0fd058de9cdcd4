"""Compare a trained viewpoint policy with random and scripted baselines over the same seeds.

Policies: ``ppo`` (a model saved by ``train_viewpoint_ppo.py``, deterministic actions) and the
scripted baselines of :mod:`uav_struct_env.baselines`: ``random`` (uniform actions), ``hold``
(hover at the starting viewpoint), ``orbit`` (fly sideways around the building at 5 m/s, turning
towards its centre from the estimated position) and ``greedy`` (each step the action whose
predicted viewpoint has the lowest Cramér-Rao bound of the agent's own position). Every policy runs
the same ``episodes`` episodes, seeds ``seed, seed + 1, ...`` (training starts at small seeds and
continues each copy's stream, so the default 10_000 + i are unseen).

Metric definitions (the same for every policy):

* final step: each agent's localization at the last step of the episode (the viewpoint the policy
  ended at; a crash's last step counts): success rate; median / P90 translation error over the
  successful ones (the paper's convention);
* all steps: the same over every agent-step after the first action;
* mean reward: the agents' episode returns, averaged;
* distance to the building: each agent's horizontal distance from its true camera position to the
  centre of the building's footprint, at the start (after reset) and at the end of the episode
  (median over agent-episodes): did the policy fly closer?

Several training seeds: ``--model RUN [RUN ...]`` evaluates each run's model on the same episodes
(rows ``ppo:<folder name>``); the ``ppo`` row pools them, and ``across_runs`` in the JSON holds the
mean, standard deviation, minimum and maximum over runs of each final-step figure.

    .venv/bin/python examples/evaluate_policy.py --model runs/ppo_s0 runs/ppo_s1 runs/ppo_s2 \
        --episodes 20 --plot evaluation.png --json-out evaluation.json

    .venv/bin/python examples/evaluate_policy.py --model runs/ppo_state --episodes 20 \
        --plot runs/ppo_state/evaluation.png --json-out runs/ppo_state/evaluation.json

Another building than the one trained on (the paper's): ``--site random --site-seed N`` draws a
parametric building (``site="random"`` of the env, from its ``texture_seed``), ``--site
my_site.json`` or ``--site model.ifc`` reads one; the starts are placed around that building.

Learning curve: ``--checkpoints RUN [RUN ...]`` evaluates every checkpoint folder
(``RUN/checkpoints/step_<N>/``, written by ``train_viewpoint_ppo.py``, and the run's final
``model.zip`` where no checkpoint holds it) of each training run (one per training seed)
deterministically on the same episodes, and plots the final-step success rate,
median translation error and mean return against agent-steps: the median over runs with a band
from the lowest to the highest run where several are given.

    .venv/bin/python examples/evaluate_policy.py --checkpoints runs/ppo_seed0 runs/ppo_seed1 \
        --episodes 10 --plot curve.png --json-out curve.json

Nothing is written unless asked: ``--plot`` and ``--json-out`` name the files (no default path).
Each says how it was made: the JSON has ``"software"`` (version, git commit) and ``"settings"``,
the settings line (:func:`uav_struct_env.provenance.settings_line`: the software, then every
option given); the figure carries the same line in its PNG ``Settings`` text chunk
(:func:`uav_struct_env.provenance.png_settings` reads it).

A model folder is read without unpickling anything from it (unpickling runs whatever code the
file names): ``model.zip`` through :func:`uav_struct_env.training.policy_files.load_ppo` and the
observation statistics from ``normalization.npz``. A folder from before ``normalization.npz``
holds only SB3's ``vecnormalize.pkl``; it is read only with ``--trust-pickle``.
"""

from __future__ import annotations

import contextlib
import json
import pickle
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from uav_struct_env.baselines import BASELINES, make_baseline
from uav_struct_env.errors import UsageError
from uav_struct_env.outputs import atomic_write_json, save_figure
from uav_struct_env.validate import (
    INPUT_ERRORS,
    CommandParser,
    check_input_file,
    check_option,
    check_output_file,
    refuse,
)

POLICIES = ("ppo", *BASELINES)
DEFAULTS: dict[str, Any] = {
    "model": None,
    "config": None,
    "association": None,
    "episodes": 20,
    "seed": 10_000,
    "policies": POLICIES,
    "plot": None,
    "json_out": None,
    "overwrite": False,
    "max_cycles": None,
    "site": None,
    "site_seed": None,
    "trust_pickle": False,
    "checkpoints": None,
}


def _check_shapes(norm, space, path: Path) -> None:
    """Raise ValueError unless every normalization entry has its observation key's shape."""
    if norm is None:
        return
    for key, mean in norm.mean.items():
        sub = space.spaces.get(key) if hasattr(space, "spaces") else None
        if sub is None or tuple(mean.shape) != tuple(sub.shape):
            want = None if sub is None else tuple(sub.shape)
            raise ValueError(f"{str(path)!r}: entry {key!r} has shape {tuple(mean.shape)}, the "
                             f"observation {want}")


class PpoPolicy:
    """A saved SB3 PPO model plus its observation normalization, read without unpickling.

    ``trust_pickle``: for a folder without ``normalization.npz``, unpickle SB3's
    ``vecnormalize.pkl`` (only for a folder whose source you trust).
    """

    def __init__(self, model_dir: str | Path, env, *, trust_pickle: bool = False) -> None:
        from uav_struct_env.training.policy_files import NORMALIZATION_FILE, load_normalization, load_ppo

        d = Path(model_dir)
        agent = env.possible_agents[0]
        stats, pickled = d / NORMALIZATION_FILE, d / "vecnormalize.pkl"
        try:
            self.model = load_ppo(d / "model.zip", env.observation_space(agent), env.action_space(agent))
            self.norm = load_normalization(stats) if stats.exists() else None
            _check_shapes(self.norm, env.observation_space(agent), stats)
        except (ValueError, OSError) as err:  # not a model folder of train_viewpoint_ppo.py
            raise UsageError(f"--model {str(d)!r}: {err}") from None
        if self.norm is None and pickled.exists():
            if not trust_pickle:
                raise UsageError(
                    f"--model {str(d)!r} has vecnormalize.pkl but no {NORMALIZATION_FILE}; loading it "
                    "would unpickle (run code from) that file: pass --trust-pickle if you trust its "
                    "source, or retrain to get normalization.npz"
                )
            with open(pickled, "rb") as f:
                self.norm = pickle.load(f).normalize_obs  # asked for by --trust-pickle

    def __call__(self, obs: dict[str, dict[str, np.ndarray]], env) -> dict[str, np.ndarray]:
        agents = list(obs)
        batch = {k: np.stack([obs[a][k] for a in agents]) for k in obs[agents[0]]}
        if self.norm is not None:
            batch = self.norm(batch)
        actions, _ = self.model.predict(batch, deterministic=True)
        return {a: actions[i].astype(np.float32) for i, a in enumerate(agents)}


def building_centre(env) -> np.ndarray:
    """The centre ``(x, y)`` of the footprint of the building ``env`` flies around (metres)."""
    return np.asarray(env.unwrapped.site.center[:2], dtype=np.float64)


def _distance(info: dict, centre: np.ndarray) -> float:
    return float(np.hypot(*(np.asarray(info["world_from_cam"])[:2, 3] - centre)))


def run_policy(policy, env, seeds) -> dict[str, Any]:
    """Roll ``policy`` over ``seeds``: per-agent final-step and all-step localization records,
    episode returns and each agent's start / end distance to the building centre."""
    final, steps, returns, start, end = [], [], [], [], []
    for seed in seeds:
        obs, infos = env.reset(seed=int(seed))
        centre = building_centre(env)
        last = {a: infos[a]["localization"] for a in obs}
        start += [_distance(infos[a], centre) for a in obs]
        where = {a: _distance(infos[a], centre) for a in obs}
        ret = dict.fromkeys(obs, 0.0)
        while env.agents:
            live = {a: obs[a] for a in env.agents}
            obs, rew, term, trunc, infos = env.step(policy(live, env))
            for a in rew:
                ret[a] += rew[a]
                last[a] = infos[a]["localization"]
                where[a] = _distance(infos[a], centre)
                steps.append(last[a])
        final += list(last.values())
        returns += list(ret.values())
        end += list(where.values())
    return {"final": final, "steps": steps, "returns": returns, "start_distance_m": start,
            "end_distance_m": end}


def summarize(records: list[dict]) -> dict[str, float]:
    ok = np.array([r["success"] for r in records], bool)
    err = np.array([r["translation_error_m"] for r in records], float)[ok]
    return {
        "n": len(records),
        "successes": int(ok.sum()),
        "success_rate": float(ok.mean()) if len(ok) else float("nan"),
        "translation_median_m": float(np.median(err)) if len(err) else float("nan"),
        "translation_p90_m": float(np.percentile(err, 90)) if len(err) else float("nan"),
    }


def policy_result(rec: dict[str, Any], seconds: float) -> dict[str, Any]:
    """The summary of one policy's :func:`run_policy` records."""
    return {
        "final_step": summarize(rec["final"]),
        "all_steps": summarize(rec["steps"]),
        "mean_return": float(np.mean(rec["returns"])),
        "start_distance_median_m": float(np.median(rec["start_distance_m"])),
        "end_distance_median_m": float(np.median(rec["end_distance_m"])),
        "wall_clock_s": seconds,
        "_final": rec["final"],
    }


def pool(recs: list[dict[str, Any]]) -> dict[str, Any]:
    """Several runs' :func:`run_policy` records as one."""
    return {k: [x for rec in recs for x in rec[k]] for k in recs[0]}


#: The final-step figures compared across training runs (``across_runs``).
ACROSS_RUNS = ("success_rate", "translation_median_m", "translation_p90_m")


def across_runs(results: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Mean, standard deviation (ddof 0), minimum and maximum over runs of each final-step figure
    and of the median end distance."""
    out = {}
    for key in (*ACROSS_RUNS, "end_distance_median_m"):
        v = np.array([r[key] if key in r else r["final_step"][key] for r in results], float)
        out[key] = {"mean": float(v.mean()), "std": float(v.std()), "min": float(v.min()),
                    "max": float(v.max()), "runs": len(v)}
    return out


def _error_cdfs(ax, results: dict[str, dict]) -> None:
    """Each policy's final-step error CDF over all its agent-episodes, ``k of N`` localized.

    Every policy gets a line that spans the axis (a CDF from a single success, or none, would
    otherwise be an invisible step of zero length), with a dot at each success.
    """
    errors = {n: np.sort([r["translation_error_m"] for r in results[n]["_final"] if r["success"]])
              for n in results}
    found = np.concatenate([e for e in errors.values() if len(e)] or [np.array([1.0])])
    lo, hi = float(found.min()) / 1.5, float(found.max()) * 1.5
    for i, (n, err) in enumerate(errors.items()):
        total = results[n]["final_step"]["n"]
        frac = np.arange(1, len(err) + 1) / total
        xs, ys = np.r_[lo, err, hi], np.r_[0.0, frac, frac[-1] if len(frac) else 0.0]
        ax.step(xs, ys, where="post", color=f"C{i}", label=f"{n} ({len(err)} of {total})")
        ax.plot(err, frac, ".", color=f"C{i}", ms=3)


def plot(results: dict[str, dict], path: str | Path, settings: str | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    names = list(results)
    fig, axes = plt.subplots(1, 2, figsize=(9.5, 3), dpi=90)
    rates = [results[n]["final_step"]["success_rate"] for n in names]
    axes[0].bar(names, rates, color="0.5")
    spread = results.get("ppo", {}).get("across_runs")
    if spread:  # the pooled ppo bar, with the lowest and highest training run
        s = spread["success_rate"]
        i = names.index("ppo")
        axes[0].errorbar([i], [rates[i]], yerr=[[rates[i] - s["min"]], [s["max"] - rates[i]]],
                         color="k", capsize=4)
    axes[0].tick_params(axis="x", labelrotation=30, labelsize=8)
    for label in axes[0].get_xticklabels():  # each label ends under its bar: long run names do not overlap
        label.set_horizontalalignment("right")
        label.set_rotation_mode("anchor")
    axes[0].set_ylim(0, 1)
    axes[0].set_ylabel("localized at final step")
    _error_cdfs(axes[1], results)
    axes[1].set_xscale("log")
    axes[1].xaxis.set_minor_formatter(NullFormatter())  # labels at the decades only: no overlap
    axes[1].set_xlabel("final-step translation error [m] (legend: localized of agent-episodes)")
    axes[1].set_ylabel("fraction of agent-episodes")
    axes[1].set_ylim(0, 1)
    axes[1].legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))  # beside the curves
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, settings=settings)
    plt.close(fig)


def _of(summary: dict[str, float]) -> str:
    """``k of N``: the successes a median is taken over, of all records."""
    return f"{summary['successes']} of {summary['n']}"


def table(results: dict[str, dict]) -> str:
    rows = [
        "| policy | success (final) | median / P90 t-error final [m] (of n) | success (all steps) "
        "| median / P90 t-error all steps [m] (of n) | mean return | distance start -> end [m] |",
        "|---|---|---|---|---|---|---|",
    ]
    for n, r in results.items():
        f, s = r["final_step"], r["all_steps"]
        rows.append(
            f"| {n} | {f['success_rate']:.2f} | {f['translation_median_m']:.3f} / "
            f"{f['translation_p90_m']:.3f} ({_of(f)}) | {s['success_rate']:.2f} | "
            f"{s['translation_median_m']:.3f} / {s['translation_p90_m']:.3f} ({_of(s)}) | "
            f"{r['mean_return']:.2f} | {r['start_distance_median_m']:.1f} -> "
            f"{r['end_distance_median_m']:.1f} |"
        )
    spread = results.get("ppo", {}).get("across_runs")
    if spread:
        rows.append("")
        rows.append(f"Across {spread['success_rate']['runs']} training runs (mean ± std, [min, max]): "
                    + "; ".join(f"{k} {v['mean']:.3f} ± {v['std']:.3f} [{v['min']:.3f}, {v['max']:.3f}]"
                                for k, v in spread.items()))
    return "\n".join(rows)


def checkpoint_folders(run: str | Path) -> list[tuple[int, Path]]:
    """``(agent_steps, folder)`` of every checkpoint of a training run, in step order.

    The run's final model (``RUN/model.zip``, at the steps its ``train.json`` records) is the
    last point when no checkpoint holds it (a run from before the trainer saved a last checkpoint).
    """
    run = Path(run)
    root = run / "checkpoints" if (run / "checkpoints").is_dir() else run
    found = []
    for d in root.glob("step_*"):
        if (d / "model.zip").is_file() and d.name[5:].isdigit():
            found.append((int(d.name[5:]), d))
    final = _final_steps(run)
    if final is not None and found and final not in {steps for steps, _ in found}:
        found.append((final, run))
    return sorted(found)


def _final_steps(run: Path) -> int | None:
    """The agent-steps of a run folder's own ``model.zip`` (its ``train.json``), or None."""
    try:
        steps = json.loads((run / "train.json").read_text())["agent_steps"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return int(steps) if (run / "model.zip").is_file() and isinstance(steps, int) and steps > 0 else None


def learning_curve(runs: list[str], env, seeds: list[int]) -> dict[str, list[dict]]:
    """Evaluate every checkpoint of every run on ``seeds``: ``{run: [point, ...]}``."""
    from tqdm.auto import tqdm

    jobs = [(run, steps, folder) for run in runs for steps, folder in checkpoint_folders(run)]
    curves: dict[str, list[dict]] = {run: [] for run in runs}
    for run, steps, folder in tqdm(jobs, unit="checkpoint", desc="learning curve"):
        rec = run_policy(PpoPolicy(folder, env), env, seeds)
        final = summarize(rec["final"])
        curves[run].append({"agent_steps": steps, "final_success_rate": final["success_rate"],
                            "final_translation_median_m": final["translation_median_m"],
                            "mean_return": float(np.mean(rec["returns"]))})
    return curves


CURVE_METRICS = (("final_success_rate", "localized at final step"),
                 ("final_translation_median_m", "final-step median t-error [m]"),
                 ("mean_return", "deterministic episode return"))


def plot_curve(curves: dict[str, list[dict]], path: str | Path, settings: str | None = None) -> None:
    """Each metric against agent-steps: the median over runs, a min-max band over runs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import EngFormatter, MaxNLocator

    fig, axes = plt.subplots(1, len(CURVE_METRICS), figsize=(11, 3), dpi=90)
    steps = sorted({p["agent_steps"] for c in curves.values() for p in c})
    for ax, (key, label) in zip(axes, CURVE_METRICS, strict=True):
        table = np.full((len(curves), len(steps)), np.nan)
        for i, c in enumerate(curves.values()):
            for p in c:
                table[i, steps.index(p["agent_steps"])] = p[key]
        with warnings.catch_warnings():  # a step no run reached, or no success there
            warnings.simplefilter("ignore", RuntimeWarning)
            mid, lo, hi = (np.nanmedian(table, 0), np.nanmin(table, 0), np.nanmax(table, 0))
        ax.plot(steps, mid, marker="o", color="C0", label=f"median of {len(curves)} run(s)")
        if len(curves) > 1:
            ax.fill_between(steps, lo, hi, color="C0", alpha=0.25, label="min-max over runs")
        ax.set_xlabel("agent-steps")
        ax.xaxis.set_major_locator(MaxNLocator(nbins=4, integer=True))  # labels that do not overlap
        ax.xaxis.set_major_formatter(EngFormatter(sep=""))  # 250k, 1.5M
        ax.set_ylabel(label)
    axes[0].set_ylim(0, 1.02)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, settings=settings)
    plt.close(fig)


def model_folders(model: str | Path | list | tuple | None) -> list[str]:
    """``--model``: one folder or several (one per training seed)."""
    if model is None:
        return []
    return [str(model)] if isinstance(model, (str, Path)) else [str(m) for m in model]


def check_options(opt: dict[str, Any]) -> None:
    """Every option (the model folder and the output files too), before any work.

    Raises:
        UsageError / OutputExistsError / ConfigError: naming the option and what was expected.
    """
    from uav_struct_env.errors import ConfigError
    from uav_struct_env.wrappers import TRAIN_CONFIGS

    bad = [p for p in opt["policies"] if p not in POLICIES]
    if bad:
        raise ValueError(f"unknown policies {bad}; valid: {POLICIES}")
    if opt["config"] is not None and opt["config"] not in TRAIN_CONFIGS:
        raise ConfigError(f"config must be one of {sorted(TRAIN_CONFIGS)}, got {opt['config']!r}")
    if opt["association"] not in (None, "paper", "robust"):
        raise ConfigError(f"association must be 'paper' or 'robust', got {opt['association']!r}")
    check_option("episodes", opt["episodes"], 1, integer=True)
    check_option("seed", opt["seed"], 0, integer=True)
    if opt["max_cycles"] is not None:
        check_option("max_cycles", opt["max_cycles"], 1, integer=True)
    if opt["site"] is not None:  # the env's own rule for a site (ConfigError naming it)
        from uav_struct_env.envs import make_config

        make_config("train", site=opt["site"])
    if opt["site_seed"] is not None:
        check_option("site_seed", opt["site_seed"], 0, integer=True)
    for run in opt["checkpoints"] or ():
        if not checkpoint_folders(run):
            raise UsageError(f"--checkpoints {str(run)!r} holds no checkpoints/step_<N>/model.zip "
                             "(a folder written by train_viewpoint_ppo.py)")
    if "ppo" in opt["policies"] and not opt["checkpoints"]:
        if not opt["model"]:
            raise ValueError("policy 'ppo' needs model=<directory with model.zip> (or a list of them)")
        for folder in model_folders(opt["model"]):
            check_input_file(Path(folder) / "model.zip", option="--model", what="model.zip")
        names = [Path(f).name for f in model_folders(opt["model"])]
        if len(set(names)) < len(names):
            raise UsageError(f"--model folders must have distinct names (the rows are named after "
                             f"them), got {names}")
    for option, path in (("--plot", opt["plot"]), ("--json-out", opt["json_out"])):
        if path:
            check_output_file(path, overwrite=opt["overwrite"], option=option)


def env_config(opt: dict[str, Any]) -> tuple[Any, str]:
    """The configuration to evaluate in, and where it came from.

    ``--config NAME``: that :data:`~uav_struct_env.wrappers.TRAIN_CONFIGS` entry (for instance to
    evaluate a policy under another association than it was trained with). Otherwise the
    configuration the runs recorded in ``train.json`` (all the same, or refused), so a run keeps
    its meaning when the named configuration changes; ``state`` for runs that recorded none and
    for baselines alone. ``--association``, ``--max-cycles``, ``--site`` and ``--site-seed``
    apply on top.

    Raises:
        UsageError: if the runs recorded different configurations.
    """
    from uav_struct_env.training.policy_files import recorded_config
    from uav_struct_env.wrappers import TRAIN_CONFIGS

    if opt["config"] is not None:
        config, source = TRAIN_CONFIGS[opt["config"]], f"--config {opt['config']}"
    else:
        models = opt["model"] if "ppo" in opt["policies"] else None
        runs = list(opt["checkpoints"] or ()) or model_folders(models)
        try:
            found = {run: recorded_config(run) for run in runs}
        except ValueError as err:
            raise UsageError(str(err)) from None
        recorded = {run: c for run, c in found.items() if c is not None}
        if any(c != next(iter(recorded.values())) for c in recorded.values()):
            raise UsageError(
                "the runs were trained in different configurations: "
                + "; ".join(f"{run}: {c.as_dict()}" for run, c in recorded.items())
                + " -- evaluate them separately, or pass --config to evaluate all in one"
            )
        unrecorded = [str(run) for run, c in found.items() if c is None]
        if recorded:
            config, source = next(iter(recorded.values())), "recorded by the run(s) in train.json"
            if unrecorded:  # trained before runs recorded it: say so rather than assume
                source += f"; {', '.join(unrecorded)} recorded none and are evaluated in it too"
        elif runs:
            config, source = TRAIN_CONFIGS["state"], (
                "the runs recorded no configuration: `state` as named now; runs trained before "
                "it switched to robust association (2026-11-25) used paper: --association paper"
            )
        else:
            config, source = TRAIN_CONFIGS["state"], "state"
    if opt["association"] is not None:
        config = config.replace(wrapper={"association": opt["association"]})
        source += f"; --association {opt['association']}"
    if opt["max_cycles"] is not None:
        config = config.replace(env={"max_cycles": opt["max_cycles"]})
    if opt["site"] is not None:  # another building than the one trained on
        config = config.replace(env={"site": opt["site"]})
        source += f"; --site {opt['site']}"
    if opt["site_seed"] is not None:
        config = config.replace(env={"texture_seed": opt["site_seed"]})
        source += f"; --site-seed {opt['site_seed']}"
    if opt["site"] is not None and _site_name(config.env) in _training_sites(opt):
        source += " (a building these runs trained on: train.json's --sites)"
    return config, source


def _site_name(env: dict[str, Any]) -> str:
    """The ``--sites`` name of an env configuration's building: ``paper``, ``random:N`` or a file."""
    site = env.get("site", "paper")
    return f"random:{env.get('texture_seed', 0)}" if site == "random" else str(site)


def _training_sites(opt: dict[str, Any]) -> set[str]:
    """The buildings the evaluated runs trained on with ``--sites`` (their ``train.json`` options)."""
    from uav_struct_env.training.policy_files import train_json

    runs = list(opt["checkpoints"] or ()) or model_folders(opt["model"] if "ppo" in opt["policies"] else None)
    sites: set[str] = set()
    for path in filter(None, map(train_json, runs)):
        with contextlib.suppress(OSError, ValueError, AttributeError, TypeError):
            sites.update(json.loads(path.read_text()).get("options", {}).get("sites") or ())
    return sites


def run_settings(opt: dict[str, Any], config: Any) -> str:
    """The settings line of an evaluation: the software, the env configuration, every option given."""
    from uav_struct_env.provenance import settings_line

    shown = {k: v for k, v in opt.items()
             if k not in ("plot", "json_out", "overwrite", "config") and v not in (None, False)}
    return settings_line({"env": config.name, "association": config.wrapper.get("association"), **shown})


def _write_curve(opt: dict[str, Any], env, head: dict[str, Any]) -> dict[str, Any]:
    """``--checkpoints``: the learning curve, its figure and JSON; returns the summary."""
    try:
        curves = learning_curve(list(opt["checkpoints"]), env, head["seeds"])
    finally:
        env.close()
    if opt["plot"]:
        plot_curve(curves, opt["plot"], head["settings"])
    summary = {**head, "learning_curve": curves}
    if opt["json_out"]:
        atomic_write_json(opt["json_out"], summary, indent=2, default=str)
    for run, points in curves.items():
        print(run)
        for q in points:
            print(f"  {q['agent_steps']:>9d} steps: localized {q['final_success_rate']:.2f}, "
                  f"median {q['final_translation_median_m']:.3f} m, return {q['mean_return']:.2f}")
    return summary


def compare(opt: dict[str, Any], env, seeds: list[int]) -> dict[str, dict]:
    """Every policy of ``opt["policies"]`` over ``seeds``: ``{row name: summary}`` (closes ``env``)."""
    results: dict[str, dict] = {}
    models = model_folders(opt["model"]) if "ppo" in opt["policies"] else []
    try:  # the model folders are read (and refused) before any episode runs
        ppos = [PpoPolicy(m, env, trust_pickle=opt["trust_pickle"]) for m in models]
    except BaseException:
        env.close()
        raise
    for name in opt["policies"]:
        if name != "ppo":
            t0 = time.perf_counter()
            rec = run_policy(make_baseline(name, env, seed=opt["seed"]), env, seeds)
            results[name] = policy_result(rec, time.perf_counter() - t0)
            continue
        runs, t0 = [], time.perf_counter()
        for folder, ppo in zip(models, ppos, strict=True):
            t1 = time.perf_counter()
            runs.append(run_policy(ppo, env, seeds))
            if len(models) > 1:
                results[f"ppo:{Path(folder).name}"] = policy_result(runs[-1], time.perf_counter() - t1)
        results["ppo"] = policy_result(pool(runs), time.perf_counter() - t0)
        if len(models) > 1:
            results["ppo"]["across_runs"] = across_runs(
                [r for n, r in results.items() if n.startswith("ppo:")])
    env.close()
    return results


def main(**kwargs: Any) -> dict[str, Any]:
    """Evaluate; returns ``{policy: summary}``. Keys: see :data:`DEFAULTS`."""
    from uav_struct_env.provenance import software

    unknown = sorted(set(kwargs) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown options {unknown}; valid: {sorted(DEFAULTS)}")
    opt = {**DEFAULTS, **kwargs}
    opt["policies"] = list(opt["policies"])
    check_options(opt)
    warnings.filterwarnings("ignore", "The `render_mode` attribute is not defined")
    from uav_struct_env.wrappers import make_train_env

    config, source = env_config(opt)
    print(f"environment: {config.name}, {config.wrapper.get('association')} association ({source})")
    seeds = [opt["seed"] + i for i in range(opt["episodes"])]
    head = {"options": opt, "env_config": config.as_dict(), "env_config_source": source, "seeds": seeds,
            "software": software(), "settings": run_settings(opt, config)}
    env = make_train_env(config)
    if opt["checkpoints"]:
        return _write_curve(opt, env, head)
    results = compare(opt, env, seeds)
    if opt["plot"]:
        plot(results, opt["plot"], head["settings"])
    for r in results.values():
        del r["_final"]
    summary = {**head, "results": results}
    if opt["json_out"]:
        atomic_write_json(opt["json_out"], summary, indent=2, default=str)
    print(table(results))
    return summary


def _parse(argv: list[str] | None = None) -> dict[str, Any]:
    p = CommandParser(prog="evaluate_policy.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default=None, nargs="+", metavar="RUN",
                   help="folder(s) with model.zip and normalization.npz (several: one per training seed)")
    p.add_argument("--config", default=DEFAULTS["config"],
                   help="TRAIN_CONFIGS name (state | image | pixels); default: the configuration the runs "
                   "recorded in train.json (state when none did)")
    p.add_argument("--association", default=None, choices=("paper", "robust"),
                   help="evaluate with this association instead of the configuration's")
    p.add_argument("--episodes", type=int, default=DEFAULTS["episodes"], help="episodes per policy")
    p.add_argument("--seed", type=int, default=DEFAULTS["seed"], help="seed of the first episode")
    p.add_argument("--policies", nargs="+", default=list(POLICIES), choices=POLICIES)
    p.add_argument("--plot", default=None, help="write the comparison figure (PNG) to this file")
    p.add_argument("--json-out", default=None, help="write the summary (JSON) to this file")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --plot / --json-out")
    p.add_argument("--max-cycles", type=int, default=None, help="episode length (default: the config's)")
    p.add_argument("--site", default=None,
                   help="evaluate on another building: paper | random (drawn from --site-seed) | a "
                   "*.json or *.ifc site file (default: the one trained on)")
    p.add_argument("--site-seed", type=int, default=None,
                   help="the env's texture_seed, which also draws --site random (default: the config's)")
    p.add_argument("--checkpoints", nargs="+", default=None, metavar="RUN",
                   help="training run folders (one per seed): evaluate every checkpoint into a "
                   "learning curve instead of comparing policies")
    p.add_argument("--trust-pickle", action="store_true",
                   help="read a model folder's vecnormalize.pkl when it has no normalization.npz "
                   "(unpickling runs code from the file: only for folders you trust)")
    return vars(p.parse_args(argv))


if __name__ == "__main__":
    args = _parse()
    if args["model"] is None and "ppo" in args["policies"]:
        args["policies"] = [p for p in args["policies"] if p != "ppo"]
    try:  # every input before any work
        check_options(args)
    except INPUT_ERRORS as err:
        sys.exit(refuse("evaluate_policy.py", err))
    from uav_struct_env.outputs import OutputBusyError, lock_output
    from uav_struct_env.processes import interrupted_status, stop_on_sigterm

    stop_on_sigterm()  # SIGTERM ends the run as Ctrl-C does
    try:  # a second evaluation writing the same --plot / --json-out at the same time is refused
        for target in (args["plot"], args["json_out"]):
            if target:
                lock_output(target, what="output file")
        main(**args)
    except KeyboardInterrupt:
        print("evaluate_policy.py: interrupted; nothing written", file=sys.stderr)
        sys.exit(interrupted_status())
    except (UsageError, OutputBusyError) as err:  # the model folder, or another run's output
        sys.exit(refuse("evaluate_policy.py", err))
    except OSError as err:  # e.g. the disk filled up
        sys.exit(refuse("evaluate_policy.py", err, status=1))
