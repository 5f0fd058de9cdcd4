"""A batched CPU renderer for training-resolution frames: many cameras, many worlds, one call.

pybullet's ``getCameraImage`` costs a fixed ~0.6 ms per call before any pixel is drawn, which
is most of a 64 x 36 or 128 x 72 frame. This renderer draws the same scene -- the site's
textured elements, the ground and markers, and the boxes added to the world (airframes, the
site activity's workers, equipment and materials) -- with a compiled z-buffer rasterizer
(:mod:`.raster`) for every view of a batch in one call, and returns the same
:class:`~uav_struct_env.sim.world.RenderResult` as ``SiteWorld.render``: RGB, metric depth along
the optical axis and pybullet body ids (-1 for sky), with the same camera model (``K``, skew,
pixel centres at integer ``(u, v)``) and lighting model. pybullet stays the physics, the
collision geometry and the full-resolution renderer; a real camera's distortion is applied to
these frames by the same remapping (``sim.lens.LensView.warp``).

Frames are limited to :data:`MAX_BATCH_PIXELS` (a 160 x 120 image with a real camera's render
margin): the renderer scans every triangle for every view, which beats pybullet at training
resolutions, not at full resolution.

Usage (one env's agents, or the agents of several envs: a vector env passes all its views)::

    from uav_struct_env.sim.batch import BatchScene, BatchView, render_batch

    scene = BatchScene(world)                  # once per SiteWorld, after its site is loaded
    views = [BatchView(scene, cam_from_world, camera, hidden_body=own_airframe_id), ...]
    results = render_batch(views)              # list of RenderResult, in the order of views

``BatchView(scene, cam_from_world (4, 4), camera, hidden_body=-1)``: the scene, the OpenCV pose,
the :class:`~uav_struct_env.sim.camera.Camera` (views of different sizes may be mixed: each size
is one compiled call) and a body id this camera does not see (its own airframe). Added bodies are
drawn at their poses in the world when :func:`render_batch` is called; the lighting is each
world's ``light``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from uav_struct_env.errors import ClosedError, ConfigError
from uav_struct_env.sim.batch.raster import render_views
from uav_struct_env.sim.batch.scene import BatchScene, PackedScenes
from uav_struct_env.sim.camera import Camera

__all__ = ["MAX_BATCH_PIXELS", "MAX_BATCH_SIZE", "BatchScene", "BatchView", "render_batch"]

#: The largest observed image the env renders with ``renderer="batch"`` (width, height).
MAX_BATCH_SIZE = (160, 120)
#: The largest render (pixels) :func:`render_batch` accepts: :data:`MAX_BATCH_SIZE` with the
#: margin a real camera's wide render adds (``sim.lens``), rounded up.
MAX_BATCH_PIXELS = 2 * MAX_BATCH_SIZE[0] * MAX_BATCH_SIZE[1]
#: Depth-buffer resolution reported with the renders: the depth is float, not a quantized buffer.
DEPTH_BITS = 32


class BatchView(NamedTuple):
    """One camera of a batch: scene, OpenCV ``cam_from_world`` (4, 4), camera, hidden body id."""

    scene: BatchScene
    cam_from_world: NDArray[np.float64]
    camera: Camera
    hidden_body: int = -1


_PACKED: list[PackedScenes] = []  # the last packing (the same scenes are rendered every step)


def _packed(scenes: list[BatchScene]) -> PackedScenes:
    key = tuple(s.uid for s in scenes)
    if not _PACKED or _PACKED[0].key != key:
        _PACKED[:] = [PackedScenes(scenes)]
    return _PACKED[0]


def _check_view(k: int, view: BatchView) -> None:
    if not isinstance(view, BatchView):
        raise TypeError(f"views[{k}] must be a BatchView, got {type(view).__name__}")
    if not isinstance(view.scene, BatchScene):
        raise TypeError(f"views[{k}].scene must be a BatchScene, got {type(view.scene).__name__}")
    if not isinstance(view.camera, Camera):
        raise TypeError(f"views[{k}].camera must be a Camera, got {type(view.camera).__name__}")
    w, h = view.camera.size
    if w * h > MAX_BATCH_PIXELS:
        raise ConfigError(
            f"views[{k}] is {w} x {h} = {w * h} pixels; the batch renderer draws at most "
            f"{MAX_BATCH_PIXELS} (training resolution, up to {MAX_BATCH_SIZE[0]} x {MAX_BATCH_SIZE[1]} "
            "delivered); render larger frames with pybullet (renderer='tiny' or 'egl')"
        )
    T = np.asarray(view.cam_from_world)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise ValueError(f"views[{k}].cam_from_world must be a finite (4, 4) transform, got shape {T.shape}")


def _light(world) -> NDArray[np.float64]:
    """(direction towards the sun (3,), ambient, diffuse) of a world's ``light``."""
    d = np.asarray(world.light["lightDirection"], dtype=np.float64)
    d = d / np.linalg.norm(d)
    return np.array([*d, world.light["lightAmbientCoeff"], world.light["lightDiffuseCoeff"]])


def _boxes(scenes: list[BatchScene]) -> tuple[NDArray, ...]:
    """The added boxes of every scene, concatenated, and each scene's range of them.

    Returns rotations, centres, half extents, colours, body ids and the (S, 2) ranges.
    """
    boxes = [s.boxes() for s in scenes]
    counts = np.array([len(b[4]) for b in boxes], dtype=np.int64)
    ends = np.cumsum(counts)
    # one scene: its arrays as they are (np.concatenate of one array copies it)
    join = (lambda arrays: arrays[0]) if len(boxes) == 1 else np.concatenate
    arrays = (np.ascontiguousarray(join([b[i] for b in boxes]), dtype=dt)
              for i, dt in enumerate((np.float64, np.float64, np.float64, np.float64, np.int64)))
    return (*arrays, np.stack([ends - counts, ends], axis=1))


def render_batch(views: Sequence[BatchView]):
    """Render every view; see the module docstring.

    Returns:
        One :class:`~uav_struct_env.sim.world.RenderResult` per view (``rgb``, ``depth``,
        ``segmentation``, ``camera``, ``depth_bits``), in order.

    Raises:
        TypeError, ValueError: for a malformed view.
        ConfigError: for a view larger than :data:`MAX_BATCH_PIXELS`.
        ClosedError: if a view's world is closed.
    """
    from uav_struct_env.sim.world import SKY_RGB, RenderResult

    views = list(views)
    for k, view in enumerate(views):
        _check_view(k, view)
    scenes: list[BatchScene] = []
    index: dict[int, int] = {}
    for k, view in enumerate(views):
        if view.scene.uid not in index:
            if view.scene.world.closed:
                raise ClosedError(
                    f"the SiteWorld of views[{k}].scene is closed; make a BatchScene of an open one"
                )
            index[view.scene.uid] = len(scenes)
            scenes.append(view.scene)
    if not views:
        return []
    packed = _packed(scenes)
    box_R, box_c, box_h, box_rgb, box_seg, scene_boxes = _boxes(scenes)
    lights = {s.uid: _light(s.world) for s in scenes}
    sky = np.array(SKY_RGB, dtype=np.uint8)
    results: list = [None] * len(views)
    for size in sorted({v.camera.size for v in views}):
        group = [k for k, v in enumerate(views) if v.camera.size == size]
        T = np.array([views[k].cam_from_world for k in group], dtype=np.float64)
        cams = [views[k].camera for k in group]
        params = np.array([[c.fx, c.skew, c.cx, c.fy, c.cy, c.near, c.far] for c in cams])
        W, H = size
        rgb = np.empty((len(group), H, W, 3), np.uint8)
        depth = np.empty((len(group), H, W), np.float32)
        seg = np.empty((len(group), H, W), np.int32)
        render_views(
            np.array([index[views[k].scene.uid] for k in group], dtype=np.int64),
            np.ascontiguousarray(T[:, :3, :3]), np.ascontiguousarray(T[:, :3, 3]),
            np.ascontiguousarray(params[:, :5]), np.ascontiguousarray(params[:, 5:]),
            np.array([lights[views[k].scene.uid] for k in group]),
            np.array([views[k].hidden_body for k in group], dtype=np.int64), sky,
            packed.scene_tris, scene_boxes, *packed.arrays(),
            box_R, box_c, box_h, box_rgb, box_seg, rgb, depth, seg,
        )
        for j, k in enumerate(group):
            results[k] = RenderResult(rgb[j], depth[j], seg[j], cams[j], DEPTH_BITS)
    return results
