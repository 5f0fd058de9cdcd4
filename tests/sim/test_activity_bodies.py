"""Activity bodies in a SiteWorld (sim/activity.py): they hide landmarks and workers."""

import numpy as np
import pytest

from localization.geometry.transforms import look_at
from uav_struct_env.sim.activity import ActivityBodies
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.world import SiteWorld
from uav_struct_env.site import paper_site
from uav_struct_env.site.activity import Box, SiteActivity, Worker


@pytest.fixture(scope="module")
def world():
    w = SiteWorld(paper_site("slab"), renderer="tiny", image_size=(320, 180), rng=np.random.default_rng(7))
    yield w
    w.close()


def _layout(site, static=(), workers=()):
    """A hand-made layout: ``SiteActivity`` with nothing placed, then the given boxes and workers."""
    layout = SiteActivity(site, "none", 0)
    layout.static, layout.workers = tuple(static), tuple(workers)
    return layout


def _standing(name, xy, z=0.0):
    return Worker(name, "ground", z, np.array([xy], dtype=float), 1.0, 0.0, (1.0, 0.5, 0.0, 1.0))


def test_a_placed_box_hides_a_landmark_in_the_render_and_in_the_ray_cast_truth(world):
    camera = Camera().scaled(320, 180)
    eye = np.array([-14.0, -12.0, 9.0])
    cam_from_world = (look_at(eye, world.site.center))
    corners = world.site.landmarks("slab_corners")
    before = world.landmark_truth("slab_corners", cam_from_world, camera,
                                  world.render(cam_from_world, camera, depth=True))
    before_rays = world.landmark_truth_raycast("slab_corners", cam_from_world, camera)
    target = int(np.flatnonzero(before["visible"])[0])
    np.testing.assert_array_equal(before["visible"], before_rays["visible"])
    # a 1 m crate on the line of sight, 4 m in front of the corner
    xyz = corners.xyz[target]
    centre = xyz + 4.0 * (eye - xyz) / np.linalg.norm(eye - xyz)
    pose = np.eye(4)
    pose[:3, 3] = centre
    bodies = ActivityBodies(world, _layout(world.site, [Box("crate", "pallet", pose, np.full(3, 0.5))]))
    try:
        after = world.landmark_truth("slab_corners", cam_from_world, camera,
                                     world.render(cam_from_world, camera, depth=True))
        after_rays = world.landmark_truth_raycast("slab_corners", cam_from_world, camera)
        for truth in (after, after_rays):
            assert not truth["visible"][target]
            others = np.arange(len(corners.ids)) != target
            np.testing.assert_array_equal(truth["visible"][others], before["visible"][others])
    finally:
        bodies.remove()
    assert world.landmark_truth_raycast("slab_corners", cam_from_world, camera)["visible"][target]


def test_a_worker_behind_a_column_is_invisible_and_beside_it_fully_visible(world):
    camera = Camera().scaled(320, 180)
    column = next(c for c in world.site.columns if c.name.endswith("00"))
    x, y = column.axis
    eye = np.array([x - 10.0, y, 1.0])
    cam_from_world = (look_at(eye, np.array([x + 1.0, y, 1.0])))
    hidden, beside = _standing("worker 0", (x + 1.0, y)), _standing("worker 1", (x + 1.0, y + 1.8))
    bodies = ActivityBodies(world, _layout(world.site, workers=[hidden, beside]))
    try:
        seen = bodies.worker_visibility(0.0, cam_from_world, camera)
        assert seen == {"worker 0": 0.0, "worker 1": 1.0}
        # both are in the rendered image region they project to: the hidden one shows no pixel
        rgb = world.render(cam_from_world, camera, segmentation=True)
        ids = set(np.unique(rgb.segmentation).tolist())
        assert bodies.worker_ids["worker 1"] in ids and bodies.worker_ids["worker 0"] not in ids
        # a crate in front of the visible worker's legs hides the two lowest of its five points
        xyz = np.array([x + 1.0, y + 1.8, 0.0])
        centre = xyz + 0.5 * (eye - xyz) / np.linalg.norm(eye - xyz)
        pose = np.eye(4)
        pose[:3, 3] = [centre[0], centre[1], 0.35]
        crate = world.add_body((0.3, 0.3, 0.35), world_from_body=pose)
        try:
            assert bodies.worker_visibility(0.0, cam_from_world, camera)["worker 1"] == pytest.approx(0.6)
        finally:
            world.remove_body(crate)
        # out of the image: visibility 0
        away = (look_at(eye, eye - [10.0, 0.0, 0.0]))
        assert bodies.worker_visibility(0.0, away, camera) == {"worker 0": 0.0, "worker 1": 0.0}
    finally:
        bodies.remove()
    assert not world._extra_bodies


def test_bodies_outside_the_view_leave_the_near_plane_alone(world):
    """A big box beside or below the camera must not pull the near plane (16-bit EGL depth) in."""
    camera = Camera().scaled(320, 180)
    eye = np.array([-20.0, 5.5, 12.0])
    cam_from_world = look_at(eye, world.site.center)
    before = world._near_plane(cam_from_world, camera)
    assert before > 5.0
    beside = np.eye(4)
    beside[:3, 3] = eye + [0.0, 6.0, -10.0]  # a truck-sized box under and to the left of the UAV
    body = world.add_body((4.0, 1.25, 1.5), world_from_body=beside)
    try:
        assert world._near_plane(cam_from_world, camera) == before
        ahead = np.eye(4)
        ahead[:3, 3] = eye + 0.5 * (world.site.center - eye)  # on the line of sight, 11 m out
        world.move_body(body, ahead)
        signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
        corners = ahead[:3, 3] + signs * [4.0, 1.25, 1.5]
        nearest = float((corners @ cam_from_world[2, :3] + cam_from_world[2, 3]).min())
        assert nearest < before / 0.8  # the box is the nearest geometry in view
        assert world._near_plane(cam_from_world, camera) == pytest.approx(0.8 * nearest)
    finally:
        world.remove_body(body)
