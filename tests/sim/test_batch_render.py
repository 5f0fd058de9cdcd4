"""The batched renderer (uav_struct_env.sim.batch) against pybullet's TinyRenderer, and in the env."""

from __future__ import annotations

import numpy as np
import pytest

import uav_struct_env
from uav_struct_env.errors import ClosedError, ConfigError
from uav_struct_env.sim.batch import MAX_BATCH_PIXELS, BatchScene, BatchView, render_batch
from uav_struct_env.sim.batch.agreement import compare, random_views
from uav_struct_env.sim.batch.scene import ground_grid
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.world import SiteWorld
from uav_struct_env.site import make_site, paper_site

SMALL = Camera().scaled(128, 72)


@pytest.fixture(scope="module")
def columns() -> tuple[SiteWorld, BatchScene]:
    world = SiteWorld(paper_site("columns"), renderer="tiny", image_size=(128, 72),
                      rng=np.random.default_rng(3))
    yield world, BatchScene(world)
    world.close()


def _env(renderer: str, **kwargs):
    return uav_struct_env.parallel_env("train", renderer=renderer, **kwargs)


def test_agrees_with_tinyrenderer_on_the_paper_site(columns):
    world, scene = columns
    result = compare(world, scene, random_views(world, np.random.default_rng(0), 30), SMALL)
    assert result.views == 30 and result.landmark_views > 300
    assert result.pixel_agreement >= 0.99
    assert result.landmark_agreement >= 0.999
    assert result.rgb_mean_abs_diff < 1.0  # same texels, same lighting (0-255 scale)


@pytest.mark.parametrize("kwargs", [
    {"site": "random", "texture_seed": 4},
    {"site": "tests/data/ifc/duplex.ifc", "stage": "Roof/slab", "marker_size": None},
    {"stage": "columns", "activity": "busy"},  # workers, equipment, materials, airframes
], ids=["random site", "duplex.ifc", "busy activity"])
def test_agrees_with_tinyrenderer_on_other_sites(kwargs):
    if "duplex" in str(kwargs.get("site")):
        pytest.importorskip("ifcopenshell")
    env = _env("tiny", **kwargs)
    env.reset(seed=1)
    try:
        world = env.world
        result = compare(world, BatchScene(world), random_views(world, np.random.default_rng(1), 16),
                         env.camera)
    finally:
        env.close()
    assert result.pixel_agreement >= 0.99
    assert result.landmark_agreement >= 0.999


def test_depth_and_ids_match_pybullet(columns):
    world, scene = columns
    T = random_views(world, np.random.default_rng(5), 1)[0]
    ours = render_batch([BatchView(scene, T, SMALL)])[0]
    ref = world.render(T, SMALL, depth=True, segmentation=True)
    same = (ours.segmentation == ref.segmentation) & (ref.segmentation >= 0)
    assert same.mean() > 0.5  # the view shows the site
    assert np.abs(ours.depth - ref.depth)[same].max() < 0.01  # metres
    assert (ours.depth[ours.segmentation < 0] == SMALL.far).all()
    assert set(np.unique(ours.segmentation)) <= {-1, *world.body_ids.values()}


def _looking(xyz, down: bool) -> np.ndarray:
    """cam_from_world of a camera at ``xyz`` looking straight down (or up), image x along world x."""
    z = np.array([0.0, 0.0, -1.0 if down else 1.0])
    x = np.array([1.0, 0.0, 0.0])
    world_from_cam = np.eye(4)
    world_from_cam[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    world_from_cam[:3, 3] = xyz
    return np.linalg.inv(world_from_cam)


def test_ground_grid_reads_the_ground_mesh(columns):
    world, scene = columns
    ground = next(e for e in world.elements if e.kind == "ground")
    grid = scene.ground
    assert grid is not None and scene.ground_seg == world.body_ids["ground"]
    assert 2 * int(grid.cells.sum()) == len(ground.mesh.faces) == 1666
    assert grid.cells.shape == (len(grid.x) - 1, len(grid.y) - 1)
    # one missing cell under each of the paper site's 8 ground markers (1.5 m sheets)
    assert (grid.cells == 0).sum() == 8
    assert np.all(np.diff(grid.x) > 0) and np.all(np.diff(grid.u) > 0)
    assert grid.u[0] == 0.0 and grid.u[-1] == 1.0
    # not a grid: a marker sheet (above z = 0), a ground whose u is not a function of x alone
    assert ground_grid(next(e for e in world.elements if e.kind == "marker")) is None
    uv = ground.uv.copy()
    uv[5, 0] += 1e-3
    bent = type(ground)("ground", "ground", ground.mesh.copy(), ground.texture)
    bent.mesh.visual.uv = uv
    assert ground_grid(bent) is None
    assert BatchScene(world, ground_per_pixel=False).n_triangles == scene.n_triangles + 1666


def test_per_pixel_ground_renders_what_its_triangles_do(columns):
    world, scene = columns
    triangles = BatchScene(world, ground_per_pixel=False)
    marker = world.body_ids["marker 0"]
    poses = random_views(world, np.random.default_rng(7), 40)
    views = [BatchView(scene, T, SMALL) for T in poses]
    views += [BatchView(scene, _looking((2.0, -3.3, 4.0), True), SMALL, marker),  # its hole, seen
              BatchView(scene, _looking((2.0, -3.3, 4.0), True), SMALL),
              BatchView(scene, _looking((2.0, -3.3, -2.0), False), SMALL)]  # from below: culled
    ours = render_batch(views)
    ref = render_batch([view._replace(scene=triangles) for view in views])
    for a, b in zip(ours, ref, strict=True):
        assert (a.segmentation == b.segmentation).mean() >= 0.999
        assert (a.rgb == b.rgb).all(axis=2).mean() >= 0.999
        assert np.abs(a.depth - b.depth).max() < 1e-3
    ground = world.body_ids["ground"]
    hole, covered, below = ours[-3:]
    assert (hole.segmentation == ground).mean() > 0.3 and (hole.segmentation == -1).sum() > 100
    assert (covered.segmentation == marker).sum() == (hole.segmentation == -1).sum()
    assert not (below.segmentation == ground).any()


def test_views_of_several_worlds_in_one_call_equal_separate_calls(columns):
    world, scene = columns
    other = SiteWorld(make_site("random", rng=np.random.default_rng(9)), renderer="tiny", image_size=(64, 36))
    try:
        scene2 = BatchScene(other)
        poses = (random_views(world, np.random.default_rng(2), 3)
                 + random_views(other, np.random.default_rng(3), 3))
        small = Camera().scaled(64, 36)
        views = [BatchView(scene, poses[0], SMALL), BatchView(scene2, poses[3], small),
                 BatchView(scene, poses[1], small), BatchView(scene2, poses[4], SMALL)]
        together = render_batch(views)
        for view, frame in zip(views, together, strict=True):
            alone = render_batch([view])[0]
            assert frame.rgb.shape == (view.camera.height, view.camera.width, 3)
            np.testing.assert_array_equal(frame.rgb, alone.rgb)
            np.testing.assert_array_equal(frame.segmentation, alone.segmentation)
            np.testing.assert_array_equal(frame.depth, alone.depth)
    finally:
        other.close()
    with pytest.raises(ClosedError, match=r"SiteWorld of views\[1\].scene is closed"):
        render_batch([BatchView(scene, poses[0], SMALL), BatchView(scene2, poses[3], SMALL)])


def test_hidden_body_is_not_drawn(columns):
    world, scene = columns
    T = random_views(world, np.random.default_rng(6), 1)[0]
    world_from_cam = np.linalg.inv(T)
    pose = world_from_cam.copy()
    pose[:3, 3] = world_from_cam[:3, 3] + 3.0 * world_from_cam[:3, 2]  # 3 m ahead of the camera
    body = world.add_body((0.5, 0.5, 0.5), (1.0, 0.0, 0.0, 1.0), pose)
    try:
        seen, hidden = render_batch([BatchView(scene, T, SMALL), BatchView(scene, T, SMALL, body)])
        ref = world.render(T, SMALL, segmentation=True)
        assert (seen.segmentation == body).mean() > 0.05
        assert (seen.segmentation == ref.segmentation).mean() >= 0.99
        assert not (hidden.segmentation == body).any()
        red = seen.rgb[seen.segmentation == body]
        assert (red[:, 0] > 100).all() and (red[:, 1:] == 0).all()
    finally:
        world.remove_body(body)


def test_env_with_batch_renderer_observes_what_tiny_does():
    envs = [_env(r, landmark_sets=("column_tops", "slab_corners")) for r in ("tiny", "batch")]
    try:
        outs = [env.reset(seed=3) for env in envs]
        rng = np.random.default_rng(0)
        for _ in range(3):
            action = {a: rng.uniform(-0.3, 0.3, 5).astype(np.float32) for a in envs[0].agents}
            outs = [env.step(action) for env in envs]
        (obs_t, *_, info_t), (obs_b, *_, info_b) = outs
        for a in envs[0].agents:
            assert obs_b[a]["image"].shape == (72, 128, 3) and obs_b[a]["image"].dtype == np.uint8
            close = np.abs(obs_b[a]["image"].astype(int) - obs_t[a]["image"].astype(int)).max(axis=2) <= 2
            assert close.mean() >= 0.99
            for name in ("column_tops", "slab_corners"):
                np.testing.assert_array_equal(info_b[a]["landmarks"][name]["visible"],
                                              info_t[a]["landmarks"][name]["visible"])
    finally:
        for env in envs:
            env.close()


def test_env_with_batch_renderer_and_a_real_camera():
    env = _env("batch", camera="mavic2pro", image_size=(160, 120), landmark_sets=("column_tops",))
    try:
        obs, info = env.reset(seed=0)
        obs, *_ = env.step({a: np.full(5, 0.2, np.float32) for a in env.agents})
        assert obs["uav_0"]["image"].shape == (120, 160, 3)
        assert obs["uav_0"]["image"].std() > 5  # a scene, not a blank frame
    finally:
        env.close()


def test_batch_renderer_refuses_large_frames(columns):
    with pytest.raises(ConfigError, match=r"renderer='batch' draws images up to 160 x 120.*320 x 240"):
        _env("batch", image_size=(320, 240))
    world, scene = columns
    big = Camera().scaled(640, 360)
    assert 640 * 360 > MAX_BATCH_PIXELS
    with pytest.raises(ConfigError, match=r"640 x 360 = 230400 pixels.*at most"):
        render_batch([BatchView(scene, np.eye(4), big)])
    with pytest.raises(TypeError, match=r"views\[0\] must be a BatchView, got tuple"):
        render_batch([(scene, np.eye(4), SMALL)])
    with pytest.raises(ValueError, match=r"views\[0\].cam_from_world must be a finite \(4, 4\)"):
        render_batch([BatchView(scene, np.eye(3), SMALL)])
    with pytest.raises(TypeError, match="world must be a uav_struct_env.sim.world.SiteWorld, got str"):
        BatchScene("paper")


def test_env_with_batch_renderer_passes_pettingzoo_api_and_seed_tests():
    from pettingzoo.test import parallel_api_test, parallel_seed_test

    parallel_api_test(_env("batch", image_size=(64, 36), max_cycles=4), num_cycles=4)
    parallel_seed_test(lambda: _env("batch", image_size=(64, 36), max_cycles=4))
