"""uav_struct_env.outputs: refuse an earlier run, write atomically, commit a set at once."""

from __future__ import annotations

import os

import pytest

from uav_struct_env.outputs import (
    PARTIAL_PREFIX,
    OutputExistsError,
    StagedOutput,
    atomic_path,
    atomic_write_json,
    atomic_write_text,
    prepare_output_dir,
)


def test_prepare_creates_a_new_folder_and_accepts_an_empty_one(tmp_path):
    out = prepare_output_dir(tmp_path / "a" / "b")
    assert out.is_dir()
    assert prepare_output_dir(out) == out


def test_prepare_refuses_a_folder_with_files_naming_overwrite(tmp_path):
    (tmp_path / "results.json").write_text("{}")
    with pytest.raises(OutputExistsError, match=r"already holds results \(results.json\); pass --overwrite"):
        prepare_output_dir(tmp_path)
    with pytest.raises(OutputExistsError, match="pass --force"):
        prepare_output_dir(tmp_path, flag="--force")
    assert prepare_output_dir(tmp_path, overwrite=True) == tmp_path
    with pytest.raises(NotADirectoryError, match="is not a folder"):
        prepare_output_dir(tmp_path / "results.json")


def test_leftovers_of_a_dead_run_are_removed_not_counted(tmp_path):
    dead = tmp_path / f"{PARTIAL_PREFIX}999999999-abc"
    dead.mkdir()
    (dead / "results.json").write_text("half")
    prepare_output_dir(tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_leaves_the_old_file_when_interrupted(tmp_path):
    path = tmp_path / "results.json"
    atomic_write_json(path, {"run": 1})
    with pytest.raises(KeyboardInterrupt), atomic_path(path) as tmp:
        tmp.write_text('{"run": 2, "trunc')
        raise KeyboardInterrupt
    assert path.read_text() == '{"run": 1}\n'
    assert os.listdir(tmp_path) == ["results.json"]
    assert oct(path.stat().st_mode & 0o777) == oct(0o666 & ~_umask())


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_atomic_write_replaces_a_symlink_instead_of_writing_through_it(tmp_path):
    target = tmp_path / "elsewhere.txt"
    target.write_text("keep me")
    link = tmp_path / "out" / "table1.md"
    link.parent.mkdir()
    link.symlink_to(target)
    atomic_write_text(link, "new")
    assert not link.is_symlink() and link.read_text() == "new"
    assert target.read_text() == "keep me"


def test_staged_output_commits_the_set_and_removes_stale_owned_files(tmp_path):
    for name, text in {"results.json": "old", "fig.png": "old", "notes.txt": "mine"}.items():
        (tmp_path / name).write_text(text)
    with pytest.raises(OutputExistsError):
        StagedOutput(tmp_path, owned=("results.json", "*.png", "*.md"))
    with StagedOutput(tmp_path, overwrite=True, owned=("results.json", "*.png", "*.md")) as staged:
        (staged.stage / "table.md").write_text("new")
        (staged.stage / "results.json").write_text("new")
        assert not (tmp_path / "table.md").exists()  # nothing is visible before the end
    assert sorted(os.listdir(tmp_path)) == ["notes.txt", "results.json", "table.md"]
    assert (tmp_path / "results.json").read_text() == "new"


def test_staged_output_discards_everything_on_an_exception(tmp_path):
    (tmp_path / "results.json").write_text("old")
    with pytest.raises(KeyboardInterrupt), StagedOutput(
        tmp_path, overwrite=True, owned=("results.json",)
    ) as staged:
        (staged.stage / "results.json").write_text("new, but the run was cut")
        raise KeyboardInterrupt
    assert os.listdir(tmp_path) == ["results.json"]
    assert (tmp_path / "results.json").read_text() == "old"


def test_staged_folders_replace_folders(tmp_path):
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "old.png").write_text("old")
    with StagedOutput(tmp_path, overwrite=True, owned=("labels.json", "images")) as staged:
        (staged.stage / "images").mkdir()
        (staged.stage / "images" / "new.png").write_text("new")
        (staged.stage / "labels.json").write_text("{}")
    assert os.listdir(tmp_path / "images") == ["new.png"]


_HOLD = """
import sys, time
from uav_struct_env.outputs import prepare_output_dir
prepare_output_dir(sys.argv[1])
print("locked", flush=True)
time.sleep(30)
"""


def test_a_second_run_into_the_same_folder_is_refused_naming_the_other(tmp_path):
    import subprocess
    import sys

    from uav_struct_env.outputs import OutputBusyError, lock_path

    out = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(OutputBusyError, match=rf"being written by another run \(pid {holder.pid}"):
            prepare_output_dir(out, overwrite=True)
        with pytest.raises(OutputBusyError, match="being written by another run"):
            StagedOutput(out, overwrite=True, owned=("results.json",))
    finally:
        holder.kill()
        holder.wait()
    assert lock_path(out).exists()  # left by the killed run: taken over
    assert prepare_output_dir(out) == out


def test_a_dead_runs_lock_is_taken_over_with_a_line(tmp_path, capsys):
    from uav_struct_env.outputs import lock_output, lock_path

    out = tmp_path / "run"
    lock_path(out).write_text("999999999 uav-struct study --out run\n")
    lock = lock_output(out)
    assert "left by pid 999999999: uav-struct study --out run, which is no longer running" in (
        capsys.readouterr().err)
    lock.release()
    assert not lock_path(out).exists()


def test_the_commit_checks_again_and_replaces_nothing_another_run_wrote(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(OutputExistsError, match="already holds results"):
        with StagedOutput(out, owned=("results.json",)) as staged:
            (staged.stage / "results.json").write_text("mine")
            (out / "results.json").write_text("theirs")  # written meanwhile, bypassing the lock
    assert (out / "results.json").read_text() == "theirs"
    assert [p.name for p in out.iterdir()] == ["results.json"]


def test_remove_earlier_run_removes_only_the_named_entries(tmp_path):
    from uav_struct_env.outputs import remove_earlier_run

    (tmp_path / "checkpoints" / "step_1").mkdir(parents=True)
    (tmp_path / "tb").mkdir()
    (tmp_path / "notes.txt").write_text("mine")
    assert remove_earlier_run(tmp_path, ("checkpoints", "tb", "train.json")) == ["checkpoints", "tb"]
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]
