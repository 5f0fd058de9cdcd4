"""``benchmarks/wrong_poses.py count``: issue 44's wrong successes read from ``per_image.csv`` files."""

from __future__ import annotations

import csv
import importlib.util
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "wrong_poses.py"
_SPEC = importlib.util.spec_from_file_location("wrong_poses", _PATH)
wrong_poses = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(wrong_poses)

_COLUMNS = ("method", "uav", "viewpoint", "success", "translation_error_m", "crb_translation_m", "n_visible",
            "n_inliers", "n_correct", "n_assigned", "reprojection_rmse_px")


def _row(method, success, error, bound, visible=6):
    return dict(zip(_COLUMNS, (method, 0, 1, success, error, bound, visible, 4, 4, 4, 0.5), strict=True))


def test_a_success_beyond_max_1m_and_three_bounds_is_wrong(tmp_path, capsys):
    rows = [
        _row("slab_corners", True, 0.9, 0.1),   # within 1 m
        _row("slab_corners", True, 1.1, 0.1),   # beyond 1 m, the bound small: wrong
        _row("slab_corners", True, 1.1, 0.5),   # within 3 x 0.5 m
        _row("slab_corners", True, 1.6, 0.5),   # beyond 1.5 m: wrong
        _row("slab_corners", False, "nan", 0.1, visible=3),
        _row("aruco_average", True, 5.0, "nan"),  # markers are not counted
    ]
    folder = tmp_path / "study"
    folder.mkdir()
    with (folder / "per_image.csv").open("w", newline="") as f:
        f.write("# settings line\n")
        writer = csv.DictWriter(f, fieldnames=_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    summary = wrong_poses.count([tmp_path])
    (entry,) = summary.values()
    assert entry["views"] == 5 and entry["posable"] == 4 and entry["poses"] == 4 and entry["wrong"] == 2
    assert entry["median_m"] == pytest.approx(1.1)
    assert "total: 4 poses, 2 wrong" in capsys.readouterr().out
    assert wrong_poses.limit_m(0.2) == 1.0 and wrong_poses.limit_m(0.5) == pytest.approx(1.5)


def test_the_building_table_refuses_a_folder_that_is_no_study(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("building_table", _PATH.with_name("building_table.py"))
    building_table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(building_table)
    (tmp_path / "sets").mkdir()
    with pytest.raises(SystemExit) as stop:
        building_table.main([str(tmp_path / "sets")])
    assert stop.value.code == 2
    err = capsys.readouterr()
    assert "not a study output folder (no per_image.csv)" in err.err and "sets" in err.err
    assert err.out == ""  # refused before any row
