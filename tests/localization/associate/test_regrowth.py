"""Regrowth: a winner that settled on a dozen right pairs and a few wrong ones is grown again.

Fuzz case ``clutter_2000`` 8027 (60 landmarks, 55 in a 3,445 x 2,352 frame through a 582 px
lens, 2,000 clutter points): the layout vote's best start paired 53 detections, 16 of them
right; refined, it settled on 17 pairs (12 right, one landmark on its neighbour's detection, four
clutter points), 2.75 m from the truth with a reported sigma of 3.7 cm -- the one confident
wrong pose of 10,000 such cases (docs/benchmarks.md, "Dense clutter at 10,000 cases"). Two of
its right pairs, with its tilt, give the structure's pose, which pairs every landmark in view.
"""

import numpy as np
import pytest

from localization import Localizer
from localization.associate.ambiguity import AMBIGUITY_MARGIN
from localization.associate.hypotheses import regrowth_hypotheses
from localization.associate.paper import candidate_landmarks
from localization.associate.robust import RobustSearch, RobustSettings
from localization.geometry.transforms import camera_center, project
from localization.pose.covariance import PriorSigmas
from localization.pose.pnp import refine_pose
from localization.testing.fuzz import corrupt_detections, draw_case
from localization.verify import CONFIRM_TOLERANCE_M

#: The former winner's pairs (detection row, landmark): 12 right, (423, 36) a neighbour's
#: detection, (1263, 7), (1632, 53), (1810, 44), (1828, 52) clutter.
FORMER_WINNER = np.array([
    [165, 5], [202, 45], [208, 55], [423, 36], [502, 51], [1259, 41], [1263, 7], [1355, 11], [1421, 1],
    [1539, 31], [1560, 15], [1632, 53], [1684, 35], [1810, 44], [1828, 52], [1857, 21], [2029, 25],
])
MARGIN_PX = 320.0


@pytest.fixture(scope="module")
def case_8027():
    case = draw_case(np.random.default_rng((19, 8027)))
    det = corrupt_detections(case, "clutter_2000", np.random.default_rng((44, 8027)), None)
    return case, det


def _search(case, det) -> RobustSearch:
    settings = RobustSettings.resolve(
        case.K, pixel_sigma=1.0, gate_px=None, coarse_gate_px=40.0, min_correspondences=4,
        prior_sigmas=PriorSigmas(), max_hypotheses=8, max_iterations=6, miss_cost=4.0,
        max_prior_mahalanobis_sq=22.46, position_offsets=((0.0, 0.0, 0.0),), shifts_per_layout=2,
        exhaustive_limit=150, max_rivals=6, max_rival_rounds=2, ambiguity_margin=AMBIGUITY_MARGIN,
        fit_quantile=1 - 1e-6,
    )
    return RobustSearch(det, case.landmarks_xyz, case.K, case.prior_cam_from_world, case.image_size,
                        MARGIN_PX, settings)


def _former_winner(case, det):
    a = np.full(det.shape[0], -1, dtype=np.int64)
    a[FORMER_WINNER[:, 0]] = FORMER_WINNER[:, 1]
    T, _ = refine_pose(case.landmarks_xyz[FORMER_WINNER[:, 1]], det[FORMER_WINNER[:, 0]], case.K,
                       case.prior_cam_from_world)
    return a, T


def test_the_winners_own_pairs_two_at_a_time_grow_into_the_structure(case_8027):
    case, det = case_8027
    truth = camera_center(case.cam_from_world)
    a, T = _former_winner(case, det)
    assert np.linalg.norm(camera_center(T) - truth) > 2.0  # the case is real: metres off
    search = _search(case, det)
    missed = int(search.missed(a[None], T[None])[0])
    assert missed > 30 and search.leaves_open(a, missed)  # 17 pairs, 52 predicted
    starts = search.regrown(a, T, missed)
    assert 0 < len(starts) <= search.settings.batch
    search.explore(starts, True, len(starts))
    _, best, T_best, best_missed = search.ranked()[0]
    assert np.linalg.norm(camera_center(T_best) - truth) < 0.05
    rows = np.flatnonzero(best >= 0)
    assert rows.size >= 50 and best_missed <= 2
    # every pair is right: its detection lies at its landmark's true projection (1 px noise)
    uv, _ = project(case.K, case.cam_from_world, case.landmarks_xyz[best[rows]])
    assert np.max(np.linalg.norm(uv - det[rows], axis=1)) < 4.0


def test_a_winner_that_explains_the_frame_is_not_regrown(case_8027):
    case, _ = case_8027
    det, a = case.detections_uv, case.true_index  # the clean detections and their landmarks
    search = _search(case, det)
    missed = int(search.missed(a[None], case.cam_from_world[None])[0])
    assert missed == 0 and not search.leaves_open(a, missed)
    assert search.regrown(a, case.cam_from_world, missed) == []
    # the hypotheses themselves, asked for: distinct starts, at most the n_distinct asked
    idx, _ = candidate_landmarks(case.landmarks_xyz, case.K, case.cam_from_world, case.image_size, MARGIN_PX)
    pairs = np.column_stack([np.arange(a.size), a])
    starts = regrowth_hypotheses(det, pairs, case.landmarks_xyz, idx, case.K, case.cam_from_world,
                                 case.prior_cam_from_world, PriorSigmas(), 20.0, 4, 40, 16)
    assert 0 < len(starts) <= 16
    assert len({b.tobytes() for b, _ in starts}) == len(starts)


@pytest.mark.parametrize(
    ("mode", "k"),
    [("ghost_shift", 4716),  # 90 landmarks and their copy: once a mix, refused as ambiguous
     pytest.param("clutter_2000", 8027, marks=pytest.mark.slow)],  # 1.7 s: 2,055 detections
)
def test_a_formerly_wrong_winner_is_now_the_structures_pose(mode, k):
    case = draw_case(np.random.default_rng((19, k)))
    det = corrupt_detections(case, mode, np.random.default_rng((44, k)), None)
    loc = Localizer(case.landmarks_xyz, case.K, association="robust", image_size=case.image_size,
                    pixel_sigma=case.pixel_sigma, verify=True, tolerance_m=CONFIRM_TOLERANCE_M)
    est = loc.localize(det, case.prior_cam_from_world)
    assert est.success, est.failure_reason
    assert np.linalg.norm(est.position - camera_center(case.cam_from_world)) < 0.05
    assert est.n_inliers >= 0.9 * len(case.true_index)
