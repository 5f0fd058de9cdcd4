"""benchmarks/vector_env.py measures the single env and every K in one run and prints the table."""

from __future__ import annotations

from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "vector_env.py"

pytestmark = pytest.mark.filterwarnings("ignore:The `render_mode` attribute is not defined")


def test_a_short_run_reports_each_env_with_positive_rates(load_script, capsys):
    pytest.importorskip("supersuit")
    bench = load_script(SCRIPT)
    out = bench.main(steps=16, ks=(1, 2), repeats=1, sb3=True, warm_episodes=0)
    assert list(out) == ["single", "K=1", "K=2", "SB3VecEnv K=2", "SuperSuit K=2"]
    for row in out.values():
        assert len(row["agent_steps_per_cpu_s"]) == 1 and row["agent_steps_per_cpu_s"][0] > 0
    printed = capsys.readouterr().out
    assert "agent_steps_per_cpu_s" in printed and "load average" in printed
