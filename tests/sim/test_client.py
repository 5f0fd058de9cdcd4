"""RenderClient: an EGL client's first frame is the frame every later render of the request gives."""

from __future__ import annotations

import numpy as np
import pytest

from localization.geometry.transforms import look_at
from uav_struct_env.sim.world import SiteWorld
from uav_struct_env.site import paper_site


def test_first_egl_frame_equals_later_frames(egl_ok):
    """Unprimed, the first 1280 x 720 frame differed from the next on 200-1,000 pixels per view."""
    if not egl_ok:
        pytest.skip("EGL rendering is unavailable on this machine")
    site = paper_site()
    pose = look_at([30.0, -25.0, 25.0], [0.0, 0.0, 5.0])
    with SiteWorld(site, renderer="egl", image_size=(1280, 720)) as world:
        first = world.render(pose, segmentation=True)
        second = world.render(pose, segmentation=True)
    np.testing.assert_array_equal(first.rgb, second.rgb)
    np.testing.assert_array_equal(first.segmentation, second.segmentation)
