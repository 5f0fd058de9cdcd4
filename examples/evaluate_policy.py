"""Compare a trained viewpoint policy with random and scripted baselines over the same seeds.

Policies: ``ppo`` (a model saved by ``train_viewpoint_ppo.py``, deterministic actions), ``random``
(uniform actions), ``hold`` (hover at the starting viewpoint) and ``orbit`` (fly sideways around
the building at 5 m/s, turning towards its centre from the estimated position). Every policy runs
the same ``episodes`` episodes, seeds ``seed, seed + 1, ...`` (training starts at small seeds and
continues each copy's stream, so the default 10_000 + i are unseen).

Metric definitions (the same for every policy):

* final step: each agent's localization at the last step of the episode (the viewpoint the policy
  ended at; a crash's last step counts): success rate; median / P90 translation error over the
  successful ones (the paper's convention);
* all steps: the same over every agent-step after the first action;
* mean reward: the agents' episode returns, averaged.

    .venv/bin/python examples/evaluate_policy.py --model runs/ppo_state --episodes 20
"""

from __future__ import annotations

import argparse
import math
import pickle
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from uav_struct_env.outputs import OutputExistsError, atomic_write_json, save_figure

POLICIES = ("ppo", "random", "hold", "orbit")
DEFAULTS: dict[str, Any] = {
    "model": None,
    "config": "state",
    "episodes": 20,
    "seed": 10_000,
    "policies": POLICIES,
    "plot": "docs/figures/policy_evaluation.png",
    "json_out": None,
    "overwrite": False,
    "max_cycles": None,
}


class PpoPolicy:
    """A saved SB3 PPO model plus its VecNormalize observation statistics."""

    def __init__(self, model_dir: str | Path) -> None:
        from stable_baselines3 import PPO

        d = Path(model_dir)
        self.model = PPO.load(d / "model.zip", device="cpu")
        self.norm = None
        if (d / "vecnormalize.pkl").exists():
            with open(d / "vecnormalize.pkl", "rb") as f:
                self.norm = pickle.load(f)  # VecNormalize without its venv: normalize_obs works
            self.norm.training = False

    def __call__(self, obs: dict[str, dict[str, np.ndarray]], env) -> dict[str, np.ndarray]:
        agents = list(obs)
        batch = {k: np.stack([obs[a][k] for a in agents]) for k in obs[agents[0]]}
        if self.norm is not None:
            batch = self.norm.normalize_obs(batch)
        actions, _ = self.model.predict(batch, deterministic=True)
        return {a: actions[i].astype(np.float32) for i, a in enumerate(agents)}


class RandomPolicy:
    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs, env):
        return {a: self.rng.uniform(-1, 1, 5).astype(np.float32) for a in obs}


def hold_policy(obs, env):
    return {a: np.zeros(5, np.float32) for a in obs}


def orbit_policy(obs, env, speed: float = 0.5, gain: float = 2.0):
    """Sideways at ``speed`` x 10 m/s, yaw towards the site centre from the estimated pose."""
    c = env.unwrapped.site.center
    out = {}
    for a, o in obs.items():
        p = o["pose"][:3]
        yaw = float(o["attitude"][2])
        want = math.atan2(c[1] - p[1], c[0] - p[0])
        err = (want - yaw + math.pi) % (2 * math.pi) - math.pi
        out[a] = np.array([0.0, speed, 0.0, np.clip(gain * err, -1, 1), 0.0], np.float32)
    return out


def run_policy(policy, env, seeds) -> dict[str, Any]:
    """Roll ``policy`` over ``seeds``; per-agent final-step and all-step localization records."""
    final, steps, returns = [], [], []
    for seed in seeds:
        obs, infos = env.reset(seed=int(seed))
        last = {a: infos[a]["localization"] for a in obs}
        ret = dict.fromkeys(obs, 0.0)
        while env.agents:
            live = {a: obs[a] for a in env.agents}
            obs, rew, term, trunc, infos = env.step(policy(live, env))
            for a in rew:
                ret[a] += rew[a]
                last[a] = infos[a]["localization"]
                steps.append(last[a])
        final += list(last.values())
        returns += list(ret.values())
    return {"final": final, "steps": steps, "returns": returns}


def summarize(records: list[dict]) -> dict[str, float]:
    ok = np.array([r["success"] for r in records], bool)
    err = np.array([r["translation_error_m"] for r in records], float)[ok]
    return {
        "n": len(records),
        "success_rate": float(ok.mean()) if len(ok) else float("nan"),
        "translation_median_m": float(np.median(err)) if len(err) else float("nan"),
        "translation_p90_m": float(np.percentile(err, 90)) if len(err) else float("nan"),
    }


def plot(results: dict[str, dict], path: str | Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results)
    fig, axes = plt.subplots(1, 2, figsize=(8, 3), dpi=90)
    rates = [results[n]["final_step"]["success_rate"] for n in names]
    axes[0].bar(names, rates, color="0.5")
    axes[0].set_ylim(0, 1)
    axes[0].set_ylabel("localized at final step")
    for n in names:
        err = np.sort([r["translation_error_m"] for r in results[n]["_final"] if r["success"]])
        if len(err):
            axes[1].step(err, np.arange(1, len(err) + 1) / results[n]["final_step"]["n"], label=n)
    axes[1].set_xscale("log")
    axes[1].set_xlabel("final-step translation error [m]")
    axes[1].set_ylabel("fraction of agent-episodes")
    axes[1].set_ylim(0, 1)
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path)
    plt.close(fig)


def table(results: dict[str, dict]) -> str:
    rows = [
        "| policy | success (final) | median / P90 t-error final [m] | success (all steps) "
        "| median / P90 t-error all steps [m] | mean return |",
        "|---|---|---|---|---|---|",
    ]
    for n, r in results.items():
        f, s = r["final_step"], r["all_steps"]
        rows.append(
            f"| {n} | {f['success_rate']:.2f} | {f['translation_median_m']:.3f} / "
            f"{f['translation_p90_m']:.3f} | {s['success_rate']:.2f} | "
            f"{s['translation_median_m']:.3f} / {s['translation_p90_m']:.3f} | "
            f"{r['mean_return']:.2f} |"
        )
    return "\n".join(rows)


def main(**kwargs: Any) -> dict[str, Any]:
    """Evaluate; returns ``{policy: summary}``. Keys: see :data:`DEFAULTS`."""
    unknown = sorted(set(kwargs) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown options {unknown}; valid: {sorted(DEFAULTS)}")
    opt = {**DEFAULTS, **kwargs}
    warnings.filterwarnings("ignore", "The `render_mode` attribute is not defined")
    from uav_struct_env.wrappers import make_train_env

    policies = list(opt["policies"])
    bad = [p for p in policies if p not in POLICIES]
    if bad:
        raise ValueError(f"unknown policies {bad}; valid: {POLICIES}")
    if "ppo" in policies and opt["model"] is None:
        raise ValueError("policy 'ppo' needs model=<directory with model.zip>")
    for path in (opt["plot"], opt["json_out"]):  # checked before the evaluation runs
        if path and Path(path).exists() and not opt["overwrite"]:
            raise OutputExistsError(f"{path!r} exists; pass --overwrite to replace it")
    overrides = {} if opt["max_cycles"] is None else {"max_cycles": opt["max_cycles"]}
    env = make_train_env(opt["config"], **overrides)
    seeds = [opt["seed"] + i for i in range(opt["episodes"])]
    results: dict[str, dict] = {}
    for name in policies:
        policy = {
            "ppo": lambda: PpoPolicy(opt["model"]),
            "random": lambda: RandomPolicy(opt["seed"]),
            "hold": lambda: hold_policy,
            "orbit": lambda: orbit_policy,
        }[name]()
        t0 = time.perf_counter()
        rec = run_policy(policy, env, seeds)
        results[name] = {
            "final_step": summarize(rec["final"]),
            "all_steps": summarize(rec["steps"]),
            "mean_return": float(np.mean(rec["returns"])),
            "wall_clock_s": time.perf_counter() - t0,
            "_final": rec["final"],
        }
    env.close()
    if opt["plot"]:
        plot(results, opt["plot"])
    for r in results.values():
        del r["_final"]
    summary = {"options": {**opt, "policies": policies}, "seeds": seeds, "results": results}
    if opt["json_out"]:
        atomic_write_json(opt["json_out"], summary, indent=2, default=str)
    print(table(results))
    return summary


def _parse(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default=None, help="directory with model.zip (+ vecnormalize.pkl)")
    p.add_argument("--config", default=DEFAULTS["config"])
    p.add_argument("--episodes", type=int, default=DEFAULTS["episodes"])
    p.add_argument("--seed", type=int, default=DEFAULTS["seed"])
    p.add_argument("--policies", nargs="+", default=list(POLICIES), choices=POLICIES)
    p.add_argument("--plot", default=DEFAULTS["plot"])
    p.add_argument("--json-out", default=None)
    p.add_argument("--overwrite", action="store_true", help="replace an existing --plot / --json-out")
    p.add_argument("--max-cycles", type=int, default=None)
    return vars(p.parse_args(argv))


if __name__ == "__main__":
    args = _parse()
    if args["model"] is None and "ppo" in args["policies"]:
        args["policies"] = [p for p in args["policies"] if p != "ppo"]
    try:
        main(**args)
    except OutputExistsError as err:
        raise SystemExit(f"evaluate_policy.py: error: {err}") from None
