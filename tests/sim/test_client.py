"""RenderClient: an EGL client's first frames are the frames every later render of the request gives."""

from __future__ import annotations

import numpy as np
import pytest

from localization.geometry.transforms import look_at
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.world import SiteWorld
from uav_struct_env.site import paper_site


@pytest.mark.parametrize("size", [(1280, 720), (320, 180)])
def test_first_egl_frames_equal_later_frames(egl_ok, size):
    """Unprimed, the first plugin calls differed: 200-1,000 px at 1280 x 720, ~20 px at 320 x 180."""
    if not egl_ok:
        pytest.skip("EGL rendering is unavailable on this machine")
    site = paper_site()
    pose = look_at([30.0, -25.0, 25.0], [0.0, 0.0, 5.0])
    camera = Camera().scaled(*size)
    with SiteWorld(site, renderer="egl", image_size=size) as world:
        frames = [world.render(pose, camera, segmentation=True) for _ in range(3)]
    for later in frames[1:]:
        np.testing.assert_array_equal(frames[0].rgb, later.rgb)
        np.testing.assert_array_equal(frames[0].segmentation, later.segmentation)
