"""benchmarks/detector.py evaluates on held-out renders only: it refuses the training seeds."""

from __future__ import annotations

import re
import runpy
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "detector.py"


@pytest.fixture(scope="module")
def bench(load_script):
    return load_script(SCRIPT)


def test_seen_seeds_are_every_dataset_seed_make_detector_renders(bench):
    """A dataset added to the Makefile's detector recipe must be known to the guard."""
    recipe = (ROOT / "Makefile").read_text()
    seeds = {int(s) for s in re.findall(r"uav_struct_env\.datasets.*?--seed (\d+)", recipe, re.S)}
    seeds |= {int(s) for s in re.findall(r"\$\(DATASET\) .*?--seed (\d+)", recipe)}
    assert seeds == set(bench.SEEN_SEEDS) == {0, 1, 3, 5, 6, 7}


@pytest.mark.parametrize("seed, what", [(3, "refiner training"), (7, "busy sites")])
def test_a_training_seed_is_refused_with_the_reason(seed, what, monkeypatch, capsys):
    # `python benchmarks/detector.py --seed 3 --layouts 1`, run in this process as Python runs a
    # script (a subprocess spent 1.5 s of CPU importing what this one has imported): the exit
    # status is the code of the SystemExit the script raises.
    monkeypatch.setattr(sys, "argv", [str(SCRIPT), "--seed", str(seed), "--layouts", "1"])
    monkeypatch.chdir(ROOT)
    with pytest.raises(SystemExit) as stop:
        runpy.run_path(str(SCRIPT), run_name="__main__")
    assert stop.value.code == 2
    stderr = capsys.readouterr().err
    assert f"--seed {seed} is the dataset seed of the committed weights'" in stderr
    assert what in stderr and "not held out" in stderr and "--allow-seen-seed" in stderr
