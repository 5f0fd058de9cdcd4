"""The localization stack: one spec, one builder, the same estimate through study and wrapper."""

import numpy as np
import pytest

import uav_struct_env
from localization import Localizer
from localization.geometry.camera import PAPER_K
from uav_struct_env.errors import ConfigError
from uav_struct_env.stack import (
    ASSOCIATIONS,
    DETECTORS,
    STRUCTURAL_DETECTORS,
    StackSpec,
    build_stack,
)
from uav_struct_env.study import protocol
from uav_struct_env.study.run import _close_envs, run_unit, stack_spec
from uav_struct_env.wrappers import localization as wrapper_module
from uav_struct_env.wrappers.localize import LocalizePoses


def test_choice_lists_derive_from_the_stack():
    assert protocol.DETECTORS == STRUCTURAL_DETECTORS == ("projection", "learned", "guided")
    assert protocol.ASSOCIATIONS == ASSOCIATIONS == ("paper", "robust")
    assert wrapper_module.DETECTORS == DETECTORS == ("projection", "learned", "guided", "aruco")
    assert wrapper_module.MODES == ASSOCIATIONS


def test_policies_are_explicit_fields():
    X = np.random.default_rng(0).uniform(-5, 5, (8, 3))
    wrapper = build_stack(StackSpec(), PAPER_K, (128, 72), model_xyz=X).localizer
    assert wrapper.pixel_sigma == pytest.approx(0.1)  # 1 px at 1280 scaled to 128
    assert wrapper.gate_px == pytest.approx(0.5) and wrapper.coarse_gate_px == pytest.approx(4.0)
    study = build_stack(
        StackSpec(pixel_sigma=0.2, min_localizer_sigma_px=0.5, scale_gates=False),
        PAPER_K,
        (128, 72),
        model_xyz=X,
    )
    assert study.localizer.pixel_sigma == 0.5 and study.localizer.gate_px is None
    assert study.localizer.coarse_gate_px == 40.0 and study.detector.pixel_sigma == 0.2
    # at the paper's width the two gate policies agree
    a = build_stack(StackSpec(pixel_sigma=1.0), PAPER_K, (1280, 720), model_xyz=X).localizer
    b = Localizer(X, PAPER_K, pixel_sigma=1.0)
    assert (a.gate_px, a.coarse_gate_px) == (max(5.0, 3.0), b.coarse_gate_px)


class Fixed:
    def detect(self, image, context):
        from localization import Detections

        return Detections(np.zeros((0, 2)))


def test_spec_takes_detector_objects_and_rejects_bad_values():
    stack = build_stack(StackSpec(detector=Fixed()), PAPER_K, (1280, 720), model_xyz=np.eye(4, 3) * 3)
    frame = stack.localize(None, {}, np.eye(4))
    assert not frame.estimate.success and frame.estimate.failure_code.value == "too_few_detections"
    with pytest.raises(ConfigError, match="detector must be one of"):
        StackSpec(detector="sift")
    with pytest.raises(ConfigError, match="association must be one of"):
        StackSpec(association="greedy")
    with pytest.raises(ConfigError, match=r"miss_rate must be a number in \[0, 1\], got 2"):
        StackSpec(miss_rate=2)
    with pytest.raises(ConfigError, match="detector='aruco' needs landmarks='aruco'"):
        StackSpec(detector="aruco")
    with pytest.raises(ConfigError, match="at least 4"):
        build_stack(StackSpec(), PAPER_K, (1280, 720), model_xyz=np.zeros((3, 3)))



class Projected:
    """Detects every landmark exactly where ``T`` projects it."""

    def __init__(self, X, T):
        from localization.geometry.transforms import project

        self.uv = project(PAPER_K, T, X)[0]

    def detect(self, image, context):
        from localization import Detections

        return Detections(self.uv)


def test_a_time_budget_reaches_the_localizer_and_a_frame_past_it_fails_as_timed_out():
    from localization import FailureCode
    from localization.geometry.transforms import look_at
    from uav_struct_env.wrappers.localize import failure_code_number

    X = np.random.default_rng(0).uniform(-5, 5, (8, 3))
    T = look_at([3.0, -25.0, 15.0], [0.0, 0.0, 0.0])
    spec = StackSpec(detector=Projected(X, T), localizer_kwargs={"time_budget_s": 1e-9})
    stack = build_stack(spec, PAPER_K, (1280, 720), model_xyz=X)
    assert stack.localizer.time_budget_s == 1e-9
    est = stack.localize(None, {}, T).estimate
    assert not est.success and est.failure_code is FailureCode.TIMED_OUT
    assert failure_code_number(est.failure_code) == len(FailureCode)  # the last code, appended
    free = build_stack(StackSpec(detector=Projected(X, T)), PAPER_K, (1280, 720), model_xyz=X)
    assert free.localize(None, {}, T).estimate.success

def test_learned_weights_by_name():
    """``learned:NAME`` is ``learned`` with the named set's two files; explicit files override."""
    from localization.detect.weights import weight_set

    active = weight_set("landmarks_active_v4")
    spec = StackSpec(detector="learned:active")
    assert (spec.detector, spec.detector_model) == ("learned", active.model)
    assert spec.refiner_model == active.refiner
    assert spec == StackSpec(detector="learned", detector_model=active.model, refiner_model=active.refiner)
    assert StackSpec(detector="learned:landmarks_active_v4") == spec
    v1 = weight_set("landmarks_v1")
    mixed = StackSpec(detector="learned:active", refiner_model=v1.refiner)
    assert (mixed.detector_model, mixed.refiner_model) == (active.model, v1.refiner)
    det = build_stack(spec, PAPER_K, (1280, 720), model_xyz=np.eye(4, 3) * 3).detector
    assert (det.model_path, det.refiner.model_path) == (active.model, active.refiner)
    plain = StackSpec(detector="learned")  # the default weights, left to the detector
    assert (plain.detector_model, plain.refiner_model) == (None, None)
    with pytest.raises(ConfigError, match=r"detector 'learned:landmarks_active_v3' names unknown weights "
                                          r"'landmarks_active_v3'; 'learned:NAME' takes NAME one of "
                                          r"\('landmarks_v1', 'landmarks_active_v4', 'active'\)"):
        StackSpec(detector="learned:landmarks_active_v3")
    with pytest.raises(ConfigError, match="detects structural landmarks, not 'aruco'"):
        StackSpec(landmarks="aruco", detector="learned:active")


def test_guided_weights_by_name():
    """``guided:NAME`` is the guided detector with the named set's files; unknown names are refused."""
    from localization.detect.weights import weight_set

    active = weight_set("active")
    spec = StackSpec(landmarks="slab_corners", detector="guided:active")
    assert (spec.detector, spec.detector_model) == ("guided", active.model)
    assert spec.refiner_model == active.refiner
    assert spec == StackSpec(landmarks="slab_corners", detector="guided", detector_model=active.model,
                             refiner_model=active.refiner)
    with pytest.raises(ConfigError, match=r"detector 'guided:v9' names unknown weights 'v9'; 'guided:NAME' "
                                          r"takes NAME one of \('landmarks_v1'"):
        StackSpec(detector="guided:v9")
    for name in ("projection:active", "aruco:active"):  # only the detectors with networks take weights
        with pytest.raises(ConfigError, match="detector must be one of"):
            StackSpec(detector=name)


def test_same_spec_and_frame_give_the_same_estimate_through_study_and_wrapper():
    config = protocol.StudyConfig(
        methods=("column_tops",), n_viewpoints=1, image_size=(320, 180), pixel_sigma=0.0
    )
    method = config.selected_methods[0]
    try:
        rows, _ = run_unit(config, method.scene, 0)
    finally:
        _close_envs()
    env = uav_struct_env.parallel_env(
        stage=method.scene.stage,
        marker_size=method.scene.marker_size,
        image_size=config.image_size,
        texture_seed=config.seed,
    )
    wrapper = LocalizePoses(env, stack_spec(config, method))
    _, infos = wrapper.reset(seed=config.seed * 1000, options={"viewpoint": 0})
    assert len(rows) == len(env.possible_agents) == 4
    for row, agent in zip(rows, env.possible_agents, strict=True):
        loc = infos[agent]["localization"]
        assert row.success and loc["success"]
        np.testing.assert_allclose(
            wrapper.estimated_position(agent), [row.est_x, row.est_y, row.est_z], atol=1e-6
        )
        assert loc["translation_error_m"] == pytest.approx(row.translation_error_m, abs=1e-6)
        assert loc["rotation_error_deg"] == pytest.approx(row.rotation_error_deg, abs=1e-5)
        assert loc["n_correspondences"] == row.n_inliers and row.translation_error_m < 0.5
    env.close()
