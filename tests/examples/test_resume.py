"""Training that survives interruption: SIGTERM saves the run, --resume reaches the same weights."""

import io
import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("supersuit")
torch = pytest.importorskip("torch")

SCRIPT = Path(__file__).resolve().parents[2] / "examples" / "train_viewpoint_ppo.py"
ROOT = SCRIPT.parents[1]
TINY = ["--total-timesteps", "512", "--n-envs", "1", "--num-cpus", "0", "--n-steps", "32",
        "--batch-size", "64", "--n-epochs", "1", "--max-cycles", "8", "--checkpoint-every", "128",
        "--seed", "3", "--no-progress-bar"]


def _train(*args: str, env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(SCRIPT), *args], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(ROOT), **(env or {})})


def _weights(path: Path) -> dict:
    with zipfile.ZipFile(path) as z:
        return torch.load(io.BytesIO(z.read("policy.pth")), weights_only=True)


@pytest.mark.slow  # three SB3 training processes: a long library run (`make test-slow`)
def test_sigterm_saves_the_run_and_resume_reaches_the_uninterrupted_weights(tmp_path):
    """Tolerance: none -- the resumed run's weights equal the uninterrupted run's bit for bit
    (one process, one torch thread; the same seeded resets, RNG states and statistics)."""
    full, cut = tmp_path / "full", tmp_path / "cut"
    whole = _train("--out", str(full), *TINY)
    part = _train("--out", str(cut), *TINY)
    deadline = time.monotonic() + 120
    while not (cut / "checkpoints" / "step_000000256" / "resume.npz").exists():
        assert part.poll() is None and time.monotonic() < deadline, part.communicate()[1][-2000:]
        time.sleep(0.05)
    part.send_signal(signal.SIGTERM)
    _, err = part.communicate(timeout=60)
    assert whole.wait(timeout=120) == 0, whole.communicate()[1][-2000:]
    if part.returncode == 0:
        pytest.skip("the run finished before the signal arrived")
    assert part.returncode == 143, err[-2000:]
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "interrupted by SIGTERM" in err and f"--resume {cut}" in err
    record = json.loads((cut / "train.json").read_text())
    assert record["interrupted"] == "SIGTERM" and not record["finished"]
    assert 256 <= record["agent_steps"] < 512 and record["agent_steps"] % 128 == 0
    assert (cut / "checkpoints" / f"step_{record['agent_steps']:09d}" / "resume.npz").is_file()
    again = _train("--resume", str(cut), "--no-progress-bar")
    assert again.wait(timeout=120) == 0, again.communicate()[1][-2000:]
    resumed = json.loads((cut / "train.json").read_text())
    assert resumed["finished"] and resumed["agent_steps"] == 512
    assert resumed["resumed_from"] == record["agent_steps"]
    a, b = _weights(full / "model.zip"), _weights(cut / "model.zip")
    assert all(torch.equal(a[k], b[k]) for k in a)
    rows = [json.loads(line)["agent_steps"] for line in (cut / "progress.jsonl").read_text().splitlines()]
    assert rows == list(range(128, 513, 128))


def test_a_second_trainer_into_the_same_out_is_refused(tmp_path):
    # The holder takes --out as the trainer's train() does before any work (prepare_output_dir)
    # and keeps it, as a first trainer would for its whole run.
    out = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time\n"
                               "from uav_struct_env.outputs import prepare_output_dir\n"
                               "prepare_output_dir(sys.argv[1]); print('locked', flush=True); time.sleep(60)",
                               str(out)], cwd=ROOT, stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout.readline().strip() == "locked"
        second = _train("--out", str(out), "--overwrite", *TINY)
        _, err = second.communicate(timeout=120)
    finally:
        holder.kill()
        holder.wait()
    assert second.returncode == 2, err
    assert err.count("\n") == 1 and f"pid {holder.pid}" in err and str(out) in err
