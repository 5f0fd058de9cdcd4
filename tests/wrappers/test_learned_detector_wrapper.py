"""LocalizationWrapper with the learned detector: runs on the rendered images, localizes."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from localization.detect.learned import DEFAULT_MODEL, LearnedDetector
from localization.detect.refiner import DEFAULT_REFINER
from uav_struct_env.errors import ConfigError
from uav_struct_env.wrappers import make_localization_env


@pytest.mark.skipif(not DEFAULT_MODEL.is_file(), reason="no committed model")
def test_learned_detector_column_tops_paper_camera_at_half_size(tmp_path):
    # weights given by path (copies of the committed ones) are the ones the detector runs
    model, refiner = tmp_path / "kp.onnx", tmp_path / "ref.onnx"
    shutil.copy(DEFAULT_MODEL, model)
    shutil.copy(DEFAULT_REFINER, refiner)
    env = make_localization_env(
        "column_tops", preset="paper", env_overrides={"image_size": (640, 360), "max_cycles": 2},
        detector="learned", detector_model=model, refiner_model=str(refiner),
    )
    assert isinstance(env.stack.detector, LearnedDetector) and env.stack.detector.scale == 1.0
    assert env.stack.detector.model_path == model and env.stack.detector.refiner.model_path == refiner
    obs, infos = env.reset(seed=0, options={"viewpoint": 0})
    frames = env.last_frames
    assert len(frames) == 4
    loc = [infos[a]["localization"] for a in infos]
    assert sum(x["success"] for x in loc) >= 3
    errors = [x["translation_error_m"] for x in loc if x["success"]]
    assert np.nanmedian(errors) < 1.0
    env.close()


def test_learned_weights_are_rejected_for_other_detectors_and_missing_files(tmp_path):
    with pytest.raises(ConfigError, match=r"detector_model applies to detector='learned' or 'guided' only, "
                                          r"got detector='projection'"):
        make_localization_env("column_tops", detector_model=DEFAULT_MODEL)
    missing = tmp_path / "nope.onnx"
    with pytest.raises(ConfigError, match=r"refiner_model must be an existing ONNX file, got "
                                          r".*nope\.onnx"):
        make_localization_env("column_tops", detector="learned", refiner_model=missing)
