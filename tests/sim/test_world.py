"""SiteWorld: buffers, metric depth, clients and lifetime, backend selection and errors."""

from __future__ import annotations

import subprocess
import sys
import tempfile
import warnings

import numpy as np
import pytest

from localization.geometry.transforms import invert, look_at, project
from uav_struct_env.errors import ClosedError, ConfigError, RendererUnavailableError
from uav_struct_env.sim import client as client_module
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.client import resolve_renderer
from uav_struct_env.sim.world import SKY_RGB, SiteWorld
from uav_struct_env.site import paper_site

SMALL = Camera().scaled(320, 180)


def _south_view(site):
    c = site.center
    return look_at(c + [0.0, -25.0, 15.0 - c[2]], c)


def test_buffers_types_and_segmentation_only_when_asked(backend, paper_world):
    world = paper_world("columns", backend)
    pose = _south_view(world.site)
    plain = world.render(pose, SMALL)
    assert plain.rgb.dtype == np.uint8 and plain.rgb.shape == (180, 320, 3)
    assert plain.depth is None and plain.segmentation is None
    full = world.render(pose, SMALL, depth=True, segmentation=True)
    assert full.depth.dtype == np.float32 and full.depth.shape == (180, 320)
    assert full.segmentation.dtype == np.int32 and full.segmentation.shape == (180, 320)
    assert set(world.body_ids.values()) >= set(np.unique(full.segmentation).tolist()) - {-1}
    # The top rows look over the horizon: sky, far depth, no body.
    assert (full.rgb[0] == SKY_RGB).all()
    assert (full.segmentation[0] == -1).all()
    np.testing.assert_allclose(full.depth[0], SMALL.far)
    # The default camera follows image_size.
    assert world.render(pose).rgb.shape == (720, 1280, 3)


def _plane_depth(camera, cam_from_world, height):
    """Depth of the horizontal plane z = height through every pixel (inf where not hit)."""
    rows, cols = np.mgrid[0:camera.height, 0:camera.width]
    rays = np.linalg.solve(camera.K, np.stack([cols.ravel(), rows.ravel(), np.ones(cols.size)]))
    world_from_cam = invert(cam_from_world)
    descent = -(world_from_cam[:3, :3] @ rays)[2]
    with np.errstate(divide="ignore"):
        depth = (world_from_cam[2, 3] - height) / descent
    depth[descent <= 0] = np.inf
    return depth.reshape(camera.height, camera.width)


@pytest.mark.parametrize("stage", ["columns", "slab"])
def test_depth_is_metric(backend, paper_world, stage):
    world = paper_world(stage, backend)
    pose = look_at([-20.0, -30.0, 18.0], world.site.center)
    camera = SMALL
    result = world.render(pose, camera, depth=True, segmentation=True)
    # Ground (z = 0) wherever it is seen; the slab top (z = 3.5) where seen from above.
    for body, height in ((world.body_ids["ground"], 0.0), (world.body_ids["slab S1"], 3.5)):
        mask = result.segmentation == body
        expected = _plane_depth(camera, pose, height)
        on_plane = mask & (np.abs(result.depth - expected) < 0.05 * expected)
        assert on_plane.sum() > 0.3 * mask.sum()  # the rest: the slab's edge and underside
        err = np.abs(result.depth[on_plane] - expected[on_plane])
        assert np.median(err) < 2e-3 * np.median(expected[on_plane]), np.median(err)


@pytest.mark.parametrize("backend_name", ["tiny", "egl"])
def test_several_worlds_in_one_process(backend_name, egl_ok):
    """Worlds coexist, each rendering only its own scene, and outlive each other's close().

    For EGL this is the regression test for the plugin's shared current context (see
    ``uav_struct_env.sim.client``): without the context switching, B's slab-stage shapes showed
    up in A's images and closing A blanked C.
    """
    if backend_name == "egl" and not egl_ok:
        pytest.skip("EGL rendering is unavailable on this machine")
    columns, slab = paper_site("columns"), paper_site("slab")
    pose = _south_view(columns)
    a = SiteWorld(columns, renderer=backend_name, rng=np.random.default_rng(1))
    alone = a.render(pose, SMALL, segmentation=True)
    b = SiteWorld(slab, renderer=backend_name, rng=np.random.default_rng(2))
    c = None
    try:
        assert a.client_id != b.client_id
        rb = b.render(pose, SMALL, segmentation=True)
        np.testing.assert_array_equal(a.render(pose, SMALL).rgb, alone.rgb)
        # b shows the slab stage: the upper columns (12 of them) are absent.
        assert len(set(np.unique(rb.segmentation).tolist()) - {-1}) < len(
            set(np.unique(alone.segmentation).tolist()) - {-1})
        c = SiteWorld(columns, renderer=backend_name, rng=np.random.default_rng(1))
        a.close()
        np.testing.assert_array_equal(b.render(pose, SMALL).rgb, rb.rgb)
        np.testing.assert_array_equal(c.render(pose, SMALL).rgb, alone.rgb)  # same seed as a
        b.close()
        np.testing.assert_array_equal(c.render(pose, SMALL, segmentation=True).segmentation,
                                      alone.segmentation)
    finally:
        for w in (a, b, c):
            if w is not None:
                w.close()


def test_worlds_in_subprocesses(egl_ok):
    # The smallest textures: what runs in the fresh process (the backend "auto" picks, a lit image,
    # the silenced banner) does not depend on them, and drawing 512 px ones cost a second of CPU.
    code = (
        "import numpy as np\n"
        "from uav_struct_env.sim.world import SiteWorld\n"
        "from uav_struct_env.site import paper_site\n"
        "from localization.geometry import look_at\n"
        "for size in ((128, 72), (640, 360)):\n"
        "    with SiteWorld(paper_site(), image_size=size, texture_size=16) as w:\n"
        "        r = w.render(look_at([0, -25, 15], w.site.center))\n"
        "        print('RESULT', w.backend, r.rgb.shape, int(r.rgb.std() > 5))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         check=True)
    lines = [line for line in out.stdout.splitlines() if line.startswith("RESULT")]
    second = "egl" if egl_ok else "tiny"
    assert lines == ["RESULT tiny (72, 128, 3) 1", f"RESULT {second} (360, 640, 3) 1"], out.stdout
    assert "GL_VERSION" not in out.stdout  # the EGL plugin's banner is silenced


def test_same_seed_same_textures_and_no_files_outlive_the_load(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    site = paper_site("slab", marker_size=None)
    pose = _south_view(site)
    a = SiteWorld(site, renderer="tiny", rng=np.random.default_rng(3))
    b = SiteWorld(site, renderer="tiny", rng=np.random.default_rng(3))
    c = SiteWorld(site, renderer="tiny", rng=np.random.default_rng(4))
    try:
        ra, rb, rc = (w.render(pose, SMALL).rgb for w in (a, b, c))
        np.testing.assert_array_equal(ra, rb)
        # The same seed's meshes and textures are built once in a process and shared (read-only).
        assert all(x is y for x, y in zip(a.elements, b.elements, strict=True))
        assert not any(x is y for x, y in zip(a.elements, c.elements, strict=True))
        assert np.abs(ra.astype(int) - rc).mean() > 1.0
        # Meshes and textures were written under tmp_path and removed once loaded: an open world
        # (or a killed process holding one) leaves nothing behind, and still renders the same.
        assert list(tmp_path.iterdir()) == []
        np.testing.assert_array_equal(a.render(pose, SMALL).rgb, ra)
    finally:
        for w in (b, c):
            w.close()
    with a:
        pass
    assert a.closed
    a.close()  # idempotent
    with pytest.raises(ClosedError, match="this SiteWorld is closed"):
        a.render(pose, SMALL)


def test_add_and_move_body(paper_world):
    world = paper_world("columns", "tiny")
    pose = _south_view(world.site)
    where = np.eye(4)
    where[:3, 3] = [4.0, -6.0, 9.0]
    body = world.add_body(half_extents=(0.4, 0.4, 0.2), world_from_body=where)
    try:
        seg = world.render(pose, SMALL, segmentation=True).segmentation
        rows, cols = np.nonzero(seg == body)
        uv, _ = project(SMALL.K, pose, where[None, :3, 3])
        assert len(rows) > 5
        assert np.hypot(cols.mean() - uv[0, 0], rows.mean() - uv[0, 1]) < 1.5
        where[:3, 3] = [-60.0, -60.0, 1.0]
        world.move_body(body, where)
        assert not (world.render(pose, SMALL, segmentation=True).segmentation == body).any()
        with pytest.raises(ValueError, match="not added with add_body"):
            world.move_body(world.body_ids["slab S1"], where)
        with pytest.raises(ValueError, match="half_extents"):
            world.add_body(half_extents=(0.1, 0.0, 0.1))
    finally:
        world.remove_body(body)


def test_auto_resolution_and_bad_renderer():
    assert resolve_renderer("auto", (1280, 720)) == "egl"
    assert resolve_renderer("auto", (128, 72)) == "tiny"
    assert resolve_renderer("tiny", (1280, 720)) == "tiny"
    with pytest.raises(ConfigError, match="renderer must be one of"):
        resolve_renderer("opengl", (10, 10))
    with pytest.raises(ConfigError, match="image_size"):
        resolve_renderer("auto", (0, 10))
    with pytest.raises(ConfigError, match="renderer must be one of"):
        SiteWorld(paper_site(), renderer="opengl")
    with pytest.raises(TypeError, match="site must be"):
        SiteWorld("paper")


def test_egl_unavailable(monkeypatch):
    monkeypatch.setattr(client_module, "egl_plugin_path", lambda: None)
    with pytest.raises(RendererUnavailableError, match="no eglRenderer plugin"):
        SiteWorld(paper_site(), renderer="egl")
    with pytest.warns(RuntimeWarning, match="falling back to TinyRenderer"):
        world = SiteWorld(paper_site(), renderer="auto", image_size=(1280, 720))
    try:
        assert world.backend == "tiny"
    finally:
        world.close()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        SiteWorld(paper_site(), renderer="auto", image_size=(128, 72)).close()  # tiny anyway
