"""The study holds the learned detector's fits to its declared noise (issue 44, item 3)."""

from __future__ import annotations

import numpy as np
import pytest

from localization.detect.learned import FIT_PIXEL_SIGMA_PX
from localization.geometry.camera import PAPER_K
from uav_struct_env.stack import build_stack
from uav_struct_env.study.protocol import METHODS, StudyConfig
from uav_struct_env.study.run import stack_spec


@pytest.mark.parametrize(("detector", "expected"), [("learned", FIT_PIXEL_SIGMA_PX), ("projection", None)])
def test_the_learned_stack_declares_the_detectors_fit_sigma(detector, expected):
    config = StudyConfig(detector=detector)
    spec = stack_spec(config, next(m for m in METHODS if m.key == "slab_corners"))
    loc = build_stack(spec, PAPER_K, config.image_size, model_xyz=np.eye(4, 3)).localizer
    assert loc.fit_sigma_px == expected and loc.pixel_sigma == 1.0  # the gates keep the study's noise
    aruco = stack_spec(config, next(m for m in METHODS if m.key == "aruco_1.0m"))
    assert "fit_sigma_px" not in aruco.localizer_kwargs
