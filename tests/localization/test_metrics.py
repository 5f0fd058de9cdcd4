import numpy as np
import pytest

from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import look_at
from localization.metrics import (
    association_scores,
    cramer_rao_bound,
    detection_rate,
    latency_summary,
    pose_errors,
    recall_at,
    summarize_errors,
)
from localization.testing.synthetic import perturb_attitude


def test_pose_errors():
    T = look_at([4, -20, 18], [4, 5.5, 3.5])
    T2 = perturb_attitude(T, [3.0, 0.0, 4.0], [0.0, 0.0, np.radians(10)])
    t, r = pose_errors(T2, T)
    assert t == pytest.approx(5.0)
    assert r == pytest.approx(10.0, abs=1e-6)


def test_summaries_use_successes_only():
    s = summarize_errors([0.1, 0.2, 100.0, 0.3], [1, 2, 90, 3], [True, True, False, True])
    assert (s.successful, s.total) == (3, 4)
    assert s.translation_median_m == pytest.approx(0.2)
    assert s.as_dict()["translation_error_m"]["median"] == pytest.approx(0.2)
    rec = recall_at([0.1, 0.4, 100.0, 0.3], [0.5, 1.5, 90, 3], [True, True, False, True])
    assert rec[(0.25, 1.0)] == pytest.approx(0.25)
    assert rec[(0.5, 2.0)] == pytest.approx(0.5)


def test_association_scores():
    s = association_scores([0, 1, -1, 2, -1], [10, 11, 12, 99, -1], model_ids=[10, 11, 12])
    # correct: 0, 1; assigned: 0, 1, 3; true detections: four (the last is a false positive)
    assert (s.correct, s.assigned, s.true_detections) == (2, 3, 4)
    assert s.precision == pytest.approx(2 / 3) and s.recall == pytest.approx(0.5)
    assert s.f1 == pytest.approx(2 * (2 / 3) * 0.5 / (2 / 3 + 0.5))
    with pytest.raises(ValueError, match="equal lengths"):
        association_scores([0], [0, 1])


def test_detection_rate():
    assert detection_rate([5, 6, -1], [5, 6, 7, 8]) == pytest.approx(0.5)
    assert np.isnan(detection_rate([], []))


def test_cramer_rao_scales_with_sigma_and_is_inf_when_degenerate():
    X = np.array([(x, y, 6.75) for y in (0, 4, 7, 11) for x in (0, 4, 8)], dtype=float)
    T = look_at([4, -20, 18], [4, 5.5, 3.5])
    b1 = cramer_rao_bound(X, T, PAPER_K, 1.0)
    b2 = cramer_rao_bound(X, T, PAPER_K, 2.0)
    assert b2.position_rms_m == pytest.approx(2 * b1.position_rms_m)
    assert b1.position_max_std_m <= b1.position_rms_m
    assert 0.01 < b1.position_rms_m < 1.0
    assert np.isinf(cramer_rao_bound(X[:2], T, PAPER_K).position_rms_m)


def test_latency_summary():
    out = latency_summary([{"total": 1.0}, {"total": 3.0}, {"total": 2.0}])
    assert out["total"]["median"] == 2.0
