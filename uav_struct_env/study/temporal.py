"""Localization over time on flown trajectories: filtered vs single-frame vs the onboard prior.

    python -m uav_struct_env.study.temporal --out runs/temporal            # docs/temporal.md
    python -m uav_struct_env.study.temporal --out /tmp/t --seeds 1 --steps 40 --overwrite

Four UAVs fly a seeded scripted path around the paper's site (an orbit whose radius swings
between ``--near`` and ``--far`` m from the site centre at a low altitude, so every UAV passes
a few metres from the structure), each with its own phase. The same episode (same env seed,
same actions, same detector seed) is localized three times through
:class:`~uav_struct_env.wrappers.LocalizationWrapper` (:data:`RUNS`): frame by frame, with
``temporal=True``, and with ``temporal=True`` but no GNSS / attitude bias states (the ablation),
for each sensor model (``gnss_ins``, ``gnss_degraded``). The UAVs fly the commanded actions
plus a seeded disturbance (:class:`ActionDisturbance`, wind), which the filter does not see.
Per step and agent it records the translation and rotation error of the single-frame pose
(NaN when the frame failed), of the filtered poses (every step) and of the onboard prior
(GNSS + attitude; during an outage the last fix held), whether GNSS had a fix and whether the
frame's fix was accepted.

The scripted pilot steers by the simulator's true state (standing in for the UAV's own flight
controller); the localizers and the filter never see it: the filter's motion input is the
commanded action applied to its own estimate.

Writes ``results.json`` (per sensor model and method: share of steps with a pose, share within
0.5 m and 2 deg, translation / rotation error median and P90; for the filter the fixes gated,
and the recovery after missed fixes) and ``temporal.png`` (error over time of one UAV).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from localization.geometry.transforms import invert
from localization.metrics import median_p90, pose_errors
from uav_struct_env.outputs import prepare_output_dir, save_figure
from uav_struct_env.provenance import software
from uav_struct_env.sim.uav import ACTION_COMPONENTS, FlightLimits, UavState, wrap_angle
from uav_struct_env.study.cells import json_ready
from uav_struct_env.study.report import write_results_json
from uav_struct_env.wrappers.base import ParallelWrapper

__all__ = ["NOISES", "fly", "main", "pilot_action", "summarize", "target_position"]

NOISES = ("gnss_ins", "gnss_degraded")
#: The localizations of each episode: frame by frame, filtered, filtered without bias states.
RUNS = ("single_frame", "filtered", "filtered_no_bias")
#: What results.json reports per sensor model: the runs and the onboard prior itself.
METHODS = (*RUNS, "prior")
#: A pose is "good" within these (translation m, rotation deg).
GOOD = (0.5, 2.0)
#: The filtered error counts as recovered below this, m.
RECOVERED_M = 0.25


def target_position(t: float, agent_index: int, center: np.ndarray, near: float, far: float,
                    altitude: float, lap_s: float = 90.0, swing_s: float = 40.0) -> np.ndarray:
    """The scripted path: angle ``2 pi t / lap_s + i pi / 2``, radius swinging near..far."""
    angle = 2 * math.pi * t / lap_s + agent_index * math.pi / 2
    radius = 0.5 * (near + far) + 0.5 * (far - near) * math.cos(2 * math.pi * t / swing_s + agent_index)
    return np.array([center[0] + radius * math.cos(angle), center[1] + radius * math.sin(angle), altitude])


def pilot_action(state: UavState, goal: np.ndarray, look_at: np.ndarray, limits: FlightLimits,
                 dt: float) -> np.ndarray:
    """The normalized action (5,) that moves ``state`` to ``goal`` in ``dt`` looking at ``look_at``."""
    v = (goal - state.xyz) / dt
    c, s = math.cos(state.yaw), math.sin(state.yaw)
    forward, left = c * v[0] + s * v[1], -s * v[0] + c * v[1]
    up = v[2] / (limits.max_ascent_speed if v[2] >= 0 else limits.max_descent_speed)
    d = look_at - goal
    yaw = math.atan2(d[1], d[0])
    pitch = math.atan2(-d[2], math.hypot(d[0], d[1]))
    a = np.array([
        forward / limits.max_horizontal_speed,
        left / limits.max_horizontal_speed,
        up,
        wrap_angle(yaw - state.yaw) / (dt * limits.max_yaw_rate),
        (pitch - state.pitch) / (dt * limits.max_gimbal_rate),
    ])
    return np.clip(a, -1.0, 1.0).astype(np.float32)


class ActionDisturbance(ParallelWrapper):
    """Adds seeded white noise (sigma ``scale``) to the velocity components of the applied actions.

    Stands in for wind and tracking error: the UAV flies the disturbed command while everything
    above this wrapper (the filter's motion input) knows only the commanded one. The kinematic
    env alone would follow every command exactly. ``scale = 0.05`` is 0.5 m/s horizontally at
    the default 10 m/s limit, the filter's ``velocity_sigma``. Yaw and gimbal rates, which the
    autopilot and the gimbal hold tightly, are left as commanded.
    """

    def __init__(self, env, scale: float) -> None:
        super().__init__(env)
        self.scale = float(scale)
        self._rng = np.random.default_rng()

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset the env; ``seed`` also seeds the disturbance."""
        if seed is not None:
            self._rng = np.random.default_rng([int(seed), 0xA1D])
        return self.env.reset(seed=seed, options=options)

    def step(self, actions: dict):
        """Step with every action disturbed (agents in a fixed order: reproducible)."""
        sigma = self.scale * np.array([1.0, 1.0, 1.0, 0.0, 0.0])  # forward, left, up
        noisy = {a: np.asarray(actions[a], dtype=np.float64)
                 + sigma * self._rng.standard_normal(len(ACTION_COMPONENTS)) for a in sorted(actions)}
        return self.env.step({a: np.clip(v, -1.0, 1.0).astype(np.float32) for a, v in noisy.items()})


def _wrapped(noise: str, run: str, steps: int, miss_rate: float, false_positives: float,
             action_noise: float):
    import uav_struct_env
    from uav_struct_env.wrappers import LocalizationWrapper
    from uav_struct_env.wrappers.temporal import filter_noise_for

    env = uav_struct_env.parallel_env(
        "paper", noise=noise, observe_image=False, max_cycles=steps, landmark_sets=("all",)
    )
    filter_noise = None
    if run == "filtered_no_bias":
        filter_noise = dataclasses.replace(
            filter_noise_for(env.config.noise), estimate_gnss_bias=False, estimate_attitude_bias=False
        )
    return LocalizationWrapper(
        ActionDisturbance(env, action_noise),
        landmarks="all",
        temporal=run != "single_frame",
        filter_noise=filter_noise,
        miss_rate=miss_rate,
        false_positives=false_positives,
    )


def fly(noise: str, seed: int, steps: int, *, near: float = 9.0, far: float = 30.0, altitude: float = 8.0,
        miss_rate: float = 0.1, false_positives: float = 1.0, action_noise: float = 0.05,
        progress: bool = False) -> dict[str, dict]:
    """One seeded episode localized by each of :data:`RUNS`; per agent, per-step records.

    Returns ``{agent: {"t_<method>", "r_<method>" for every method of :data:`METHODS`,
    "gnss_fix", "fix_accepted", "fix_gated"}}`` (the last three of the ``filtered`` run), lists
    over the steps the agent flew (NaN: no pose).
    """
    runs = {name: _wrapped(noise, name, steps, miss_rate, false_positives, action_noise) for name in RUNS}
    base = runs["single_frame"].unwrapped
    center = np.array([*base.site.center[:2], 0.5 * base.site.center[2]])
    cfg = base.config
    rec: dict[str, dict] = {}
    infos = {}
    for name, w in runs.items():
        _, infos[name] = w.reset(seed=seed)
    bar = tqdm(range(steps + 1), desc=f"{noise} seed {seed}", unit="step", disable=not progress, leave=False)
    for k in bar:
        for name in runs:
            _record(rec, name, infos[name], runs[name].tracks)
        agents = list(runs["single_frame"].agents)
        if not agents or k == steps:
            break
        t_next = (k + 1) * cfg.control_period
        actions = {}
        for a in agents:
            i = base.possible_agents.index(a)
            state = base.uav_state(a)
            goal = target_position(t_next, i, center, near, far, altitude)
            actions[a] = pilot_action(state, goal, center, cfg.limits, cfg.control_period)
        for name, w in runs.items():
            out = w.step({a: actions[a] for a in w.agents})
            infos[name] = out[4]
    return rec


_KEYS = (*(f"{x}_{m}" for m in METHODS for x in "tr"), "gnss_fix", "fix_accepted", "fix_gated",
         "gnss_gated", "attitude_gated")


def _record(rec: dict, name: str, infos: dict, tracks) -> None:
    nan = float("nan")
    for agent, info in infos.items():
        r = rec.setdefault(agent, {key: [] for key in _KEYS})
        loc = info["localization"]
        if name == "single_frame":
            ok = loc["success"]
            r["t_single_frame"].append(loc["translation_error_m"] if ok else nan)
            r["r_single_frame"].append(loc["rotation_error_deg"] if ok else nan)
            gt = invert(info["world_from_cam"])
            t, d = pose_errors(invert(info["prior_world_from_cam"]), gt)
            r["t_prior"].append(float(t))
            r["r_prior"].append(float(d))
            continue
        r[f"t_{name}"].append(loc["filtered_translation_error_m"])
        r[f"r_{name}"].append(loc["filtered_rotation_error_deg"])
        if name == "filtered":
            r["gnss_fix"].append(bool(loc["gnss_fix"]))
            r["fix_accepted"].append(bool(loc["fix_accepted"]))
            r["fix_gated"].append(bool(loc["success"] and not loc["fix_accepted"]))
            for kind in ("gnss", "attitude"):  # a reading fused ungated after a streak counts too
                upd = tracks.last_updates[agent].get(kind)
                r[f"{kind}_gated"].append(upd is not None and (not upd.accepted or upd.reason is not None))


def recovery(t_filtered: Sequence[float], accepted: Sequence[bool], threshold: float = RECOVERED_M) -> list:
    """Per run of steps without an accepted fix: ``(gap length, max error in it, recovery steps)``.

    Recovery steps count from the first step with an accepted fix after the gap until the
    filtered error is below ``threshold`` (0 when it already is; None when the episode ends first).
    """
    out = []
    acc = list(accepted)
    t = np.asarray(t_filtered, dtype=np.float64)
    k = 1
    while k < len(acc):
        if acc[k]:
            k += 1
            continue
        start = k
        while k < len(acc) and not acc[k]:
            k += 1
        gap_max = float(np.max(t[start:k]))
        steps = None
        for j in range(k, len(acc)):
            if t[j] < threshold:
                steps = j - k
                break
        if k < len(acc):
            out.append((k - start, gap_max, steps))
    return out


def summarize(records: Sequence[dict]) -> dict:
    """The results of one sensor model over episodes (``fly`` outputs)."""
    rows = [r for rec in records for r in rec.values()]
    cat = {key: np.concatenate([np.asarray(r[key], dtype=np.float64) for r in rows]) for key in _KEYS}
    n = len(cat["t_prior"])
    out: dict = {"steps": n, "gnss_fix_share": float(cat["gnss_fix"].mean())}
    for m in METHODS:
        t, r = cat[f"t_{m}"], cat[f"r_{m}"]
        has = np.isfinite(t)
        good = has & (t < GOOD[0]) & (r < GOOD[1])
        out[m] = {
            "pose_share": float(has.mean()),
            f"within_{GOOD[0]}m_{GOOD[1]}deg_share": float(good.mean()),
            "translation_error_m": median_p90(t),
            "rotation_error_deg": median_p90(r),
            "translation_error_m_without_gnss_fix": median_p90(t[cat["gnss_fix"] == 0]),
        }
    gaps = [g for rec in records for r in rec.values() for g in recovery(r["t_filtered"], r["fix_accepted"])]
    steps = [g[2] for g in gaps if g[2] is not None]
    out["filtered"]["fixes_accepted"] = int(cat["fix_accepted"].sum())
    out["filtered"]["fixes_gated"] = int(cat["fix_gated"].sum())
    out["filtered"]["gnss_readings_gated"] = int(cat["gnss_gated"].sum())
    out["filtered"]["attitude_readings_gated"] = int(cat["attitude_gated"].sum())
    out["filtered"]["recovery"] = {
        "gaps": len(gaps),
        "gap_steps": median_p90([g[0] for g in gaps]),
        "max_error_in_gap_m": median_p90([g[1] for g in gaps]),
        "threshold_m": RECOVERED_M,
        "steps_to_recover": {**median_p90(steps), "max": float(max(steps)) if steps else float("nan")},
        "not_recovered": sum(g[2] is None for g in gaps),
    }
    return out


def plot(records: dict[str, dict], path: Path, agent: str = "uav_0") -> Path:
    """Error over time of one UAV: filtered vs single-frame vs prior, per sensor model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(records), 1, figsize=(9, 3.2 * len(records)), sharex=True, squeeze=False)
    for ax, (noise, rec) in zip(axes[:, 0], records.items(), strict=True):
        r = rec[agent]
        k = np.arange(len(r["t_prior"]))
        ax.semilogy(k, r["t_prior"], color="0.6", lw=1, label="onboard prior (GNSS + attitude)")
        ax.semilogy(k, r["t_single_frame"], "o", ms=3, color="tab:orange",
                    label="single frame (failed: no dot)")
        ax.semilogy(k, r["t_filtered"], color="tab:blue", lw=1.5, label="filtered")
        acc = np.asarray(r["fix_accepted"])
        ax.semilogy(k[acc], np.asarray(r["t_filtered"])[acc], "|", ms=7, color="tab:blue",
                    label="filtered: fix accepted")
        for j in np.flatnonzero(~np.asarray(r["gnss_fix"])):
            ax.axvspan(j - 0.5, j + 0.5, color="tab:red", alpha=0.12, lw=0)
        ax.set_ylabel("translation error (m)")
        ax.set_title(f"{noise}, {agent} (red: no GNSS fix)")
        ax.grid(True, which="both", alpha=0.3)
    axes[-1, 0].set_xlabel("step (0.5 s)")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: fly, localize, write ``results.json`` and ``temporal.png`` into ``--out``."""
    p = argparse.ArgumentParser(
        prog="python -m uav_struct_env.study.temporal", description=__doc__.split("\n")[0]
    )
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--seeds", type=int, default=3, help="episodes per sensor model (seeds 0..N-1)")
    p.add_argument("--steps", type=int, default=160, help="steps per episode (0.5 s each)")
    p.add_argument("--noise", nargs="+", choices=NOISES, default=list(NOISES))
    p.add_argument("--action-noise", type=float, default=0.05,
                   help="sigma of the disturbance added to each applied action component (wind)")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    out = prepare_output_dir(args.out, overwrite=args.overwrite)
    results = {"config": {"seeds": args.seeds, "steps": args.steps, "noise": args.noise, "landmarks": "all",
                          "preset": "paper", "observe_image": False, "miss_rate": 0.1, "false_positives": 1.0,
                          "action_noise": args.action_noise,
                          "path": {"near_m": 9.0, "far_m": 30.0, "altitude_m": 8.0}},
               "software": software(), "noise": {}}
    first = {}
    for noise in args.noise:
        recs = []
        for seed in range(args.seeds):
            recs.append(fly(noise, seed, args.steps, action_noise=args.action_noise,
                            progress=not args.no_progress))
        first[noise] = recs[0]
        results["noise"][noise] = summarize(recs)
    write_results_json(out / "results.json", json_ready(results))
    plot(first, out / "temporal.png")
    for noise, r in results["noise"].items():
        print(f"{noise}: steps {r['steps']}, GNSS fix {100 * r['gnss_fix_share']:.0f} %")
        for m in METHODS:
            x = r[m]
            t, d = x["translation_error_m"], x["rotation_error_deg"]
            good = x[f"within_{GOOD[0]}m_{GOOD[1]}deg_share"]
            print(f"  {m:16s} pose {100 * x['pose_share']:5.1f} %  good {100 * good:5.1f} %"
                  f"  t {t['median']:.3f} / {t['p90']:.3f} m  r {d['median']:.2f} / {d['p90']:.2f} deg")
        rec = r["filtered"]["recovery"]
        f = r["filtered"]
        print(f"  filtered: gated {f['fixes_gated']} fixes, {f['gnss_readings_gated']} GNSS and "
              f"{f['attitude_readings_gated']} attitude readings; "
              f"{rec['gaps']} gaps without a fix, "
              f"max error in a gap median {rec['max_error_in_gap_m']['median']:.3f} m, steps to recover "
              f"below {RECOVERED_M} m median {rec['steps_to_recover']['median']} "
              f"max {rec['steps_to_recover']['max']}")
    print(f"wrote {out / 'results.json'} and {out / 'temporal.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
