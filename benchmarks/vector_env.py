"""Throughput of the vector env (``uav_struct_env.vector``) beside the single wrapped env, per core.

In this one process: the wrapped env of a training configuration (``state`` by default) stepped
alone, as ``benchmarks/wrapper_throughput.py`` steps it, and :func:`~uav_struct_env.vector.make_vector_env`
with K = 1, 4, 16 copies (seeds ``seed + k``, the paper site with its own textures per copy, or
``--site random``: one random site per copy), all under the same ``hold`` (hover) or seeded
``random`` actions, episodes of 30 steps autoreset. The measurements alternate (single, K = 1, 4,
16, then again) ``--repeats`` times, so the figures of one round share the machine's load.

With ``--sb3`` two more rows at the largest K, both stepped through Stable-Baselines3's ``VecEnv``
API: ``SB3VecEnv`` over the vector env, and the path ``examples/train_viewpoint_ppo.py`` takes
today (``StepInfos`` + SuperSuit's ``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1``,
its K copies in this process).

One agent-step is one agent's observation. ``agent_steps_per_cpu_s`` (agent-steps per second of
this process's CPU time) is the per-core figure; ``agent_steps_per_s`` is wall-clock, lower when
other processes share the cores (``uptime``'s load is printed).

    .venv/bin/python benchmarks/vector_env.py --steps 4000
    .venv/bin/python benchmarks/vector_env.py --config state --ks 1 4 16 --policy random --site random
    .venv/bin/python benchmarks/vector_env.py --sb3   # SB3VecEnv beside SuperSuit at K = 16
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np


def _actions(policy: str, rng: np.random.Generator, n: int) -> np.ndarray:
    if policy == "random":
        return rng.uniform(-1, 1, (n, 5)).astype(np.float32)
    return np.zeros((n, 5), np.float32)


def measure_single(env, steps: int, policy: str, seed: int) -> tuple[float, float]:
    """(agent-steps per wall second, per CPU second) of the single wrapped env."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    n, t0, c0 = 0, time.perf_counter(), time.process_time()
    while n < steps:
        if not env.agents:
            env.reset()
        acts = _actions(policy, rng, len(env.agents))
        obs, *_ = env.step(dict(zip(env.agents, acts, strict=True)))
        n += len(obs)
    return n / (time.perf_counter() - t0), n / (time.process_time() - c0)


def measure_vector(vec, steps: int, policy: str, seed: int) -> tuple[float, float]:
    """(agent-steps per wall second, per CPU second) of the vector env."""
    rng = np.random.default_rng(seed)
    vec.reset(seed=seed)
    n, t0, c0 = 0, time.perf_counter(), time.process_time()
    while n < steps:
        vec.step(_actions(policy, rng, vec.num_slots))
        n += vec.num_slots
    return n / (time.perf_counter() - t0), n / (time.process_time() - c0)


def measure_sb3(venv, steps: int, policy: str, seed: int) -> tuple[float, float]:
    """(agent-steps per wall second, per CPU second) of an SB3 ``VecEnv`` (one slot per agent)."""
    rng = np.random.default_rng(seed)
    venv.reset()
    n, t0, c0 = 0, time.perf_counter(), time.process_time()
    while n < steps:
        venv.step(_actions(policy, rng, venv.num_envs))
        n += venv.num_envs
    return n / (time.perf_counter() - t0), n / (time.process_time() - c0)


def sb3_envs(config: str, k: int, site: str, seed: int) -> dict[str, object]:
    """SB3 ``VecEnv`` s of ``k`` copies: ours, and SuperSuit's as the PPO example builds it."""
    import supersuit as ss

    from uav_struct_env.vector import SB3VecEnv, make_vector_env
    from uav_struct_env.wrappers import StepInfos, make_train_env

    ours = SB3VecEnv(make_vector_env(config, k, site=site))
    ours.seed(seed)
    env = StepInfos(make_train_env(config, site=site), keys=("localization",), time_limit=True)
    supersuit = ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(env), k, num_cpus=0,
                                      base_class="stable_baselines3")
    return {f"SB3VecEnv K={k}": ours, f"SuperSuit K={k}": supersuit}


def main(config: str = "state", steps: int = 4000, ks: tuple[int, ...] = (1, 4, 16), policy: str = "hold",
         seed: int = 0, site: str = "paper", repeats: int = 2, sb3: bool = False,
         warm_episodes: int = 2) -> dict:
    warnings.filterwarnings("ignore", "The `render_mode` attribute is not defined")
    from tqdm import tqdm

    from uav_struct_env.vector import make_vector_env
    from uav_struct_env.wrappers import make_train_env

    single = make_train_env(config, site=site)
    vecs = {k: make_vector_env(config, k, site=site) for k in ks}
    warm = warm_episodes * 31 * len(single.possible_agents)  # whole episodes: resets and every path warm
    measure_single(single, warm, policy, seed)
    for vec in vecs.values():
        measure_vector(vec, warm * vec.num_envs, policy, seed)
    venvs = sb3_envs(config, max(ks), site, seed) if sb3 else {}
    for venv in venvs.values():
        measure_sb3(venv, warm * max(ks), policy, seed)
    rows: dict[str, list[tuple[float, float]]] = {"single": [], **{f"K={k}": [] for k in ks}}
    rows.update({name: [] for name in venvs})
    with tqdm(total=repeats * len(rows), desc="vector_env", unit="run") as bar:
        for _ in range(repeats):
            rows["single"].append(measure_single(single, steps, policy, seed))
            bar.update()
            for k, vec in vecs.items():
                rows[f"K={k}"].append(measure_vector(vec, steps, policy, seed))
                bar.update()
            for name, venv in venvs.items():
                rows[name].append(measure_sb3(venv, steps, policy, seed))
                bar.update()
    for env in (single, *vecs.values(), *venvs.values()):
        env.close()
    print(f"config {config}, policy {policy}, site {site}, {steps} agent-steps per run, {repeats} rounds, "
          f"load average (1 min) {os.getloadavg()[0]:.2f}, {os.cpu_count()} cores")
    print(f"{'env':18s} {'agent_steps_per_s':>20s} {'agent_steps_per_cpu_s':>24s} {'cpu_vs_single':>14s}")
    base = float(np.median([c for _, c in rows["single"]]))
    out = {}
    for name, runs in rows.items():
        wall = [w for w, _ in runs]
        cpu = [c for _, c in runs]
        out[name] = {"agent_steps_per_s": wall, "agent_steps_per_cpu_s": cpu}
        print(f"{name:18s} {_span(wall):>20s} {_span(cpu):>24s} {np.median(cpu) / base:>13.2f}x")
    return out


def _span(values: list[float]) -> str:
    lo, hi = min(values), max(values)
    return f"{lo:,.0f}" if round(lo) == round(hi) else f"{lo:,.0f}-{hi:,.0f}"


if __name__ == "__main__":
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    p.add_argument("--config", default="state", help="training configuration (wrappers.configs)")
    p.add_argument("--steps", type=int, default=4000, help="agent-steps per measurement")
    p.add_argument("--ks", type=int, nargs="+", default=[1, 4, 16], help="vector env sizes K")
    p.add_argument("--policy", default="hold", choices=("hold", "random"),
                   help="actions: hold still or random")
    p.add_argument("--seed", type=int, default=0, help="first copy's seed (copy k: seed + k)")
    p.add_argument("--site", default="paper", help="'paper', 'random' (one per copy) or a site file")
    p.add_argument("--repeats", type=int, default=2, help="alternating rounds")
    p.add_argument("--warm-episodes", type=int, default=2,
                   help="untimed episodes per env before the rounds (resets and every path warm)")
    p.add_argument("--sb3", action="store_true",
                   help="also SB3VecEnv and SuperSuit's vector env at the largest K (SB3's VecEnv API)")
    args = p.parse_args()
    if args.steps < 1 or args.repeats < 1 or min(args.ks) < 1:
        p.error("--steps, --repeats and every K must be at least 1")
    if args.warm_episodes < 0:
        p.error(f"--warm-episodes must be 0 or more, not {args.warm_episodes}")
    main(args.config, args.steps, tuple(args.ks), args.policy, args.seed, args.site, args.repeats, args.sb3,
         args.warm_episodes)
