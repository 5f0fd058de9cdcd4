"""Issue 19, item 1: the robust localizer never reports a confident wrong pose.

The fuzz suite draws problems with :func:`localization.testing.fuzz.draw_case` (regular and irregular
grids, coplanar and 3D layouts, short and long focal lengths, centred and off-centre principal
points, priors off by up to 3 m and 2, 2, 5 degrees, every in-frame landmark detected with 1 px
noise) and holds every robust success to ``error <= max(1 m, 10 x its position std)`` and the
covariance to calibration (median NEES within a factor 2 of its 6 degrees of freedom). Case
``k`` is drawn from ``default_rng((19, k))``, so any case reproduces alone; the default run
takes cases 0-999, the slow run all 10,000.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from localization import Detections, FailureCode, Localizer, pose_nees
from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import camera_center, look_at, make_transform, project
from localization.testing.fuzz import FuzzCase, draw_case
from localization.testing.synthetic import paper_prior

SLICE = 1_000
FULL = 10_000
DOF = 6


def _localize(case: FuzzCase):
    loc = Localizer(
        case.landmarks_xyz,
        case.K,
        association="robust",
        image_size=case.image_size,
        pixel_sigma=case.pixel_sigma,
    )
    return loc.localize(case.detections_uv, case.prior_cam_from_world)


def _run(cases: range) -> dict:
    """Localize the cases; the broken bounds, the NEES of the successes, the failure codes."""
    broken, nees, codes = [], [], {}
    for k in cases:
        case = draw_case(np.random.default_rng((19, k)))
        est = _localize(case)
        if not est.success:
            codes[est.failure_code.value] = codes.get(est.failure_code.value, 0) + 1
            continue
        err = float(np.linalg.norm(est.position - camera_center(case.cam_from_world)))
        std = float(np.sqrt(np.trace(est.covariance[:3, :3])))
        if not err <= max(1.0, 10.0 * std):
            broken.append((k, round(err, 3), round(std, 4), case.labels))
        nees.append(pose_nees(est.cam_from_world, case.cam_from_world, est.covariance))
    return {"n": len(cases), "broken": broken, "nees": np.array(nees), "codes": codes}


def _check(result: dict) -> None:
    assert result["broken"] == [], result["broken"][:20]
    n_ok = result["nees"].size
    # Not vacuous: most cases succeed (a localizer that always failed would break no bound).
    assert n_ok >= 0.8 * result["n"], (n_ok, result["codes"])
    median = float(np.median(result["nees"]))
    assert DOF / 2 <= median <= 2 * DOF, median


def test_fuzz_slice_has_no_confident_wrong_pose_and_a_calibrated_covariance():
    _check(_run(range(SLICE)))


@pytest.mark.slow
@pytest.mark.parametrize("start", range(0, FULL, SLICE))
def test_fuzz_full_has_no_confident_wrong_pose_and_a_calibrated_covariance(start):
    _check(_run(range(start, start + SLICE)))


@pytest.mark.parametrize("k", [5079, 8493])
def test_a_refit_without_outliers_on_a_degenerate_rest_keeps_the_verified_pose(k):
    # a regular coplanar grid: the outlier test drops pairs and the rest lie so that their
    # covariance is singular (it was reported inf, the NEES NaN); the verified pose stands instead
    case = draw_case(np.random.default_rng((19, k)))
    est = _localize(case)
    assert est.success and np.all(np.isfinite(est.covariance))
    loc = Localizer(case.landmarks_xyz, case.K, association="robust", image_size=case.image_size,
                    pixel_sigma=case.pixel_sigma, verify=False)
    plain = loc.localize(case.detections_uv, case.prior_cam_from_world)
    np.testing.assert_array_equal(est.cam_from_world, plain.cam_from_world)
    np.testing.assert_array_equal(est.assignment, plain.assignment)


def test_issue_19_reproduction_localizes_the_only_assignment_that_fits():
    # As issue 19 states it: a 3 x 3 grid of coplanar landmarks, a long lens with an off-centre
    # principal point, six correct detections, a prior 2.6 m / 2.8 deg off. The localizer kept
    # four detections, all wrongly identified, and reported a pose 8.44 m off with a 0.015 m
    # std. Brute force over all 60,480 assignments: only (7, 3, 5, 8, 4, 1) fits (1.15 px RMS),
    # 0.03 m from the true centre.
    X = np.array([[x, y, 8.35] for y in (-12.64, -9.41, -4.18) for x in (-11.12, -7.85, -2.3)])
    K = np.array([[8938.6, 0, 1528.2], [0, 11144.5, 863.4], [0, 0, 1]])
    det = np.array(
        [[498.3, 543.1], [870.1, 1414.8], [2455.3, 445.9], [1453.0, 67.7], [1530.1, 1013.1],
         [2275.7, 1354.3]]
    )
    R, _ = cv2.Rodrigues(np.array([1.85527, -0.90118, 0.56758]))
    centre = np.array([-27.433, -27.114, 19.896])
    prior = make_transform(R, -R @ centre)
    est = Localizer(X, K, association="robust", image_size=(3055, 1711)).localize(det, prior)
    assert est.success, est.failure_reason
    np.testing.assert_array_equal(est.assignment, [7, 3, 5, 8, 4, 1])
    err = float(np.linalg.norm(est.position - [-29.25, -27.89, 21.56]))
    assert err < 0.1
    assert err <= max(1.0, 10.0 * float(np.sqrt(np.trace(est.covariance[:3, :3]))))
    assert est.reprojection_rmse_px < 1.5


def test_a_window_onto_a_grid_that_the_prior_cannot_place_fails_as_ambiguous():
    # A long lens sees 3 x 3 bays of a 12 x 12 grid of 4 m bays; the prior is 2 m (half a bay)
    # off along x, so the true window and the one a bay over fit equally well and are equally
    # consistent with the prior: any pick would be a guess.
    X = np.array([[4.0 * i, 4.0 * j, 10.0] for j in range(12) for i in range(12)])
    K = np.array([[6000.0, 0, 1000.0], [0, 6000.0, 750.0], [0, 0, 1]])
    size = (2000, 1500)
    T = look_at([22.0, -20.0, 40.0], [22.0, 22.0, 10.0])
    uv, depth = project(K, T, X)
    vis = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= 1999) & (uv[:, 1] >= 0) & (uv[:, 1] <= 1499)
    assert 6 <= vis.sum() <= 20
    prior = np.linalg.inv(np.linalg.inv(T) + np.pad(np.array([[2.0], [0], [0]]), ((0, 1), (3, 0))))
    est = Localizer(X, K, association="robust", image_size=size).localize(uv[vis], prior)
    assert not est.success
    assert est.failure_code is FailureCode.AMBIGUOUS
    assert "ambiguous" in est.failure_reason and "m apart" in est.failure_reason
    np.testing.assert_array_equal(est.cam_from_world, prior)


def test_the_same_grid_with_a_prior_good_to_half_a_metre_is_placed():
    # Control for the test above. With the default 3 m sigma even a prior 0.3 m off cannot
    # place the window (a bay over costs only (3.7 / 3)^2 - (0.3 / 3)^2 = 1.5); a prior known
    # to 0.5 m makes the bay over (3.7 / 0.5)^2 = 55 less likely and places it.
    X = np.array([[4.0 * i, 4.0 * j, 10.0] for j in range(12) for i in range(12)])
    K = np.array([[6000.0, 0, 1000.0], [0, 6000.0, 750.0], [0, 0, 1]])
    T = look_at([22.0, -20.0, 40.0], [22.0, 22.0, 10.0])
    uv, depth = project(K, T, X)
    vis = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= 1999) & (uv[:, 1] >= 0) & (uv[:, 1] <= 1499)
    prior = np.linalg.inv(np.linalg.inv(T) + np.pad(np.array([[0.3], [0], [0]]), ((0, 1), (3, 0))))
    loc = Localizer(
        X, K, association="robust", image_size=(2000, 1500), prior_sigmas=(0.5, (2.0, 2.0, 5.0))
    )
    est = loc.localize(uv[vis], prior)
    assert est.success, est.failure_reason
    assert np.linalg.norm(est.position - camera_center(T)) < 0.05


def test_a_minimal_fit_of_wrong_detections_that_explains_half_its_prediction_fails(association_case):
    """A render of the duplex IFC building (tests/data/association_duplex_minimal_fit.json):
    eight slab corners in view, eight detections, none of them a corner. Four of them fit a pose
    near the prior, and the association used to report it, 6.48 m off; that pose projects all
    eight corners into the image and explains four."""
    c = association_case("association_duplex_minimal_fit.json")
    assert np.all(c["true_ids"] == -1)
    loc = Localizer(c["landmarks_xyz"], c["K"], image_size=tuple(c["image_size"]),
                    margin_px=float(c["margin_px"]))
    est = loc.localize(Detections(c["detections_uv"], c["scores"]), c["prior_cam_from_world"])
    assert not est.success
    assert est.failure_code is FailureCode.NO_CONSISTENT_ASSOCIATION
    assert "pairs only 4 detections (the minimum) and leaves 4 of the 8 landmarks" in est.failure_reason


def _two_openings():
    """A 3 x 2.5 m opening and a 1.5 x 1.2 m one beside it in one slab, seen from 20 m, and their
    projections with 0.5 px noise (openings of one shape would make four corners ambiguous)."""
    X = np.array([[0, 0, 6], [3, 0, 6], [3, 2.5, 6], [0, 2.5, 6],
                  [6, 3, 6], [7.5, 3, 6], [7.5, 4.2, 6], [6, 4.2, 6]], dtype=float)
    T = look_at([4.5, -16.0, 18.0], [4.5, 1.5, 6.0])
    uv, depth = project(PAPER_K, T, X)
    assert np.all(depth > 0) and np.all((uv >= 0) & (uv < PAPER_IMAGE_SIZE)), "all eight in view"
    return X, T, uv + np.random.default_rng(0).normal(0.0, 0.5, uv.shape)


def test_a_minimal_fit_is_refused_only_when_half_its_prediction_goes_unmatched():
    """Four right detections of one opening while the other opening's four corners project into
    the image unmatched: refused (the image cannot tell it from a coincidence). One more corner
    detected, or the other opening not in the model, and the same four give a pose."""
    X, T, uv = _two_openings()
    prior = paper_prior(T, 3)
    loc = Localizer(X, PAPER_K, image_size=PAPER_IMAGE_SIZE)
    half = loc.localize(uv[:4], prior)
    assert half.failure_code is FailureCode.NO_CONSISTENT_ASSOCIATION
    assert "leaves 4 of the 8" in half.failure_reason
    five = loc.localize(uv[:5], prior)
    assert five.success and five.assignment.tolist() == [0, 1, 2, 3, 4]
    six = Localizer(X[:6], PAPER_K, image_size=PAPER_IMAGE_SIZE).localize(uv[:4], prior)
    assert six.success and six.assignment.tolist() == [0, 1, 2, 3]  # two of six unmatched
    for est in (five, six):
        assert np.linalg.norm(est.position - camera_center(T)) < 0.5
