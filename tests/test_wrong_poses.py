"""``benchmarks/wrong_poses.py count``: issue 44's wrong successes read from ``per_image.csv`` files."""

from __future__ import annotations

import csv
import importlib.util
from pathlib import Path

import pytest

from localization.metrics import pose_errors

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


def _recording(tmp_path, true_ids_shift: int = 0, truth_shift_m: float = 0.0):
    """One recorded frame of a 3 x 4 column grid seen from 25 m, 0.5 px noise, and its study row.

    ``truth_shift_m``: the recorded truth moved along x after the localization (its pose then that
    far off).
    """
    import pickle

    import numpy as np

    from localization import Detections, Localizer
    from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
    from localization.geometry.transforms import camera_center, look_at, project
    from localization.testing.synthetic import paper_prior

    xs, ys = np.meshgrid([0.0, 4.0, 8.0], [0.0, 4.0, 7.0, 11.0])
    xyz = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 7.0)])
    truth = look_at([4.0, -20.0, 15.0], [4.0, 5.5, 4.0])
    uv = project(PAPER_K, truth, xyz)[0] + np.random.default_rng(0).normal(0.0, 0.5, (len(xyz), 2))
    loc = Localizer(xyz, PAPER_K, association="robust", image_size=PAPER_IMAGE_SIZE, fit_sigma_px=0.7,
                    tolerance_m=1.0)
    prior = paper_prior(truth, 1)
    est = loc.localize(Detections(uv), prior)
    assert est.success
    truth = truth.copy()
    truth[:3, 3] -= truth[:3, :3] @ np.array([truth_shift_m, 0.0, 0.0])  # the centre moved by +x
    ids = np.arange(len(xyz))
    true_ids = ids.copy()
    true_ids[0] = (true_ids[0] + true_ids_shift) % len(xyz)  # a pair labelled wrong, the geometry as it was
    records = tmp_path / "rec"
    records.mkdir()
    rec = {"landmarks": "column_tops", "localizer": loc, "uv": uv, "scores": None, "true_ids": true_ids,
           "model_ids": ids, "prior": prior, "gt": truth, "prior_sigmas": None, "warm_start": None,
           "success": True, "translation_error_m": float(np.linalg.norm(camera_center(est.cam_from_world)
                                                                       - camera_center(truth))),
           "cam_from_world": est.cam_from_world, "n_inliers": est.n_inliers, "detector": "projection",
           "image": None, "site": None}
    (records / "1_00000.pkl").write_bytes(pickle.dumps(rec))
    study = tmp_path / "study"
    study.mkdir()
    c = camera_center(truth)
    columns = ("method", "success", "translation_error_m", "crb_translation_m", "crb_pixel_sigma_px",
               "gt_x", "gt_y", "gt_z")
    with (study / "per_image.csv").open("w", newline="") as f:
        f.write("# settings line\n")
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerow(dict(zip(columns, ("column_tops", True, rec["translation_error_m"], 0.05, 0.5, *c),
                                 strict=True)))
    return records, study, rec


def test_diagnose_counts_a_right_success_and_its_fit(tmp_path, capsys):
    records, study, rec = _recording(tmp_path)
    totals = wrong_poses.diagnose([(records, study)])
    assert totals["successes"] == 1 and totals["right"] == 1 and totals["wrong"] == 0
    assert totals["beyond_3x"] == 0 and totals["refused_right"] == 0
    assert 0.0 <= totals["chance_wrong"] < 1e-3  # 1 m is 20 bounds away
    _, _, est = wrong_poses._replay_one(rec)
    d = wrong_poses.diagnosis(rec, est)
    assert d["pairs"] == 12 and d["wrong_pairs"] == 0 and d["sigma_px"] == 0.7
    # the fit's residuals show the 0.5 px noise (12 pairs, 18 degrees of freedom), not the declared 0.7
    assert 0.3 < d["posterior_sigma_px"] < 0.7
    assert d["posterior_level_m"] == pytest.approx(d["level_m"])  # the declared sigma is the larger
    err = pose_errors(est.cam_from_world, rec["gt"])[0]
    assert totals["median_error_m"] == err and totals["median_error_bounds"] == err / 0.05  # one success
    out = capsys.readouterr().out
    assert "successes    1: right 1 (refused 0)" in out
    assert f"median error {err:.4f} m ({err / 0.05:.3f}x the bound)" in out


def test_diagnose_names_a_wrong_pair_and_scales_the_level_with_a_loose_fit(tmp_path):
    records, study, rec = _recording(tmp_path, true_ids_shift=1)
    _, _, est = wrong_poses._replay_one(rec)
    assert wrong_poses.diagnosis(rec, est)["wrong_pairs"] == 1
    # a recording without ground truth (a detector that knows none): no pair can be shown right
    assert wrong_poses.diagnosis(rec | {"true_ids": None}, est)["wrong_pairs"] == 12
    rec["localizer"].fit_sigma_px = 0.2  # a detector declaring 0.2 px: the residuals show more
    d = wrong_poses.diagnosis(rec, est)
    assert d["posterior_sigma_px"] > 0.3
    assert d["posterior_level_m"] == pytest.approx(d["level_m"] * d["posterior_sigma_px"] / 0.2)


def test_diagnose_wants_one_study_per_recording(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        wrong_poses.main(["diagnose", str(tmp_path / "a"), str(tmp_path / "b"), "--studies", str(tmp_path)])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "one --studies folder per recordings folder, got 2 recordings and 1 studies" in err


def test_diagnose_lists_a_wrong_success_first(tmp_path, capsys):
    records, study, rec = _recording(tmp_path, truth_shift_m=2.0)
    totals = wrong_poses.diagnose([(records, study)])
    assert totals["successes"] == 1 and totals["wrong"] == 1 and totals["beyond_3x"] == 1
    assert totals["right"] == 0
    out = capsys.readouterr().out
    assert "  wrong: " in out and "error 2.0" in out and "pairs 12 (0 wrong)" in out
