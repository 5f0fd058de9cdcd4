"""uav_struct_env.validate: every command checks its inputs first and refuses in one line."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from uav_struct_env.demo import main as render_main
from uav_struct_env.errors import UsageError
from uav_struct_env.outputs import OutputExistsError, open_append, real_folder
from uav_struct_env.study.study import main as study_main
from uav_struct_env.validate import (
    MIN_FREE_BYTES,
    check_input_file,
    check_output_dir,
    check_output_file,
    check_site,
)

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=300, env=env,
                          cwd=ROOT)


# ----------------------------------------------------------------------------- output folder
def test_output_dir_that_is_a_file_or_under_a_file_is_refused_and_nothing_created(tmp_path):
    f = tmp_path / "results.json"
    f.write_text("{}")
    with pytest.raises(UsageError, match=rf"--out '{re.escape(str(f))}' exists and is not a folder"):
        check_output_dir(f)
    with pytest.raises(UsageError, match=r"cannot be created: '.*results.json' is not a folder"):
        check_output_dir(f / "a" / "b")
    assert sorted(tmp_path.iterdir()) == [f]


def test_output_dir_is_checked_without_being_created(tmp_path):
    out = tmp_path / "a" / "b"
    assert check_output_dir(out) == out
    assert not (tmp_path / "a").exists()


def test_output_dir_with_an_earlier_run_names_overwrite(tmp_path):
    (tmp_path / "table1.md").write_text("x")
    with pytest.raises(OutputExistsError, match=r"already holds results \(table1.md\); pass --overwrite"):
        check_output_dir(tmp_path)
    assert check_output_dir(tmp_path, overwrite=True) == tmp_path


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere")
def test_output_dir_in_an_unwritable_folder_is_refused(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        with pytest.raises(UsageError, match="cannot be created: this user cannot write into"):
            check_output_dir(locked / "out")
    finally:
        locked.chmod(0o700)


def test_a_full_file_system_is_refused_before_the_work(tmp_path, monkeypatch):
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(shutil, "disk_usage", lambda _: usage._replace(free=3 * 2**20))
    with pytest.raises(UsageError, match=rf"has 3.0 MiB free, less than the {MIN_FREE_BYTES // 2**20} MiB"):
        check_output_dir(tmp_path / "out")


def test_output_and_input_files(tmp_path):
    (tmp_path / "plot.png").write_bytes(b"x")
    with pytest.raises(OutputExistsError, match="--plot '.*plot.png' exists; pass --overwrite"):
        check_output_file(tmp_path / "plot.png", option="--plot")
    with pytest.raises(UsageError, match="--plot '.*' is a folder; name a file"):
        check_output_file(tmp_path, option="--plot")
    with pytest.raises(UsageError, match="--model '.*nope.zip' does not exist; expected an existing model"):
        check_input_file(tmp_path / "nope.zip", option="--model", what="model")


# ----------------------------------------------------------------------------- symlinks
def test_links_inside_the_output_folder_are_replaced_not_followed(tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("precious")
    out = tmp_path / "out"
    out.mkdir()
    (out / "log.jsonl").symlink_to(outside)
    (out / "tb").symlink_to(tmp_path, target_is_directory=True)
    with open_append(out / "log.jsonl") as fh:
        fh.write("{}\n")
    assert real_folder(out / "tb") == out / "tb"
    assert not (out / "log.jsonl").is_symlink() and (out / "log.jsonl").read_text() == "{}\n"
    assert (out / "tb").is_dir() and not (out / "tb").is_symlink()
    assert outside.read_text() == "precious"


def test_render_replaces_a_planted_link_instead_of_writing_through_it(tmp_path):
    outside = tmp_path / "outside.png"
    outside.write_bytes(b"precious")
    out = tmp_path / "renders"
    out.mkdir()
    (out / "slab_uav_0_viewpoint0.png").symlink_to(outside)
    # 160 x 90 views: the size has nothing to do with the link
    argv = ["--out", str(out), "--stage", "slab", "--renderer", "tiny", "--overwrite",
            "--image-size", "160x90"]
    assert render_main(argv) == 0
    target = out / "slab_uav_0_viewpoint0.png"
    assert not target.is_symlink() and target.read_bytes()[:4] == b"\x89PNG"
    assert outside.read_bytes() == b"precious"


# ----------------------------------------------------------------------------- sites
def test_a_malformed_site_file_is_refused_before_the_output_folder_exists(tmp_path, capsys):
    site = tmp_path / "bad.json"
    site.write_text(json.dumps({"building": {"grid": {"spans_x": [4, 4], "spans_y": [4, float("nan")]}}}))
    out = tmp_path / "results"
    assert study_main(["--site", str(site), "--out", str(out), "--detector", "projection"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "uav-struct study: error: --site" in err
    assert "spans_y[1]" in err and "nan" in err
    assert not out.exists()
    assert render_main(["--site", str(site), "--out", str(out)]) == 2
    assert not out.exists()


def test_an_unknown_study_method_is_one_line_naming_it_and_the_choices(tmp_path, capsys):
    out = tmp_path / "results"
    assert study_main(["--methods", "column_tops,doors", "--out", str(out), "--detector", "projection"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "uav-struct study: error: methods must be" in err
    assert "'doors'" in err and "'slab_corners'" in err
    assert not out.exists()


def test_check_site_names_the_option_and_the_file(tmp_path):
    with pytest.raises(UsageError, match=r"--site 'nope.json': site file 'nope.json' does not exist"):
        check_site("nope.json")
    assert check_site("paper", "slab").stage == "slab"


# ----------------------------------------------------------------------------- the commands
def test_render_viewpoint_out_of_range_is_one_line_and_status_2(tmp_path):
    done = _run("-m", "uav_struct_env.cli", "render", "--viewpoint", "12", "--out", str(tmp_path / "r"))
    assert done.returncode == 2
    expected = "uav-struct render: error: --viewpoint must be an int in [0, 9], got 12"
    assert done.stderr.splitlines() == [expected]
    assert not (tmp_path / "r").exists()


def test_version():
    from uav_struct_env import __version__
    from uav_struct_env.cli import main

    done = _run("-m", "uav_struct_env.cli", "--version")
    assert done.returncode == 0 and done.stdout.strip() == f"uav-struct {__version__}"
    with pytest.raises(SystemExit) as stop:
        render_main(["--version"])
    assert stop.value.code == 0
    assert main(["--version"]) == 0


def _help(main, capsys) -> str:
    with pytest.raises(SystemExit) as stop:
        main(["--help"])
    assert stop.value.code == 0
    return capsys.readouterr().out


def _commands():
    from uav_struct_env.datasets.__main__ import main as dataset_main

    commands = [study_main, render_main, dataset_main]
    try:
        from uav_struct_env.training.train_detector import main as detector_main
        from uav_struct_env.training.train_refiner import main as refiner_main
    except ImportError:  # the train extra (torch)
        return commands
    return [*commands, detector_main, refiner_main]


@pytest.mark.parametrize("main", _commands(), ids=lambda m: m.__module__)
def test_every_option_with_a_value_shows_its_default_in_help(main, capsys):
    text = _help(main, capsys)
    options = text.split("options:", 1)[1]
    entries = re.split(r"\n  (?=-)", options)[1:]
    with_value = [e for e in entries if re.match(r"-[-\w]+(, -[-\w]+)? [A-Z{]", e)]
    assert with_value
    for entry in with_value:
        if entry.startswith("--version"):
            continue
        assert "default" in " ".join(entry.split()), entry


def test_pybullet_and_egl_print_nothing(tmp_path):
    code = (
        "import uav_struct_env\n"
        "for r in ('tiny', 'egl'):\n"
        "    env = uav_struct_env.parallel_env(renderer=r, image_size=(64, 48))\n"
        "    env.reset(seed=0)\n"
        "    env.close()\n"
    )
    done = _run("-c", code)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "" and done.stderr == ""


def test_image_size_options_read_width_x_height_and_refuse_what_the_env_cannot_render():
    import argparse

    from uav_struct_env.validate import image_size_argument

    assert image_size_argument("320x180") == (320, 180) and image_size_argument("64X36") == (64, 36)
    for bad, why in (("320", "WIDTHxHEIGHT"), ("320x", "WIDTHxHEIGHT"), ("-3x5", "WIDTHxHEIGHT"),
                     ("8x8", "16-8192 px"), ("8193x100", "16-8192 px"), ("8000x8000", "at most")):
        with pytest.raises(argparse.ArgumentTypeError, match=why):
            image_size_argument(bad)
    # on the command line: one line naming the option, status 2, before any work
    with pytest.raises(SystemExit) as stop:
        render_main(["--image-size", "8x8"])
    assert stop.value.code == 2
