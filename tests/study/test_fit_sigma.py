"""The study holds the learned detector's fits to its declared noise (issue 44, item 3)."""

from __future__ import annotations

import numpy as np
import pytest

from localization.detect.guided import GUIDED_FIT_SIGMA_PX
from localization.detect.learned import FIT_PIXEL_SIGMAS_PX
from localization.geometry.camera import PAPER_K
from localization.verify import CONFIRM_TOLERANCE_M
from uav_struct_env.stack import build_stack
from uav_struct_env.study.protocol import METHODS, StudyConfig
from uav_struct_env.study.run import stack_spec


@pytest.mark.parametrize(
    ("detector", "imaging", "expected"),
    [("learned", "ideal", FIT_PIXEL_SIGMAS_PX[("landmarks_v1", "ideal")]),
     ("learned", "camera", FIT_PIXEL_SIGMAS_PX[("landmarks_v1", "camera")]),
     ("learned:active", "camera", FIT_PIXEL_SIGMAS_PX[("landmarks_active_v4", "camera")]),
     ("projection", "ideal", None)],
)
def test_the_learned_stack_declares_the_detectors_fit_sigma(detector, imaging, expected):
    config = StudyConfig(detector=detector, imaging=imaging)
    spec = stack_spec(config, next(m for m in METHODS if m.key == "slab_corners"))
    loc = build_stack(spec, PAPER_K, config.image_size, model_xyz=np.eye(4, 3)).localizer
    assert loc.fit_sigma_px == pytest.approx(expected)
    assert loc.pixel_sigma == 1.0  # the gates keep the study's noise
    assert loc.tolerance_m == (None if expected is None else CONFIRM_TOLERANCE_M)
    aruco = stack_spec(config, next(m for m in METHODS if m.key == "aruco_1.0m"))
    assert "fit_sigma_px" not in aruco.localizer_kwargs


def test_the_guided_stack_declares_its_own_fit_sigma_whatever_the_weights():
    for detector in ("guided", "guided:active"):
        spec = stack_spec(StudyConfig(detector=detector, imaging="camera"),
                          next(m for m in METHODS if m.key == "slab_corners"))
        assert spec.detector == "guided"
        assert spec.localizer_kwargs["fit_sigma_px"] == GUIDED_FIT_SIGMA_PX
        assert spec.localizer_kwargs["tolerance_m"] == CONFIRM_TOLERANCE_M
