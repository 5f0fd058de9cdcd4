"""Every command that writes files refuses an earlier run and leaves nothing half-written."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from uav_struct_env.datasets.__main__ import main as dataset_main
from uav_struct_env.demo import main as render_main


def _sigint_default() -> None:
    """In the child before exec: Ctrl-C handled as a terminal's would be, even when this test run
    was started with SIGINT ignored (a background job of a non-interactive shell), which the child
    would inherit, and then Python installs no KeyboardInterrupt handler."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _earlier_run(out, name):
    out.mkdir()
    (out / name).write_text("an earlier run")
    return {p.name: p.read_bytes() for p in out.iterdir()}


def test_render_refuses_an_earlier_run_and_replaces_it_with_overwrite(tmp_path, capsys):
    out = tmp_path / "renders"
    before = _earlier_run(out, "slab_uav_0_viewpoint0.png")
    # 160 x 90 views: which files it writes, refuses or replaces does not depend on the size
    argv = ["--out", str(out), "--stage", "slab", "--renderer", "tiny", "--image-size", "160x90"]
    assert render_main(argv) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert render_main([*argv, "--overwrite"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert len(names) == 5 and all(n.startswith("slab_") and n.endswith(".png") for n in names)
    assert (out / "slab_uav_0_viewpoint0.png").read_bytes()[:4] == b"\x89PNG"


def test_dataset_generator_refuses_an_earlier_dataset(tmp_path, capsys):
    out = tmp_path / "data"
    before = _earlier_run(out, "labels.json")
    assert dataset_main([str(out), "--layouts", "1", "--views", "1", "--scale", "0.25"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_an_interrupted_dataset_leaves_no_labels_and_no_images(tmp_path):
    out = tmp_path / "data"
    proc = subprocess.Popen(
        [sys.executable, "-m", "uav_struct_env.datasets", str(out), "--layouts", "40", "--views",
         "2", "--scale", "0.25", "--renderer", "tiny", "--workers", "2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        preexec_fn=_sigint_default,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # wait until images are being written (in the stage)
        staged = [p for p in out.glob(".partial-*/images/*.png")] if out.exists() else []
        if staged:
            break
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err[-2000:]
    assert "Traceback" not in err and "interrupted" in err
    assert list(out.iterdir()) == []


def test_training_refuses_an_earlier_run(tmp_path, capsys):
    pytest.importorskip("torch")
    from uav_struct_env.training.train_detector import main as train_main

    out = tmp_path / "run"
    before = _earlier_run(out, "summary.json")
    with pytest.raises(SystemExit) as stop:
        train_main(["--data", str(tmp_path), "--out", str(out)])
    assert stop.value.code == 2
    assert "already holds results (summary.json); pass --overwrite" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
