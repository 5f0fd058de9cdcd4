"""The robust association's warm start: a predicted pose answers the frame only when it explains
all of it; anything less runs the full search, so what is accepted does not change."""

import numpy as np
import pytest

from localization import Localizer
from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import invert, look_at, project
from localization.testing.synthetic import paper_prior, perturb_attitude


def _frame(building, center, k, rng):
    """Column tops seen from viewpoint ``k``: (landmarks, true pose, noisy detections, order, prior)."""
    _, X = building["column_tops"]
    T = look_at([4 + 26 * np.cos(0.6 * k), 5.5 + 26 * np.sin(0.6 * k), 17], center)
    uv, _ = project(PAPER_K, T, X)
    order = rng.permutation(len(X))
    return X, T, uv[order] + rng.normal(0.0, 1.0, (len(X), 2)), order, paper_prior(T, k)


def test_a_good_prediction_answers_with_the_full_search_result(building, center, rng):
    """Predicted 5 cm and 0.1 deg off: no search, and the very pose and pairs of the full search."""
    for k in range(8):
        X, T, det, order, prior = _frame(building, center, k, rng)
        loc = Localizer(X, PAPER_K, image_size=PAPER_IMAGE_SIZE)
        full = loc.localize(det, prior)
        near = perturb_attitude(T, [0.05, -0.03, 0.04], np.radians([0.1, 0, -0.1]))
        warm = loc.localize(det, prior, warm_start=near)
        assert full.success and not full.warm_started and full.n_hypotheses > 1
        assert warm.success and warm.warm_started and warm.n_hypotheses == 1
        np.testing.assert_array_equal(warm.assignment, order)
        np.testing.assert_array_equal(warm.assignment, full.assignment)
        np.testing.assert_allclose(warm.cam_from_world, full.cam_from_world, atol=1e-6)
        np.testing.assert_allclose(warm.covariance, full.covariance, rtol=1e-5)


def test_a_frame_the_prediction_does_not_explain_is_searched(building, center, rng):
    """Clutter, a missed landmark or a prediction one column off: the full search's answer."""
    X, T, det, order, prior = _frame(building, center, 2, rng)
    loc = Localizer(X, PAPER_K, image_size=PAPER_IMAGE_SIZE)
    near = perturb_attitude(T, [0.05, 0.0, 0.0], [0.0, 0.0, 0.0])
    cases = {
        "clutter": np.vstack([det, [[640.0, 700.0]]]),  # a detection no landmark explains
        "miss": det[1:],  # a landmark the pose projects into the image, not detected
    }
    for name, d in cases.items():
        full, warm = loc.localize(d, prior), loc.localize(d, prior, warm_start=near)
        assert full.success and warm.success and not warm.warm_started, name
        np.testing.assert_array_equal(warm.assignment, full.assignment)
    # one column spacing (4 m) along x: the grid shifted onto itself explains some detections
    # with the wrong identities and predicts a row of columns that is not there
    shift = np.eye(4)
    shift[0, 3] = 4.0
    warm = loc.localize(det, prior, warm_start=invert(shift @ invert(T)))
    assert warm.success and not warm.warm_started
    np.testing.assert_array_equal(warm.assignment, order)


def test_a_prediction_the_prior_rules_out_is_searched(building, center, rng):
    """A prediction 40 m off fits nothing near the prior; the warm start never overrides it."""
    X, T, det, order, prior = _frame(building, center, 5, rng)
    loc = Localizer(X, PAPER_K, image_size=PAPER_IMAGE_SIZE)
    far = perturb_attitude(T, [40.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    warm = loc.localize(det, prior, warm_start=far)
    assert warm.success and not warm.warm_started
    np.testing.assert_array_equal(warm.assignment, order)


def test_warm_start_is_validated_and_ignored_by_the_paper_association(building, center, rng):
    X, T, det, order, prior = _frame(building, center, 1, rng)
    with pytest.raises(ValueError, match="warm_start must have shape"):
        Localizer(X, PAPER_K).localize(det, prior, warm_start=np.eye(3))
    with pytest.raises(ValueError, match="warm_start rotation block"):
        Localizer(X, PAPER_K).localize(det, prior, warm_start=np.diag([1.0, 1.0, 2.0, 1.0]))
    paper = Localizer(X, PAPER_K, association="paper")
    a, b = paper.localize(det, prior), paper.localize(det, prior, warm_start=T)
    assert not b.warm_started
    np.testing.assert_array_equal(a.assignment, b.assignment)
    np.testing.assert_array_equal(a.cam_from_world, b.cam_from_world)
