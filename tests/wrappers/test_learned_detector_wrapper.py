"""LocalizationWrapper with the learned detector: runs on the rendered images, localizes."""

from __future__ import annotations

import numpy as np
import pytest

from localization.learned import DEFAULT_MODEL, LearnedDetector
from uav_struct_env.wrappers import make_localization_env


@pytest.mark.skipif(not DEFAULT_MODEL.is_file(), reason="no committed model")
def test_learned_detector_column_tops_paper_camera_at_half_size():
    env = make_localization_env(
        "column_tops", preset="paper", env_overrides={"image_size": (640, 360), "max_cycles": 2},
        detector="learned",
    )
    assert isinstance(env._detector, LearnedDetector) and env._detector.scale == 1.0
    obs, infos = env.reset(seed=0, options={"viewpoint": 0})
    frames = env.last_frames
    assert len(frames) == 4
    loc = [infos[a]["localization"] for a in infos]
    assert sum(x["success"] for x in loc) >= 3
    errors = [x["translation_error_m"] for x in loc if x["success"]]
    assert np.nanmedian(errors) < 1.0
    env.close()
