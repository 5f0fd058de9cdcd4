"""benchmarks/ppo_throughput.py runs the real trainer and accounts for every process it starts."""

import sys
from pathlib import Path

import pytest

from uav_struct_env.errors import UsageError

pytest.importorskip("stable_baselines3")
pytest.importorskip("supersuit")

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "ppo_throughput.py"


@pytest.fixture(scope="module")
def bench(load_script):
    """The benchmark script as a module (loaded once for the tests below)."""
    return load_script(SCRIPT)


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_short_run_reports_the_training_process_and_each_env_worker(bench):
    row = bench.main(minutes=0.1, seed=1, trainer_args=[
        "--n-envs", "2", "--num-cpus", "2", "--n-steps", "16", "--batch-size", "32", "--n-epochs", "1"])
    roles = sorted(p["role"] for p in row["processes"])
    assert roles == ["env worker", "env worker", "training"]
    assert row["agent_steps"] >= 2 * 4 * 16  # at least one rollout of 2 copies x 4 agents
    assert all(p["cpu_s"] > 0 for p in row["processes"])
    assert row["cpu_ms_per_agent_step"] == pytest.approx(
        sum(p["cpu_ms_per_agent_step"] for p in row["processes"]), abs=0.01)


def test_a_bad_duration_is_refused_before_anything_runs(bench):
    with pytest.raises(UsageError, match="--minutes must be positive, got 0"):
        bench.main(minutes=0)
