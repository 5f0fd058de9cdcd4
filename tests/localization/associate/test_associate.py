import itertools

import numpy as np

from localization.associate.paper import assign, associate_paper
from localization.associate.robust import associate_robust
from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import look_at, project
from localization.testing.synthetic import paper_prior

MARGIN = 320.0


def test_assign_plain_and_gated():
    model = np.array([[0.0, 0.0], [100.0, 0.0], [200.0, 0.0]])
    det = np.array([[101.0, 1.0], [500.0, 500.0], [1.0, -1.0]])
    plain = assign(det, model)
    assert plain.tolist()[0] == 1 and plain.tolist()[2] == 0 and plain[1] == 2  # clutter forced
    gated = assign(det, model, gate_px=10.0)
    assert gated.tolist() == [1, -1, 0]
    assert assign(np.zeros((0, 2)), model).shape == (0,)
    assert assign(det, np.zeros((0, 2))).tolist() == [-1, -1, -1]


def test_paper_association_correct_with_exact_prior(building, center):
    ids, X = building["column_tops"]
    T = look_at([4, -20, 18], center)
    uv, _ = project(PAPER_K, T, X)
    perm = np.random.default_rng(0).permutation(len(X))
    a = associate_paper(uv[perm], X, PAPER_K, T, PAPER_IMAGE_SIZE, MARGIN)
    np.testing.assert_array_equal(a.assignment, perm)


def test_robust_resolves_four_coplanar_points_by_prior(building, center):
    """Any assignment of four coplanar corners fits some pose; only the prior can tell."""
    _, X = building["opening_corners"]
    for k in range(8):
        T = look_at([4 + 25 * np.cos(k), 5.5 + 25 * np.sin(k), 15], center)
        uv, _ = project(PAPER_K, T, X)
        prior = paper_prior(T, k)
        for perm in itertools.islice(itertools.permutations(range(4)), 0, 24, 5):
            p = list(perm)
            a = associate_robust(uv[p], X, PAPER_K, prior, PAPER_IMAGE_SIZE, MARGIN)
            np.testing.assert_array_equal(a.assignment, p)


def test_robust_leaves_clutter_unassigned_and_survives_misses(building, center):
    ids, X = building["column_tops"]
    rng = np.random.default_rng(4)
    for k in range(6):
        T = look_at([4 + 28 * np.cos(0.7 * k), 5.5 + 28 * np.sin(0.7 * k), 18], center)
        uv, _ = project(PAPER_K, T, X)
        keep = rng.random(len(X)) > 0.15
        det = np.vstack(
            [uv[keep] + rng.normal(0, 1, (keep.sum(), 2)), rng.uniform([0, 0], [1280, 720], (2, 2))]
        )
        truth = np.concatenate([np.flatnonzero(keep), [-1, -1]])
        a = associate_robust(det, X, PAPER_K, paper_prior(T, k), PAPER_IMAGE_SIZE, MARGIN)
        assert a.failure_reason is None
        assigned = a.assignment >= 0
        assert np.all(a.assignment[assigned] == truth[assigned])
        assert np.sum(a.assignment[truth >= 0] == truth[truth >= 0]) >= keep.sum() - 1


def test_nothing_in_front_of_the_camera(building, center):
    _, X = building["column_tops"]
    T = look_at([4, -20, 18], [4, -40, 18])  # looking away
    a = associate_robust(np.array([[640.0, 360.0]] * 5), X, PAPER_K, T, PAPER_IMAGE_SIZE, MARGIN)
    assert a.failure_reason and "front" in a.failure_reason
    a = associate_paper(np.array([[640.0, 360.0]] * 5), X, PAPER_K, T, PAPER_IMAGE_SIZE, MARGIN)
    assert a.failure_reason and np.all(a.assignment == -1)
