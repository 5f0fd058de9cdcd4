"""PPO end to end: agent-steps per second and where the CPU goes, per process.

Runs ``examples/train_viewpoint_ppo.py`` (its own process, as a user starts it) into a temporary
folder for ``--minutes`` and reads, from ``/proc`` (Linux), the CPU time of the training process
and of each env worker it starts. Prints the training's agent-steps per second (its
``train.json``), each process's CPU milliseconds per agent-step (start-up included: imports and
building the envs, a few seconds) and how busy the cores were over the trainer's lifetime.
Any other option is passed on to the trainer:

    .venv/bin/python benchmarks/ppo_throughput.py --minutes 2 --seed 9
    .venv/bin/python benchmarks/ppo_throughput.py --minutes 2 -- --n-envs 8 --num-cpus 4 --n-steps 64

A short run overstates a whole run's average (the policy soon keeps more landmarks in view):
docs/benchmarks.md compares 2-minute runs with a 30-minute one. Other processes on the machine
lower the figures; ``uptime``'s load is printed.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from uav_struct_env.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
TRAINER = ROOT / "examples" / "train_viewpoint_ppo.py"


def _cpu_seconds(pid: int) -> tuple[float, int]:
    """(user + system CPU seconds, parent pid) of a live process, from ``/proc/<pid>/stat``."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks, int(fields[1])


def _children_cpu(root: int, seen: dict[int, tuple[str, float]]) -> None:
    """Record the CPU seconds of ``root`` and of its direct children (the env workers)."""
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        pid = int(entry)
        try:
            cpu, parent = _cpu_seconds(pid)
        except (OSError, IndexError, ValueError):  # gone meanwhile
            continue
        if pid == root:
            seen[pid] = ("training", cpu)
        elif parent == root:
            seen[pid] = ("env worker", cpu)


def main(minutes: float = 2.0, seed: int = 9, trainer_args: list[str] | None = None) -> dict:
    if not Path("/proc/self/stat").exists():
        raise OSError("ppo_throughput.py reads process CPU times from /proc: Linux only")
    if not minutes > 0:
        raise UsageError(f"--minutes must be positive, got {minutes}")
    with tempfile.TemporaryDirectory(prefix="ppo_throughput_") as tmp:
        out = Path(tmp) / "run"
        cmd = [sys.executable, str(TRAINER), "--out", str(out), "--minutes", str(minutes),
               "--seed", str(seed), "--total-timesteps", "100000000", "--no-progress-bar",
               "--checkpoint-every", "100000000", *(trainer_args or [])]
        log = Path(tmp) / "stderr.txt"  # a file, not a pipe: a full pipe would stall the trainer
        with open(log, "w") as err:
            t0 = time.perf_counter()
            proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err)
            seen: dict[int, tuple[str, float]] = {}
            while proc.poll() is None:  # the last reading before each process exits is kept
                _children_cpu(proc.pid, seen)
                time.sleep(0.5)
            lifetime = time.perf_counter() - t0
        if proc.returncode != 0:
            raise RuntimeError(f"the trainer failed (status {proc.returncode}):\n"
                               f"{log.read_text()[-4000:]}")
        summary = json.loads((out / "train.json").read_text())
    steps, wall = summary["agent_steps"], summary["wall_clock_s"]
    total = sum(cpu for _, cpu in seen.values())
    cores = os.cpu_count() or 1
    out_row = {
        "agent_steps": steps,
        "wall_clock_s": round(wall, 1),
        "agent_steps_per_s": round(summary["agent_steps_per_s"], 1),
        "cpu_ms_per_agent_step": round(1e3 * total / steps, 3),
        "process_wall_clock_s": round(lifetime, 1),  # start-up and saving included
        "cores_busy_percent": round(100 * total / (lifetime * cores), 1),
        "processes": [
            {"role": role, "pid": pid, "cpu_s": round(cpu, 1),
             "cpu_ms_per_agent_step": round(1e3 * cpu / steps, 3)}
            for pid, (role, cpu) in sorted(seen.items())
        ],
        "load_average_1min": os.getloadavg()[0],
        "cpu_count": cores,
    }
    for key, value in out_row.items():
        if key != "processes":
            print(f"{key:24s} {value}")
    for row in out_row["processes"]:
        print(f"  {row['role']:10s} pid {row['pid']:<7d} {row['cpu_s']:8.1f} s CPU  "
              f"{row['cpu_ms_per_agent_step']:.3f} ms per agent-step")
    return out_row


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--minutes", type=float, default=2.0, help="training wall clock")
    p.add_argument("--seed", type=int, default=9, help="the trainer's --seed")
    p.add_argument("trainer_args", nargs="*", help="more train_viewpoint_ppo.py options, after --")
    a = p.parse_args()
    main(a.minutes, a.seed, a.trainer_args)
