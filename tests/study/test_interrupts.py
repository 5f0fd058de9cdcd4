"""Ctrl-C and dead workers, sent from here to a real ``uav-struct study`` process."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest


def _sigint_default() -> None:
    """In the child before exec: Ctrl-C handled as a terminal's would be, even when this test run
    was started with SIGINT ignored (a background job of a non-interactive shell), which the child
    would inherit, and then Python installs no KeyboardInterrupt handler."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _children(pid: int) -> list[int]:
    kids: list[int] = []
    for task in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{task}/children") as fh:
            kids += [int(x) for x in fh.read().split()]
    return kids


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return fh.read().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


SMALL = (320, 180)  # a quarter of the paper's image width and height, for runs whose images are not checked


def _study(out: Path, workers: int, *extra: str, progress: bool = False) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "uav_struct_env.cli", "study", "--out", str(out), "--workers",
           str(workers), *([] if progress else ["--no-progress"]), "--no-figures", "--detector",
           "projection", *extra]
    # A session of its own, so that a signal to the group is what a terminal's Ctrl-C sends.
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env=os.environ.copy(), preexec_fn=_sigint_default)


def _wait_for_workers(proc: subprocess.Popen, n: int, timeout: float = 120) -> list[int]:
    """Pids of the study's ``n`` worker processes once they are rendering."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        workers = [c for c in _children(proc.pid) if "spawn_main" in _cmdline(c)]
        if len(workers) >= n:
            time.sleep(3.0)  # past start-up: each has a site loaded
            return workers
        time.sleep(0.2)
    raise AssertionError("the study's workers did not start")


def _wait_for_viewpoints(proc: subprocess.Popen, done: int,
                         timeout: float = 180) -> tuple[list, threading.Thread]:
    """Read the study's progress bar (stderr) until it counts ``done`` viewpoints.

    Returns what was read (the list keeps growing) and the reading thread (joined at EOF).

    A fixed sleep was not enough where the kernels had still to be compiled (a fresh clone): the
    signal then came before the first viewpoint. A thread keeps reading, so the pipe never fills.
    """
    read: list[str] = []
    reader = threading.Thread(target=lambda: read.extend(iter(lambda: proc.stderr.read(1), "")), daemon=True)
    reader.start()
    deadline = time.monotonic() + timeout
    while f" {done}/" not in "".join(read):
        assert proc.poll() is None and time.monotonic() < deadline, "".join(read)[-2000:]
        time.sleep(0.1)
    return read, reader


def _previous_run(out: Path) -> dict[str, bytes]:
    out.mkdir()
    files = {"results.json": b'{"earlier": "run"}\n', "table2.md": b"| earlier |\n",
             "notes.txt": b"the user's own file\n"}
    for name, data in files.items():
        (out / name).write_bytes(data)
    return files


# one worker (a second study with a progress bar): `make test-slow`
@pytest.mark.parametrize("workers", [pytest.param(1, marks=pytest.mark.slow), 2])
def test_ctrl_c_stops_the_study_quickly_with_one_line_and_status_130(workers, tmp_path):
    out = tmp_path / "out"
    before = _previous_run(out)
    proc = _study(out, workers, "--overwrite", progress=workers == 1)
    if workers > 1:
        pids = _wait_for_workers(proc, workers)
    else:
        read, reader = _wait_for_viewpoints(proc, 1)  # past start-up: a viewpoint done, the next rendering
        pids = []
    pids += _children(proc.pid)
    t0 = time.monotonic()
    os.killpg(proc.pid, signal.SIGINT)
    if workers > 1:
        _, err = proc.communicate(timeout=30)
    else:
        proc.wait(timeout=30)
        reader.join(timeout=10)  # to the end of stderr
        err = "".join(read)
    stopped_s = time.monotonic() - t0
    assert proc.returncode == 130, err[-2000:]
    assert stopped_s < 5.0
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-2000:]
    ours = [line for line in err.splitlines() if line.startswith("uav-struct")]
    assert len(ours) == 1 and "interrupted: stopped after" in ours[0], err[-2000:]
    assert "viewpoints; nothing written" in ours[0]
    time.sleep(0.5)
    assert [p for p in pids if _running(p)] == []
    # the earlier run is untouched and nothing half-written is left
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_a_killed_worker_fails_the_study_naming_it(tmp_path):
    out = tmp_path / "out"
    proc = _study(out, 2)
    workers = _wait_for_workers(proc, 2)
    others = [p for p in _children(proc.pid) if p not in workers]
    os.kill(workers[-1], signal.SIGKILL)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err[-2000:]
    assert "Traceback" not in err, err[-2000:]
    assert f"(pid {workers[-1]}) was killed by SIGKILL" in err
    assert "nothing written" in err
    time.sleep(0.5)
    assert [p for p in workers + others if _running(p)] == []
    assert list(out.iterdir()) == []


def test_an_output_folder_with_results_is_refused_naming_overwrite(tmp_path, capsys):
    # No signal and no worker: the command's own function, in this process, gives the exit status.
    from uav_struct_env.study.study import main

    out = tmp_path / "out"
    before = _previous_run(out)
    assert main(["--out", str(out), "--workers", "1", "--no-progress", "--no-figures", "--detector",
                 "projection", "--quick"]) == 2
    err = capsys.readouterr().err
    assert "already holds results" in err and "--overwrite" in err
    assert "Traceback" not in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_overwrite_replaces_the_earlier_study_and_removes_its_stale_files(tmp_path, capsys):
    # No signal and no worker: the command's own function, in this process (its kernels warm), on
    # small images (what is checked is the files the run leaves, not what it renders).
    from uav_struct_env.study import study as study_cli

    out = tmp_path / "out"
    _previous_run(out)
    (out / "fig2_associations.png").write_bytes(b"an earlier figure")
    status = study_cli.main(["--out", str(out), "--workers", "1", "--no-progress", "--no-figures",
                             "--detector", "projection", "--quick", "--overwrite", "--image-size", "320x180",
                             "--methods", "column_tops"])  # one scene: quickest
    assert status == 0, capsys.readouterr().err[-2000:]
    names = sorted(p.name for p in out.iterdir())
    # --no-figures: the earlier figure is not left beside the new results; the user's file stays
    assert names == ["detections.csv", "notes.txt", "per_image.csv", "results.json", "table1.md", "table2.md"]
    assert b"earlier" not in (out / "results.json").read_bytes()
    results = json.loads((out / "results.json").read_text())
    assert list(results["methods"]) == ["column_tops"] and results["config"]["image_size"] == list(SMALL)


def test_sigterm_ends_the_study_like_ctrl_c_with_status_143(tmp_path):
    out = tmp_path / "out"
    before = _previous_run(out)
    proc = _study(out, 2, "--overwrite")
    pids = _wait_for_workers(proc, 2) + _children(proc.pid)
    proc.send_signal(signal.SIGTERM)  # to the study alone, as `kill PID` sends it
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 143, err[-2000:]
    assert "Traceback" not in err, err[-2000:]
    ours = [line for line in err.splitlines() if line.startswith("uav-struct")]
    assert len(ours) == 1 and "interrupted" in ours[0] and "nothing written" in ours[0], err[-2000:]
    time.sleep(0.5)
    assert [p for p in pids if _running(p)] == []  # the workers went with it
    # the earlier run as it was: no .partial-* staging folder left beside it
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_two_studies_into_one_new_folder_one_writes_the_other_is_refused(tmp_path):
    out = tmp_path / "new"
    # two real processes (on small images: the race for the folder does not depend on them)
    procs = [_study(out, 1, "--quick", "--methods", "column_tops", "--image-size", "320x180")
             for _ in range(2)]
    done = [p.communicate(timeout=600) for p in procs]
    codes = sorted(p.returncode for p in procs)
    assert codes == [0, 2], [err[-2000:] for _, err in done]
    refused = next(err for p, (_, err) in zip(procs, done, strict=True) if p.returncode == 2)
    ours = [line for line in refused.splitlines() if line.strip()]
    # refused while the other writes (or, had it finished first, because the folder holds its results)
    why = ("being written by another run", "already holds results")
    assert len(ours) == 1 and any(w in ours[0] for w in why), refused[-2000:]
    assert (out / "results.json").is_file() and not [p for p in out.iterdir() if p.name.startswith(".")]
    assert json.loads((out / "results.json").read_text())["config"]["image_size"] == list(SMALL)


def test_a_corrupt_detector_model_is_one_line_and_status_2(tmp_path, capsys):
    from uav_struct_env.study.study import main

    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"\x08\x07not a protobuf at all" * 40)
    out = tmp_path / "out"
    assert main(["--detector-model", str(bad), "--out", str(out), "--quick", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "detector_model" in err, err
    assert "not a model ONNX Runtime can load" in err, err
    assert not out.exists()


@pytest.mark.parametrize("when", ["at the check", "after the check"])
def test_a_sweep_into_a_folder_another_run_writes_is_refused_with_status_2(when, tmp_path, capsys,
                                                                            monkeypatch):
    import uav_struct_env.validate
    from uav_struct_env.study.sweep import main

    if when == "after the check":  # the other run takes --out between the check and the sweep's start
        monkeypatch.setattr(uav_struct_env.validate, "check_output_dir", lambda *a, **k: None)
    out = tmp_path / "sweep"
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time\n"
                               "from uav_struct_env.outputs import prepare_output_dir\n"
                               "prepare_output_dir(sys.argv[1]); print('locked', flush=True); time.sleep(30)",
                               str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert main(["--sites", "paper", "--out", str(out), "--quick", "--detector", "projection",
                     "--no-progress"]) == 2
    finally:
        holder.kill()
        holder.wait()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"being written by another run (pid {holder.pid}" in err, err
