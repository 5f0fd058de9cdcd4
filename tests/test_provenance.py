"""Every file the study, the trainer and the evaluator write says how it was made.

A table or CSV opens with the settings line, a JSON file has ``software`` and the settings, a PNG
carries the line in its ``Settings`` text chunk, and a file in a library's own format (a model,
normalization statistics, TensorBoard events) lies in a run folder whose ``train.json`` does.
"""

import json
import re
from pathlib import Path

import uav_struct_env
from uav_struct_env.outputs import INSIDE_LOCK
from uav_struct_env.provenance import git_commit, png_settings, settings_line, version_text

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _json_settings(path: Path) -> str | None:
    from uav_struct_env.study.report import settings_line as study_settings_line

    data = json.loads(path.read_text())
    if not isinstance(data, dict) or data.get("software", {}).get("version") != uav_struct_env.__version__:
        return None
    if "settings" in data:
        return data["settings"]
    return study_settings_line(data) if "config" in data else None  # the study's results.json


def _first_line(path: Path, prefix: str) -> str | None:
    first = path.read_text().splitlines()[0]
    return first[len(prefix):] if first.startswith(prefix) else None


def _run_record(path: Path, run: Path) -> str | None:
    """The settings of the training run folder ``run``, if a library-format file lies in it."""
    return _json_settings(run / "train.json") if run in path.parents else None


def _is_lock(path: Path) -> bool:
    return path.name == INSIDE_LOCK or (path.name.startswith(".") and path.name.endswith(".lock"))


def provenance(path: Path, run: Path) -> str | None:
    """The settings line ``path`` carries (or its run folder's ``train.json`` does), or None."""
    if path.suffix == ".csv":
        return _first_line(path, "# Settings: ")
    if path.suffix == ".md":
        return _first_line(path, "Settings: ")
    if path.suffix == ".png":
        return png_settings(path)
    if path.suffix == ".json":
        return _json_settings(path)
    return _run_record(path, run)


def test_settings_line_lists_what_was_given_after_the_software():
    sw = {"package": "uav-struct-env", "version": "9.9", "git_commit": "0123456789abcdef",
          "git_modified": True}
    line = settings_line({"seed": 3, "model": None, "policies": ("ppo", "random"), "overwrite": False}, sw)
    assert line == ("uav-struct-env 9.9 (git 0123456789, modified) · seed 3 · policies ppo,random · "
                    "overwrite False")
    assert version_text({**sw, "git_commit": None}) == "uav-struct-env 9.9"


def test_every_file_of_the_study_the_trainer_and_the_evaluator_says_how_it_was_made(
        quick_projection_study, tiny_ppo_run, tmp_path, load_script, capsys):
    study, _ = quick_projection_study  # `uav-struct study --quick --detector projection` (conftest)
    run, _ = tiny_ppo_run  # the trainer's smallest run: 256 agent-steps, two checkpoints
    evaluate = load_script(EXAMPLES / "evaluate_policy.py")
    ev = tmp_path / "eval"
    evaluate.main(model=str(run), policies=("ppo", "random"), episodes=1, max_cycles=4,
                  plot=str(ev / "evaluation.png"), json_out=str(ev / "eval.json"))
    evaluate.main(checkpoints=(str(run),), episodes=1, max_cycles=4,
                  plot=str(ev / "curve.png"), json_out=str(ev / "curve.json"))
    # every file each command wrote, but the output locks (``.<name>.lock``: a running command's
    # pid, not an output)
    files = sorted(p for root in (study, run, ev) for p in root.rglob("*") if p.is_file() and not _is_lock(p))
    names = {p.name for p in files}
    assert {"table1.md", "per_image.csv", "detections.csv", "results.json", "error_cdf.png", "train.json",
            "model.zip", "normalization.npz", "progress.jsonl", "evaluation.png", "eval.json",
            "curve.png", "curve.json"} <= names, names
    assert any(p.name.startswith("events.out.tfevents") for p in files)
    head = f"uav-struct-env {uav_struct_env.__version__}"
    commit = git_commit()
    for path in files:
        line = provenance(path, run)
        assert line is not None, f"{path} does not say how it was made"
        assert line.startswith(head), (path, line)
        if commit is not None:  # the commit the command ran (the checkout may move on meanwhile)
            assert re.search(r" \(git [0-9a-f]{10}(, modified)?\) ", line), (path, line)
    # the evaluator's line names what it was asked; the study's its detector, the run its seed
    assert "policies ppo,random" in png_settings(ev / "evaluation.png")
    assert "episodes 1" in json.loads((ev / "curve.json").read_text())["settings"]
    assert "projection detector" in png_settings(study / "error_cdf.png")
    assert "seed 3" in json.loads((run / "train.json").read_text())["settings"]
    capsys.readouterr()
