"""The building model aligned with the image from the prior alone, and the guided detector's use of it."""

import numpy as np
import pytest

from localization.detect.guided import Matches
from localization.detect.learned import LANDMARK_TYPES
from localization.detect.prior_align import PriorAligner, fit_matches
from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import invert, project
from uav_struct_env.sim.templates import SiteTemplates
from uav_struct_env.stack import StackSpec, build_stack
from uav_struct_env.stack.guided import GuidedDetector
from uav_struct_env.stack.prior_starts import PriorStarts


def _pixel_error(K, cam_from_world, truth_cam_from_world, xyz):
    a, _ = project(K, cam_from_world, xyz)
    b, _ = project(K, truth_cam_from_world, xyz)
    return float(np.median(np.hypot(*(a - b).T)))


def test_the_model_drawn_at_the_prior_is_aligned_with_the_image(slab_view):
    site, image, info = slab_view
    K = info["intrinsics"]
    prior, truth = invert(info["prior_world_from_cam"]), invert(info["world_from_cam"])
    xyz = site.landmarks("all").xyz
    aligner = PriorAligner(SiteTemplates(site))
    hypotheses = aligner.align(image, prior, K)
    assert 1 <= len(hypotheses) <= 2
    assert hypotheses[0].score >= hypotheses[-1].score
    before = _pixel_error(K, prior, truth, xyz)
    after = min(_pixel_error(K, h.cam_from_world, truth, xyz) for h in hypotheses)
    assert before > 150.0 and after < 15.0, (before, after)  # the prior's landmarks 226 px off, 10.7 here
    # the truth draws the model on the image better than the prior, and than the alignment
    assert aligner.score(image, truth, K) > max(h.score for h in hypotheses) > aligner.score(image, prior, K)


def test_no_hypothesis_without_the_model_in_the_frame(slab_view):
    site, image, info = slab_view
    away = np.diag([-1.0, 1.0, -1.0, 1.0]) @ invert(info["prior_world_from_cam"])  # turned round
    aligner = PriorAligner(SiteTemplates(site))
    assert aligner.align(image, away, info["intrinsics"]) == []
    assert aligner.score(image, away, info["intrinsics"]) == -1.0


def test_aligner_refuses_bad_input(slab_view):
    site, image, info = slab_view
    with pytest.raises(TypeError, match="templates must have render"):
        PriorAligner(object())
    with pytest.raises(ValueError, match="zooms and angles_deg"):
        PriorAligner(SiteTemplates(site), zooms=())
    with pytest.raises(ValueError, match="scale"):
        PriorAligner(SiteTemplates(site), scale=2.0)
    with pytest.raises(ValueError, match=r"image must be an \(H, W, 3\) uint8"):
        PriorAligner(SiteTemplates(site)).align(image[..., 0], np.eye(4), PAPER_K)


def test_fit_matches_recovers_the_pose_through_an_outlier_and_needs_four():
    rng = np.random.default_rng(5)
    xyz = rng.uniform([-8, -8, 0], [8, 8, 6], size=(10, 3))
    truth = np.eye(4)
    truth[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down
    truth[:3, 3] = [0.5, -0.3, 30.0]
    uv, _ = project(PAPER_K, truth, xyz)
    uv[3] += [40.0, -25.0]  # one match on the wrong corner
    guess = truth.copy()
    guess[:3, 3] += [0.8, -0.5, 1.5]
    found = Matches(uv, np.ones(10), np.arange(10))
    fitted = fit_matches(xyz, found, PAPER_K, None, guess)
    assert fitted is not None
    np.testing.assert_allclose(fitted[:3, 3], truth[:3, 3], atol=1e-4)
    three = Matches(uv[:3], np.ones(3), np.arange(3))
    assert fit_matches(xyz, three, PAPER_K, None, guess) is None


class _NoCandidates:
    """A first-pass detector that finds nothing (``detect_all``)."""

    def detect_all(self, image):
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64)


def _stack(site, info, **detector_kwargs):
    model = site.landmarks("slab_corners")
    stack = build_stack(StackSpec(landmarks="slab_corners", detector="guided", min_localizer_sigma_px=0.5,
                                  scale_gates=False, localizer_kwargs={"fit_sigma_px": 0.7}),
                        info["intrinsics"], (1280, 720), model_xyz=model.xyz, model_ids=model.ids,
                        distortion=info["distortion"], site=site)
    stack.detector.seed = _NoCandidates()
    for key, value in detector_kwargs.items():
        setattr(stack.detector, key, value)
    return stack


def test_without_any_candidate_the_alignment_gives_the_pose_and_its_gate_can_refuse_it(slab_view):
    site, image, info = slab_view
    prior, truth = invert(info["prior_world_from_cam"]), invert(info["world_from_cam"])
    stack = _stack(site, info)
    assert stack.detector.types == (LANDMARK_TYPES.index("slab_corners"),)
    frame = stack.localize(image, info["landmarks"], prior, truth)
    assert frame.estimate.success and frame.translation_error_m < 0.3
    assert np.sum(frame.detections.true_ids >= 0) >= 4
    # a pose confirmed from an alignment must draw the model better than the alignment did
    strict = _stack(site, info, min_gain=10.0)
    frame = strict.localize(image, info["landmarks"], prior, truth)
    assert not frame.estimate.success and len(frame.detections) == 0


def _set_stack(site, info, landmarks):
    model = site.landmarks(landmarks)
    return build_stack(StackSpec(landmarks=landmarks, detector="guided", min_localizer_sigma_px=0.5,
                                 scale_gates=False, localizer_kwargs={"fit_sigma_px": 0.7}),
                       info["intrinsics"], (1280, 720), model_xyz=model.xyz, model_ids=model.ids,
                       distortion=info["distortion"], site=site)


def test_the_sets_of_a_frame_share_the_learned_run_and_the_starts_and_detect_as_alone(slab_view):
    site, image, info = slab_view
    image = image.copy()
    image[0, 0, 0] ^= 1  # a frame no earlier test has seen (the shared starts remember the last ones)
    slab, openings = _set_stack(site, info, "slab_corners"), _set_stack(site, info, "opening_corners")
    assert slab.detector.seed is openings.detector.seed
    assert slab.detector.prior_starts is openings.detector.prior_starts
    aligner = slab.detector.prior_starts.aligner
    calls = []
    original = aligner.align
    aligner.align = lambda *args: calls.append(1) or original(*args)
    prior = invert(info["prior_world_from_cam"])
    starts = [list(d.starts(image, prior)) for d in (slab.detector, openings.detector)]
    assert len(calls) == 1 and len(starts[0]) >= 1
    # the shared starts are those a detector with its own computes
    alone = GuidedDetector(openings.detector.seed, openings.detector.types, openings.detector.localizer,
                           openings.detector.matcher, "opening_corners", anchors=openings.detector.anchors)
    assert alone.prior_starts is not openings.detector.prior_starts
    for (a, sa), (b, sb) in zip(starts[1], alone.starts(image, prior), strict=True):
        np.testing.assert_array_equal(a, b)
        assert sa == sb
    context = {"prior_cam_from_world": prior}
    shared = openings.detector.detect(image, context)
    np.testing.assert_array_equal(shared.uv, alone.detect(image, context).uv)


def test_starts_for_another_camera_are_refused(slab_view):
    site, _, info = slab_view
    d = _set_stack(site, info, "slab_corners").detector
    K = np.array(info["intrinsics"], dtype=np.float64)
    K[:2, :3] *= 2.0  # the same camera at twice the resolution
    other = PriorStarts(d.aligner, d.prior_starts.wide, K, info["distortion"])
    with pytest.raises(ValueError, match="the localizer's camera"):
        GuidedDetector(d.seed, d.types, d.localizer, d.matcher, "slab_corners", prior_starts=other)
    with pytest.raises(TypeError, match="PriorAligner and a TemplateMatcher"):
        PriorStarts(object(), d.prior_starts.wide, info["intrinsics"])
