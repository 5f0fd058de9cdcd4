"""benchmarks/site_conditions_study.py: the figures it derives from a study's per-image table."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench(load_script):
    return load_script(ROOT / "benchmarks" / "site_conditions_study.py")


def _per_image(tmp_path: Path, rows: list[tuple]) -> Path:
    """A per_image.csv with the columns these figures read."""
    path = tmp_path / "per_image.csv"
    lines = ["method,success,n_visible,n_true_detections,n_assigned,n_correct"]
    lines += [",".join(str(v) for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_exact_f1_counts_the_landmarks_of_views_no_pnp_can_pose_as_misses(bench, tmp_path):
    rows = bench.read_per_image(_per_image(tmp_path, [
        ("slab_corners", True, 5, 5, 5, 5),
        ("slab_corners", False, 3, 3, 0, 0),  # three visible: no pose, whatever the detector
        ("slab_corners", True, 4, 3, 4, 3),
        ("column_tops", True, 12, 12, 12, 12),
    ]))
    r = 9 / 12
    assert bench.exact_f1(rows, "slab_corners") == pytest.approx(2 * r / (1 + r))
    assert bench.exact_f1(rows, "column_tops") == 1.0
    # the posable views: 2 of them, both posed; F1 over them pools 8 correct of 9 assigned, 8 true
    posed, views, f1 = bench.posable_views(rows, "slab_corners")
    assert (posed, views) == (2, 2) and f1 == pytest.approx(2 * (8 / 9) * 1.0 / (8 / 9 + 1.0))


def test_unposed_short_counts_posable_views_the_detector_left_short(bench, tmp_path):
    rows = bench.read_per_image(_per_image(tmp_path, [
        ("opening_corners", False, 4, 3, 0, 0),  # four visible, three found: the detector's
        ("opening_corners", False, 4, 4, 0, 0),  # four found and no pose: the association's
        ("opening_corners", False, 3, 2, 0, 0),  # not posable at all
        ("opening_corners", True, 4, 3, 4, 3),  # posed although short
    ]))
    assert bench.unposed_short(rows, "opening_corners") == 1
    assert bench.posable_views(rows, "opening_corners")[:2] == (1, 3)
    assert bench.unposed_short(rows, "slab_corners") == 0
