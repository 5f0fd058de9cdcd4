"""Env steps per second and the share of each step spent rendering.

Usage::

    .venv/bin/python benchmarks/env_step.py                  # paper 1280x720 and train 128x72
    .venv/bin/python benchmarks/env_step.py --steps 50 --renderer tiny
    .venv/bin/python benchmarks/env_step.py --config "paper 1280x720" --config "paper 1280x720, busy activity"
    .venv/bin/python benchmarks/env_step.py --compare-camera mavic2pro --steps 40

For each configuration: the time of one ``reset`` (the first one also builds the world), then
``--steps`` steps with random actions (gentle, so the UAVs stay up), reporting env steps/s (one
step = all four UAVs), the time inside ``SiteWorld.render`` (four images per step) and inside
``SiteWorld.landmark_truth`` (or ``landmark_truth_raycast`` without images) as shares of the step
time (``cpu ms``: the process's CPU time per step, renderer threads included; steadier than
the wall time on a shared machine), and the rest (kinematics, sensors, projections, dict
building; with ``camera="mavic2pro"`` also the distortion / rolling-shutter warp and blur of
:mod:`uav_struct_env.sim.lens`).
The ``mavic2pro`` row against the first is issue 15's camera-cost figure (random actions, so
every frame has motion: the full rolling-shutter path).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from tqdm import tqdm

import uav_struct_env

CONFIGS = {
    "paper 1280x720": ("paper", {}),
    "paper 1280x720, no landmark info": ("paper", {"landmark_sets": ()}),
    "paper 1280x720, light activity": ("paper", {"activity": "light"}),
    "paper 1280x720, busy activity": ("paper", {"activity": "busy"}),
    "paper 1280x720, mavic2pro camera": ("paper", {"camera": "mavic2pro"}),
    "paper 1280x720, mavic2pro camera, busy activity": ("paper", {"camera": "mavic2pro", "activity": "busy"}),
    "train 128x72": ("train", {}),
    "train 128x72 + landmark info": ("train", {"landmark_sets": ("column_tops", "slab_corners")}),
    "train, no image + landmark info (ray-cast)": (
        "train", {"landmark_sets": ("column_tops", "slab_corners"), "observe_image": False}),
    "train, no image + ray-cast, busy activity": (
        "train", {"landmark_sets": ("column_tops", "slab_corners"), "observe_image": False,
                  "activity": "busy"}),
}


class _Timed:
    """Wraps a callable and accumulates its wall time."""

    def __init__(self, fn):
        self.fn, self.total, self.calls = fn, 0.0, 0

    def __call__(self, *args, **kwargs):
        t = time.perf_counter()
        try:
            return self.fn(*args, **kwargs)
        finally:
            self.total += time.perf_counter() - t
            self.calls += 1


def bench(preset: str, overrides: dict, steps: int, renderer: str) -> dict:
    env = uav_struct_env.parallel_env(preset, renderer=renderer, **overrides)
    t0 = time.perf_counter()
    env.reset(seed=0)
    first_reset = time.perf_counter() - t0
    t0 = time.perf_counter()
    env.reset(seed=1)
    reset = time.perf_counter() - t0
    world = env.world
    render, truth = _Timed(world.render), _Timed(world.landmark_truth)
    rays = _Timed(world.landmark_truth_raycast)
    world.render, world.landmark_truth, world.landmark_truth_raycast = render, truth, rays
    rng = np.random.default_rng(0)
    t0, c0 = time.perf_counter(), time.process_time()
    n = 0
    for _ in range(steps):
        if not env.agents:
            env.reset()
        env.step({a: rng.uniform(-0.3, 0.3, 5).astype(np.float32) for a in env.agents})
        n += 1
    elapsed = time.perf_counter() - t0
    cpu = time.process_time() - c0
    out = {
        "backend": world.backend,
        "first_reset_s": first_reset,
        "reset_s": reset,
        "steps_per_s": n / elapsed,
        "step_ms": 1e3 * elapsed / n,
        "cpu_ms_per_step": 1e3 * cpu / n,
        "render_ms_per_image": 1e3 * render.total / max(render.calls, 1),
        "render_share": render.total / elapsed,
        "truth_share": (truth.total + rays.total) / elapsed,
    }
    env.close()
    return out


def main(steps: int = 20, renderer: str = "auto", configs: list[str] | None = None) -> dict:
    results = {}
    print(
        f"{'config':44s} {'backend':7s} {'1st reset':>9s} {'reset':>7s} {'steps/s':>8s} "
        f"{'ms/step':>8s} {'cpu ms':>7s} {'ms/img':>7s} {'render':>7s} {'truth':>6s} {'other':>6s}"
    )
    for name in configs or list(CONFIGS):
        preset, overrides = CONFIGS[name]
        r = bench(preset, overrides, steps, renderer)
        results[name] = r
        other = 1.0 - r["render_share"] - r["truth_share"]
        print(
            f"{name:44s} {r['backend']:7s} {r['first_reset_s']:8.2f}s {r['reset_s']:6.3f}s "
            f"{r['steps_per_s']:8.2f} {r['step_ms']:8.1f} {r['cpu_ms_per_step']:7.0f} "
            f"{r['render_ms_per_image']:7.1f} "
            f"{r['render_share']:6.0%} {r['truth_share']:6.0%} {other:6.0%}",
            flush=True,
        )
    return results


def compare_cameras(steps: int = 20, renderer: str = "auto", camera: str = "mavic2pro") -> dict:
    """The ``paper`` preset with ``camera="paper"`` and with ``camera``, stepped alternately.

    Both envs take the same random actions, one step each in turn, so a shared machine's load
    drifts over both alike; reports the median wall and CPU (process) time per step of each and
    their ratios (issue 15, item 6: at most 1.3).
    """
    envs = {name: uav_struct_env.parallel_env("paper", renderer=renderer, camera=name)
            for name in ("paper", camera)}
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in envs}
    for env in envs.values():
        env.reset(seed=0)
        env.step({a: np.zeros(5, np.float32) for a in env.agents})  # warm up
    rngs = {name: np.random.default_rng(0) for name in envs}
    for _ in tqdm(range(steps), desc="alternating steps"):
        for name, env in envs.items():
            if not env.agents:
                env.reset()
            action = {a: rngs[name].uniform(-0.3, 0.3, 5).astype(np.float32) for a in env.agents}
            t0, c0 = time.perf_counter(), time.process_time()
            env.step(action)
            times[name].append((time.perf_counter() - t0, time.process_time() - c0))
    out = {}
    for name, t in times.items():
        wall, cpu = np.median(np.array(t), axis=0) * 1e3
        out[name] = {"wall_ms": float(wall), "cpu_ms": float(cpu)}
        print(f"camera={name!r:12s} median per step: wall {wall:7.1f} ms, cpu {cpu:7.1f} ms")
    for key in ("wall_ms", "cpu_ms"):
        print(f"{camera} / paper {key[:-3]}: {out[camera][key] / out['paper'][key]:.3f}")
    for env in envs.values():
        env.close()
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--steps", type=int, default=20, help="env steps timed per configuration")
    parser.add_argument("--renderer", default="auto", choices=["auto", "tiny", "egl"],
                        help="pybullet renderer")
    parser.add_argument("--config", action="append", choices=list(CONFIGS), dest="configs",
                        help="a configuration to time (repeatable; default: all)")
    parser.add_argument("--compare-camera", default=None, metavar="CAMERA",
                        help="instead: the paper preset with camera='paper' and with CAMERA, "
                        "stepped alternately (median wall and CPU per step, and their ratio)")
    args = parser.parse_args()
    if args.compare_camera:
        compare_cameras(args.steps, args.renderer, args.compare_camera)
    else:
        main(args.steps, args.renderer, args.configs)
