"""Robust association: one-pair swaps of the winner, and detection scores as evidence."""

import numpy as np
import pytest

from localization import Detections, Localizer
from localization.associate.robust import associate_robust
from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import look_at, project
from localization.testing.synthetic import paper_prior

CASE = "association_busy_slab.json"
CLUSTER = "association_busy_cluster.json"


@pytest.mark.parametrize("with_scores", [False, True])
def test_a_scaffold_post_beside_a_corner_does_not_take_its_place(with_scores, association_case):
    """A render of the busy site (tests/data/association_busy_slab.json): four slab corners
    visible, all four detected, and a scaffold post 20 px from one of them. The pose fitted to
    the post (chi-square 23.8 on 2 dof, within the fit test) used to win because no hypothesis
    reached the corner; a swap of that one pair finds the exact fit (chi-square 0.24)."""
    c = association_case(CASE)
    a = associate_robust(
        c["detections_uv"], c["landmarks_xyz"], c["K"], c["prior_cam_from_world"], tuple(c["image_size"]),
        float(c["margin_px"]), detection_scores=c["scores"] if with_scores else None,
    )
    assert a.failure_reason is None
    ids = np.where(a.assignment >= 0, c["landmark_ids"][np.maximum(a.assignment, 0)], -1)
    np.testing.assert_array_equal(ids, c["true_ids"])  # the four corners right, clutter left out
    assert np.linalg.norm(a.cam_from_world[:3, 3] - c["cam_from_world"][:3, 3]) < 0.1


def test_the_likeliest_detections_anchor_hypotheses_when_clutter_is_the_dense_part(association_case):
    """A render of the busy site (tests/data/association_busy_cluster.json): four slab corners
    detected within 0.7 px (scores 0.72-1.00), thirteen detections of one stack of clutter
    200-300 px to their left (scores <= 0.48), the prior's corners 95 px off. The spread-out
    anchors come from the dense part of the image -- the clutter -- so no two-point hypothesis
    held two corners and the association found none; with scores the four likeliest detections
    anchor too."""
    c = association_case(CLUSTER)
    args = (c["detections_uv"], c["landmarks_xyz"], c["K"], c["prior_cam_from_world"],
            tuple(c["image_size"]), float(c["margin_px"]))
    plain = associate_robust(*args)
    assert plain.failure_reason is not None  # without scores nothing tells the corners apart
    a = associate_robust(*args, detection_scores=c["scores"])
    assert a.failure_reason is None
    ids = np.where(a.assignment >= 0, c["landmark_ids"][np.maximum(a.assignment, 0)], -1)
    np.testing.assert_array_equal(ids, c["true_ids"])
    assert np.linalg.norm(a.cam_from_world[:3, 3] - c["cam_from_world"][:3, 3]) < 0.1


def _square_view():
    """Four coplanar corners seen from 25 m, and the pixels of an extra detection beside one."""
    X = np.array([[0.0, 0.0, 3.0], [8.0, 0.0, 3.0], [8.0, 6.0, 3.0], [0.0, 6.0, 3.0]])
    T = look_at([4.0, -18.0, 16.0], [4.0, 3.0, 3.0])
    uv, _ = project(PAPER_K, T, X)
    return X, T, uv


def test_scores_decide_between_two_detections_that_fit_alike():
    """Two detections 1.0 px and 1.5 px from a landmark's projection: without scores the nearer
    is assigned; with scores 0.1 / 0.9 the likelier; ``use_scores=False`` ignores them."""
    X, T, uv = _square_view()
    det = np.vstack([uv[:3], uv[3] + [1.0, 0.0], uv[3] + [-1.5, 0.0]])
    prior = paper_prior(T, 0)
    plain = associate_robust(det, X, PAPER_K, prior, PAPER_IMAGE_SIZE, 320.0)
    assert plain.assignment.tolist() == [0, 1, 2, 3, -1]
    scores = np.array([0.9, 0.9, 0.9, 0.1, 0.9])
    scored = associate_robust(det, X, PAPER_K, prior, PAPER_IMAGE_SIZE, 320.0, detection_scores=scores)
    assert scored.assignment.tolist() == [0, 1, 2, -1, 3]
    loc = Localizer(X, PAPER_K, image_size=PAPER_IMAGE_SIZE, margin_px=320.0)
    assert loc.localize(Detections(det, scores), prior).assignment.tolist() == [0, 1, 2, -1, 3]
    assert loc.localize(det, prior).assignment.tolist() == [0, 1, 2, 3, -1]  # plain pixels: no scores
    off = Localizer(X, PAPER_K, image_size=PAPER_IMAGE_SIZE, margin_px=320.0, use_scores=False)
    assert off.localize(Detections(det, scores), prior).assignment.tolist() == [0, 1, 2, 3, -1]
    paper = Localizer(X, PAPER_K, "paper", image_size=PAPER_IMAGE_SIZE, margin_px=320.0)
    assert paper.localize(Detections(det, scores), prior).success  # paper association: scores unused


def test_scores_that_are_not_probabilities_are_refused():
    X, T, uv = _square_view()
    loc = Localizer(X, PAPER_K, image_size=PAPER_IMAGE_SIZE, margin_px=320.0)
    with pytest.raises(ValueError, match=r"scores must be probabilities in \[0, 1\].*got values in "
                                         r"\[0\.5, 7\].*use_scores=False"):
        loc.localize(Detections(uv, np.array([0.5, 7.0, 0.5, 0.5])), T)
    with pytest.raises(TypeError, match="use_scores must be True or False, got 'yes'"):
        Localizer(X, PAPER_K, use_scores="yes")
    nan_ok = loc.localize(Detections(uv, np.array([0.5, np.nan, 0.5, 0.5])), T)
    assert nan_ok.success  # a NaN score is no evidence either way
