"""Issue 44, item 3: a time bound per frame. ``Localizer(time_budget_s=...)`` ends a call past its
budget as ``TIMED_OUT``, never with a pose, and changes nothing within it.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from localization import FailureCode, Localizer
from localization.budget import Deadline, OutOfTime
from localization.geometry.transforms import look_at, project
from localization.testing.fuzz import corrupt_detections, draw_case
from localization.verify import CONFIRM_TOLERANCE_M

#: A budget no step fits in: every check after the first instant is past it.
NO_TIME_S = 1e-9


def _clutter_case(k: int = 8027, mode: str = "clutter_2000"):
    """Fuzz case ``k`` with ``mode``'s clutter (8027: 2,055 detections, 60 candidates)."""
    case = draw_case(np.random.default_rng((19, k)))
    return case, corrupt_detections(case, mode, np.random.default_rng((44, k)))


def _localizer(case, **kw) -> Localizer:
    return Localizer(case.landmarks_xyz, case.K, association="robust", image_size=case.image_size,
                     pixel_sigma=case.pixel_sigma, tolerance_m=CONFIRM_TOLERANCE_M, **kw)


@pytest.fixture
def scene():
    X = np.array([[0.0, 0, 10], [8, 0, 10], [8, 6, 10], [0, 6, 10], [4, 3, 14]])
    T = look_at([4.0, -20.0, 18.0], [4.0, 3.0, 10.0])
    K = np.array([[800.0, 0, 640], [0, 800, 360], [0, 0, 1]])
    uv, _ = project(K, T, X)
    return X, T, uv


def test_a_deadline_names_the_step_it_stopped_before():
    Deadline(time.perf_counter() + 60.0, 1.0).check("anything")  # a minute ahead: no raise
    late = Deadline(time.perf_counter() - 2.0, 0.5)
    assert late.passed() and late.spent() >= 2.0
    spent = r"out of time: 2\.\d{3} s spent of a 0\.500 s budget .* before the vote"
    with pytest.raises(OutOfTime, match=spent):
        late.check("the vote")
    assert Deadline.after(None, 0.0) is None


def test_the_search_stops_at_its_deadline_as_timed_out():
    case, det = _clutter_case()
    est = _localizer(case, time_budget_s=NO_TIME_S).localize(det, case.prior_cam_from_world)
    assert not est.success and est.failure_code is FailureCode.TIMED_OUT
    assert "before the robust association's refinement of" in est.failure_reason
    assert (est.assignment == -1).all() and np.array_equal(est.cam_from_world, case.prior_cam_from_world)


@pytest.mark.parametrize("association", ["paper", "robust"])
def test_a_pose_finished_after_the_deadline_is_refused(scene, association):
    # five clean corners: the paper association has no step to check, its finished pose is refused
    # after the fact; the robust one stops before its first refinement
    X, T, uv = scene
    prior = T.copy()
    prior[:3, 3] += 0.5
    K = np.array([[800.0, 0, 640], [0, 800, 360], [0, 0, 1]])
    assert Localizer(X, K, association=association).localize(uv, prior).success  # without a budget
    est = Localizer(X, K, association=association, time_budget_s=NO_TIME_S).localize(uv, prior)
    assert not est.success and est.failure_code is FailureCode.TIMED_OUT
    assert est.failure_reason.startswith("out of time") and "budget" in est.failure_reason


def test_a_budget_the_call_fits_in_changes_nothing():
    case, det = _clutter_case(3, "clutter_500")
    free = _localizer(case).localize(det, case.prior_cam_from_world)
    bounded = _localizer(case, time_budget_s=600.0).localize(det, case.prior_cam_from_world)
    assert free.success and bounded.success  # a pose through the whole search and verification
    np.testing.assert_array_equal(free.cam_from_world, bounded.cam_from_world)
    np.testing.assert_array_equal(free.assignment, bounded.assignment)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_a_budget_must_be_positive_and_finite(bad):
    case, _ = _clutter_case(3)
    with pytest.raises(ValueError, match="time_budget_s"):
        _localizer(case, time_budget_s=bad)
    with pytest.raises(TypeError, match="time_budget_s"):
        _localizer(case, time_budget_s="1 s")

