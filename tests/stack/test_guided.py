"""The BIM-guided detector: model renders, template matching at a pose, and its place in the stack."""

import numpy as np
import pytest

from localization import Detections
from localization.detect.guided import (
    Matches,
    ModelViews,
    TemplateMatcher,
    orientation_field,
    structure_shading,
)
from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import invert, project
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.templates import SiteTemplates
from uav_struct_env.stack import StackSpec, build_stack
from uav_struct_env.stack.guided import GuidedDetector, merged


def test_templates_draw_the_model_where_it_projects(slab_view):
    site, _, info = slab_view
    templates = SiteTemplates(site)
    cam_from_world = invert(info["world_from_cam"])
    xyz = site.landmarks("slab_corners").xyz
    uv, z = project(PAPER_K, cam_from_world, xyz)
    k = int(np.argmin(z))  # the nearest corner: in the frame and seen
    Ks = np.repeat(PAPER_K[None], 2, axis=0)
    Ks[0, :2, 2] -= np.floor(uv[k]) - 24  # a 48 px patch centred on the corner
    Ks[1, :2, 2] += 5000  # a patch far off the model: nothing drawn
    views = templates.render(cam_from_world, Ks, (48, 48))
    assert views.label.shape == views.depth.shape == views.shade.shape == (2, 48, 48)
    u, v = (np.round(uv[k] - np.floor(uv[k]) + 24)).astype(int)
    near = views.depth[0, v - 1: v + 2, u - 1: u + 2]
    assert np.min(near) == pytest.approx(z[k], rel=0.03)  # the corner's own surface, nothing in front
    assert np.all(views.label[1] == -1) and np.all(np.isinf(views.depth[1]))
    shading = structure_shading(views)
    assert np.all(shading[1] == 0.5)  # the background's level only: no edge to match
    field = [np.hypot(*orientation_field(s, 0.7).transpose(2, 0, 1)) for s in shading]
    assert field[0].max() > 0.3 and field[1].max() == 0.0


def test_the_template_edge_lies_on_the_label_boundary_not_beside_it():
    label = np.zeros((1, 32, 32), np.int32)
    label[:, :, 20:] = 7  # a vertical boundary between columns 19 and 20
    label[:, 24:, :] = -1  # and the model ends below row 24
    views = ModelViews(np.zeros((1, 32, 32), np.float32), np.ones((1, 32, 32), np.float32), label)
    field = orientation_field(structure_shading(views)[0], 0.7)
    strength = np.hypot(field[..., 0], field[..., 1])
    assert set(np.argsort(strength[10])[-2:].tolist()) == {19, 20}  # centred on the boundary
    assert set(np.argsort(strength[:, 8])[-2:].tolist()) == {23, 24}
    assert field[10, 19, 0] > 0 > field[23, 8, 0]  # doubled angle: a gradient along x vs along y


def test_matcher_finds_the_corners_at_the_true_pose_and_nothing_in_a_blank_frame(slab_view):
    site, image, info = slab_view
    truth = info["landmarks"]["slab_corners"]
    matcher = TemplateMatcher(site.landmarks("slab_corners").xyz, SiteTemplates(site))
    found = matcher.find(image, invert(info["world_from_cam"]), info["intrinsics"], info["distortion"])
    visible = np.flatnonzero(truth["visible"])
    assert len(visible) >= 3
    assert set(found.index.tolist()) <= set(visible.tolist())  # never a landmark the model hides
    err = np.hypot(*(found.uv - np.asarray(truth["uv"])[found.index]).T)
    assert len(found.index) >= len(visible) - 1 and np.all(err < 2.0), err
    blank = np.full_like(image, 128)
    assert len(matcher.find(blank, invert(info["world_from_cam"]), info["intrinsics"]).index) == 0


def test_matcher_refuses_bad_input(slab_view):
    site, image, info = slab_view
    with pytest.raises(TypeError, match="templates must have render"):
        TemplateMatcher(np.zeros((4, 3)), object())
    matcher = TemplateMatcher(site.landmarks("slab_corners").xyz, SiteTemplates(site))
    with pytest.raises(ValueError, match=r"image must be an \(H, W, 3\) uint8"):
        matcher.find(image[..., 0], np.eye(4), PAPER_K)
    with pytest.raises(ValueError, match="search_px"):
        TemplateMatcher(np.zeros((4, 3)), SiteTemplates(site), search_px=0)
    with pytest.raises(ValueError, match="search_px"):
        matcher.find(image, invert(info["world_from_cam"]), PAPER_K, search_px=0)


def test_matches_replace_the_seeds_near_them_and_far_seeds_stay():
    seeds = Detections(np.array([[100.0, 100.0], [300.0, 300.0]]), np.array([0.9, 0.8]))
    found = Matches(np.array([[104.0, 102.0], [500.0, 500.0]]), np.array([0.4, 0.5]), np.array([0, 1]))
    uv, scores = merged(seeds, found, 8.0)
    np.testing.assert_allclose(uv, [[104, 102], [500, 500], [300, 300]])
    np.testing.assert_allclose(scores, [0.4, 0.5, 0.8])
    uv, _ = merged(seeds, Matches(np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64)), 8.0)
    np.testing.assert_allclose(uv, seeds.uv)


def test_guided_stack_needs_the_site_and_localizes_a_frame(slab_view):
    site, image, info = slab_view
    model = site.landmarks("slab_corners")
    with pytest.raises(ConfigError, match="needs site="):
        build_stack(StackSpec(landmarks="slab_corners", detector="guided"), PAPER_K, (1280, 720),
                    model_xyz=model.xyz)
    stack = build_stack(StackSpec(landmarks="slab_corners", detector="guided", min_localizer_sigma_px=0.5,
                                  scale_gates=False), info["intrinsics"], (1280, 720), model_xyz=model.xyz,
                        model_ids=model.ids, distortion=info["distortion"], site=site)
    assert isinstance(stack.detector, GuidedDetector) and stack.detector.anchors is not None
    gt = invert(info["world_from_cam"])
    frame = stack.localize(image, info["landmarks"], invert(info["prior_world_from_cam"]), gt)
    assert frame.estimate.success and frame.translation_error_m < 0.5
    assert frame.detections.true_ids is not None and np.sum(frame.detections.true_ids >= 0) >= 4


def test_the_study_detects_with_the_guided_detector_on_ifc_buildings_unless_told():
    from uav_struct_env.study.study import _parser, study_config

    duplex = "tests/data/ifc/duplex.ifc"
    assert study_config(_parser().parse_args(["--site", duplex])).detector == "guided"
    learned = study_config(_parser().parse_args(["--site", duplex, "--detector", "learned"]))
    assert learned.detector == "learned"
    assert study_config(_parser().parse_args([])).detector == "learned"  # the paper site


class _Candidates:
    """Fixed first-pass candidates in the learned detector's ``detect_all`` form (all of one type)."""

    def __init__(self, uv, kind):
        self.uv, self.kind = np.asarray(uv, dtype=np.float64), kind

    def detect_all(self, image):
        return self.uv, np.ones(len(self.uv)), np.full(len(self.uv), self.kind)


def test_an_unconfirmed_first_pose_leads_the_templates_to_a_confirmed_one(slab_view):
    from localization.detect.learned import LANDMARK_TYPES

    site, image, info = slab_view
    model = site.landmarks("slab_corners")
    stack = build_stack(StackSpec(landmarks="slab_corners", detector="guided", min_localizer_sigma_px=0.5,
                                  scale_gates=False, localizer_kwargs={"fit_sigma_px": 0.7}),
                        info["intrinsics"], (1280, 720), model_xyz=model.xyz, model_ids=model.ids,
                        distortion=info["distortion"], site=site)
    truth = info["landmarks"]["slab_corners"]
    seen = np.flatnonzero(truth["visible"])[:4]
    uv = np.asarray(truth["uv"])[seen] + [[0, 0], [0, 0], [0, 0], [6.0, -4.0]]  # one candidate off its corner
    guided = stack.detector
    guided.seed = _Candidates(uv, LANDMARK_TYPES.index("slab_corners"))
    prior = invert(info["prior_world_from_cam"])
    first = Detections(uv, np.ones(4))
    pose, confirmed = guided.first_pose(first, first, prior)
    assert pose is not None and not confirmed  # the four candidates alone are refused
    assert not stack.localizer.localize(first, prior).success
    frame = stack.localize(image, info["landmarks"], prior, invert(info["world_from_cam"]))
    assert frame.estimate.success and frame.translation_error_m < 0.5
    det = frame.detections  # the match replaced the candidate off its corner
    assert sorted(det.true_ids.tolist()) == sorted(np.asarray(truth["ids"])[seen].tolist())
    off = np.hypot(*(det.uv - np.asarray(truth["uv"])[np.searchsorted(truth["ids"], det.true_ids)]).T)
    assert np.all(off < 2.0), off
