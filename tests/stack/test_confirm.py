"""Minimal fits held to the building's structure matched in the image (uav_struct_env.stack.confirm)."""

import numpy as np
import pytest

import uav_struct_env
from localization import FailureCode, Localizer, PoseEstimate
from localization.geometry.transforms import camera_center, invert, project
from localization.pose.pnp import refine_pose
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.templates import SiteTemplates
from uav_struct_env.stack import StackSpec, build_stack, localize_frame
from uav_struct_env.stack.confirm import PoseConfirmation, confirmation_for


@pytest.fixture(scope="module")
def slab_frames():
    """The paper site's slab stage at 1280 x 720, viewpoint 0: (site, {agent: (image, K, cam_from_world)})."""
    env = uav_struct_env.parallel_env(image_size=(1280, 720), stage="slab", renderer="tiny")
    obs, infos = env.reset(seed=0, options={"viewpoint": 0})
    frames = {a: (obs[a]["image"], infos[a]["intrinsics"], invert(infos[a]["world_from_cam"]))
              for a in ("uav_1", "uav_3")}
    yield env.site, frames
    env.close()


#: The corner a biased detector places 4 px off, per view: the minimal fit is then 1.1-1.4 m off.
BIASED = {"uav_1": 1, "uav_3": 0}


def _confirmation(site, K, fit_sigma_px=0.3, tolerance_m=0.5) -> PoseConfirmation:
    """The opening corners' confirmation, as a stack whose localizer has this noise and tolerance builds it.

    A tight noise and tolerance (the tolerance is ``max(tolerance_m, 3 x bound)``) make a pose a
    metre off beyond it on this clean render, where a detector 4 px off one corner fits to 0.9 px.
    """
    localizer = Localizer(site.landmarks("opening_corners").xyz, K, tolerance_m=tolerance_m,
                          fit_sigma_px=fit_sigma_px)
    return confirmation_for(SiteTemplates(site), site.landmarks("all").xyz, localizer, 1.0)


def _biased_uv(site, K, truth, agent):
    """The four opening corners' projections with one of them 4 px off."""
    uv, _ = project(K, truth, site.landmarks("opening_corners").xyz)
    uv[BIASED[agent], 0] += 4.0
    return uv


def _minimal_fit_off(site, K, truth, agent):
    """The pose the four opening corners give with one of them 4 px off (a fit with 2 dof left)."""
    X = site.landmarks("opening_corners").xyz
    pose, rmse = refine_pose(X, _biased_uv(site, K, truth, agent), K, truth)
    assert rmse < 1.0  # the four pairs fit it within the association's 1 px noise
    return pose


@pytest.mark.parametrize("agent", ["uav_1", "uav_3"])
def test_the_true_pose_is_confirmed_by_the_structure_it_predicts(slab_frames, agent):
    site, frames = slab_frames
    image, K, truth = frames[agent]
    verdict = _confirmation(site, K).assess(image, truth)
    assert verdict.confirmed and verdict.reason is None
    assert verdict.n_here >= 6 and verdict.n_agree >= 6  # of the stage's 8 corners
    assert verdict.shift_m < 0.1


@pytest.mark.parametrize("agent", ["uav_1", "uav_3"])
def test_a_minimal_fit_metres_off_is_refused_for_the_pose_the_structure_gives(slab_frames, agent):
    site, frames = slab_frames
    image, K, truth = frames[agent]
    pose = _minimal_fit_off(site, K, truth, agent)
    error = float(np.linalg.norm(camera_center(pose) - camera_center(truth)))
    conf = _confirmation(site, K)
    verdict = conf.assess(image, pose)
    assert error > 1.0 and error > 1.5 * verdict.tolerance_m  # a confident wrong pose by issue 44's rule
    assert not verdict.confirmed
    assert verdict.n_agree > verdict.n_here
    assert verdict.shift_m == pytest.approx(error, rel=0.25)  # the structure's pose lies near the truth
    assert "a nearby pose explains the image better" in verdict.reason
    # at a 1 px noise and a 1 m tolerance the same pose lies within its tolerance: kept
    assert _confirmation(site, K, fit_sigma_px=1.0, tolerance_m=1.0).assess(image, pose).confirmed


def test_a_pose_far_off_is_refused_for_the_structure_the_image_does_not_show(slab_frames):
    site, frames = slab_frames
    image, K, truth = frames["uav_1"]
    far = truth.copy()
    far[:3, 3] += [9.0, 0.0, 0.0]
    verdict = _confirmation(site, K).assess(image, far)
    assert not verdict.confirmed and verdict.n_here < 2
    assert "does not show the structure it predicts" in verdict.reason


def test_only_minimal_fits_are_held_and_a_refusal_is_a_failure_with_its_reason(slab_frames):
    site, frames = slab_frames
    image, K, truth = frames["uav_1"]
    conf = _confirmation(site, K)
    assert conf.max_pairs == 4
    prior = truth.copy()
    prior[:3, 3] += [3.0, -3.0, 3.0]
    wrong = _minimal_fit_off(site, K, truth, "uav_1")
    est = PoseEstimate(True, wrong, np.arange(4), reprojection_rmse_px=0.5, n_inliers=4,
                       covariance=np.eye(6), timings={"total": 0.01})
    out = conf.confirmed(image, est, prior)
    assert not out.success and out.failure_code is FailureCode.UNCONFIRMED
    assert np.array_equal(out.cam_from_world, prior) and out.n_inliers == 0
    assert np.array_equal(out.assignment, est.assignment) and "m away" in out.failure_reason
    five = PoseEstimate(True, wrong, np.arange(5), n_inliers=5)
    assert conf.confirmed(image, five, prior) is five  # spare pairs: the verification's to judge
    right = PoseEstimate(True, truth, np.arange(4), n_inliers=4)
    assert conf.confirmed(image, right, prior) is right


def test_the_stack_holds_image_detectors_to_the_structure_and_not_the_projection_detector(slab_frames):
    site, frames = slab_frames
    image, K, truth = frames["uav_1"]
    xyz = site.landmarks("opening_corners").xyz
    learned = build_stack(StackSpec(landmarks="opening_corners", detector="learned"), K, (1280, 720),
                          model_xyz=xyz, site=site)
    assert isinstance(learned.confirmation, PoseConfirmation)
    assert learned.confirmation.max_pairs == 4
    off = build_stack(StackSpec(landmarks="opening_corners", detector="learned", confirm=False), K,
                      (1280, 720), model_xyz=xyz, site=site)
    assert off.confirmation is None
    assert build_stack(StackSpec(landmarks="opening_corners", detector="learned"), K, (1280, 720),
                       model_xyz=xyz).confirmation is None  # no building model, nothing to render
    projection = build_stack(StackSpec(landmarks="opening_corners"), K, (1280, 720), model_xyz=xyz, site=site)
    assert projection.confirmation is None  # simulated detections: not the image's
    with pytest.raises(ConfigError, match="confirm must be True or False, got 'yes'"):
        StackSpec(landmarks="opening_corners", confirm="yes")


class _FixedDetections:
    """A detector returning fixed pixels (the four corners a biased detector would give)."""

    def __init__(self, uv):
        self.uv = uv

    def detect(self, image, context):
        from localization import Detections

        return Detections(self.uv)


def test_localize_frame_refuses_a_wrong_minimal_fit_and_times_the_confirmation(slab_frames):
    site, frames = slab_frames
    image, K, truth = frames["uav_1"]
    conf = _confirmation(site, K)
    uv = _biased_uv(site, K, truth, "uav_1")
    localizer = Localizer(site.landmarks("opening_corners").xyz, K)  # 1 px: the fit passes its tests
    prior = truth.copy()
    prior[:3, 3] += [1.0, -1.0, 0.5]
    plain = localize_frame(_FixedDetections(uv), localizer, image, {}, prior, truth)
    held = localize_frame(_FixedDetections(uv), localizer, image, {}, prior, truth, confirmation=conf)
    assert plain.estimate.success and plain.estimate.n_inliers == 4
    assert plain.translation_error_m > 1.0  # what the localizer alone reports as a success
    assert not held.estimate.success and held.estimate.failure_code is FailureCode.UNCONFIRMED
    assert held.estimate.timings["confirm"] > 0 and held.latency_s >= held.estimate.timings["confirm"]
