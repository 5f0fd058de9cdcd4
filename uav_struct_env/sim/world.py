"""SiteWorld: one pybullet client with one site loaded, rendered through calibrated cameras.

The site is built and loaded once, when the world is made (the environment keeps one world and
only moves its UAVs on reset). Each world owns its own DIRECT client, released by
:meth:`SiteWorld.close` (also on garbage collection, and at interpreter exit). The meshes and
textures are written to a temporary directory that lives only while pybullet loads them (pybullet
keeps what it read; renders are identical without the files), so no file outlives the load --
not even when a pool worker holding a world is terminated, which skips every exit handler.

**Depth precision.** The EGL plugin's depth buffer has 16 bits (measured: steps of exactly
2**-16). With the camera's near plane at 0.1 m one step is ``z**2 / (0.1 * 65536)``, 0.38 m at
50 m: the marker sheets (1 cm above the ground) would z-fight and occlusion tests would be coarse.
Each render therefore moves the near plane out to 80 % of the nearest depth any scene geometry
can have in that view (element bounding boxes, the ground plane through the image corners, added
bodies), never below ``camera.near``. Typically that is 10-20 m, making a step at 50 m 2-4 mm.
Only the depth mapping changes (pixel geometry is independent of the clip planes); the camera
actually used is returned as ``RenderResult.camera``.
"""

from __future__ import annotations

import functools
import math
import time
import warnings
import weakref
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.geometry.transforms import check_transform, quat_wxyz_from_matrix
from uav_struct_env.errors import ClosedError, RendererUnavailableError
from uav_struct_env.sim.camera import Camera, depth_from_buffer, view_matrix
from uav_struct_env.sim.client import RenderClient, p, resolve_renderer  # p: pybullet, imported quietly
from uav_struct_env.sim.raycast import RayScene, raycast_visibility
from uav_struct_env.sim.scene import LoadedScene, load_elements
from uav_struct_env.sim.visibility import landmark_visibility
from uav_struct_env.site.activity import BOX_CORNER_SIGNS
from uav_struct_env.site.mesh import shared_site_elements
from uav_struct_env.site.model import Site

__all__ = ["DEFAULT_LIGHT", "SKY_RGB", "RenderResult", "SiteWorld", "random_light"]

#: Colour given to pixels that show no geometry (both backends clear to different colours).
SKY_RGB = (186, 204, 224)
#: Depth-buffer value from which a pixel counts as background (TinyRenderer clears to 1 - 1e-7).
_BACKGROUND_DEPTH = 1.0 - 1e-6
#: Sun from the south-east, high; TinyRenderer's lighting coefficients (EGL uses the direction).
DEFAULT_LIGHT = {
    "lightDirection": (0.45, -0.35, 1.0),
    "lightAmbientCoeff": 0.55,
    "lightDiffuseCoeff": 0.45,
    "lightSpecularCoeff": 0.0,
}


def random_light(rng: np.random.Generator) -> dict:
    """A random sun: elevation 25-85 deg, any azimuth, TinyRenderer coefficients drawn too.

    Ambient 0.35-0.7, diffuse 0.3-0.6; EGL uses only the direction (pybullet's EGL renderer
    ignores the coefficients).

    Shadows are not drawn: pybullet's ``shadow=1`` changes nothing with EGL here, and with
    TinyRenderer it needs ``lightDistance``, darkens the image by 5/255 on average without a
    visible cast shadow, and costs 40-70 % more render time (measured on the paper's site).
    """
    az, el = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(25, 85))
    return {
        "lightDirection": (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)),
        "lightAmbientCoeff": float(rng.uniform(0.35, 0.7)),
        "lightDiffuseCoeff": float(rng.uniform(0.3, 0.6)),
        "lightSpecularCoeff": 0.0,
    }


@functools.lru_cache(maxsize=16)
def _image_corner_rays(camera: Camera) -> NDArray[np.float64]:
    """(3, 4) rays ``K^-1 (u, v, 1)`` through the outer corners of the image's corner pixels.

    Cached per camera (a frozen dataclass): the near plane needs them on every render.
    """
    W, H = camera.width, camera.height
    image_corners = [[-0.5, W - 0.5, W - 0.5, -0.5], [-0.5, -0.5, H - 0.5, H - 0.5], [1] * 4]
    rays = np.linalg.inv(camera.K) @ np.array(image_corners)
    rays.flags.writeable = False
    return rays


@dataclass(frozen=True, eq=False)
class RenderResult:
    """One rendered view.

    Attributes:
        rgb: (H, W, 3) uint8.
        depth: (H, W) float32 metric depth along the optical axis (m; ``camera.far`` where
            nothing was hit), or None if not requested.
        segmentation: (H, W) int32 pybullet body ids (-1 for sky), or None if not requested.
        camera: the camera with the near plane used for this render (see the module docstring).
        depth_bits: bits of the depth buffer the metric depth was decoded from.
    """

    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32] | None = None
    segmentation: NDArray[np.int32] | None = None
    #: The camera as rendered: the requested intrinsics with the near plane actually used.
    camera: Camera | None = None
    #: Depth-buffer resolution of the backend (16 for EGL, 24 for TinyRenderer's float buffer).
    depth_bits: int = 24


class SiteWorld:
    """A pybullet client with ``site`` loaded, rendering RGB, depth and segmentation.

    Args:
        site: the site to load.
        renderer: ``"auto"``, ``"tiny"`` or ``"egl"``. ``"auto"`` picks the faster backend for
            ``image_size`` and falls back to ``"tiny"`` with a warning when EGL cannot start.
        image_size: ``(width, height)`` of the images this world will mostly render; sets the
            default :attr:`camera` (the paper's camera scaled to this size) and the "auto" choice.
        rng: generator for the textures (default: ``np.random.default_rng(0)``).
        texture_size: texture side cap in pixels (columns; the slab and inner ground get twice it).

    Raises:
        ConfigError: for an unknown renderer or a bad image size.
        RendererUnavailableError: if ``renderer="egl"`` and EGL cannot start.
    """

    def __init__(
        self,
        site: Site,
        *,
        renderer: str = "auto",
        image_size: tuple[int, int] = (1280, 720),
        rng: np.random.Generator | None = None,
        texture_size: int = 512,
    ) -> None:
        if not isinstance(site, Site):
            raise TypeError(f"site must be a uav_struct_env.site.Site, got {type(site).__name__}")
        if rng is not None and not isinstance(rng, np.random.Generator):
            raise TypeError(
                f"rng must be a numpy.random.Generator or None, got {type(rng).__name__}"
            )
        start = time.perf_counter()
        backend = resolve_renderer(renderer, image_size)
        try:
            client = RenderClient(backend)
        except RendererUnavailableError as exc:
            if renderer != "auto":
                raise
            warnings.warn(
                f"EGL rendering is unavailable ({exc}); falling back to TinyRenderer, which is "
                "2-5x slower at 1280x720. Pass renderer='tiny' to silence this warning.",
                RuntimeWarning,
                stacklevel=2,
            )
            client = RenderClient("tiny")
        self._client = client
        self._finalizer = weakref.finalize(self, client.close)
        self.site = site
        self.camera = Camera().scaled(*(int(x) for x in image_size))
        self.light = dict(DEFAULT_LIGHT)
        try:
            elements = shared_site_elements(
                site, np.random.default_rng(0) if rng is None else rng, texture_size=texture_size
            )
            client.activate()
            self.scene: LoadedScene = load_elements(client.client_id, elements)
        except BaseException:
            self.close()
            raise
        #: The loaded elements (meshes and textures), for renderers other than pybullet's.
        self.elements: tuple = tuple(elements)
        #: Bodies added with add_body: body id -> the box's half extents (m), and -> its pose.
        self._extra_bodies: dict[int, NDArray[np.float64]] = {}
        self._extra_rgba: dict[int, tuple[float, ...]] = {}
        #: Their poses as rows of one array (ray casting and the near plane read them all at once).
        self._body_row: dict[int, int] = {}
        self._body_poses = np.zeros((0, 4, 4))
        #: The rendered triangles, for landmark visibility without rendering (:mod:`.raycast`).
        self._rays = RayScene([(e.mesh.vertices, e.mesh.faces) for e in elements])
        self._depth_meta: dict[int, tuple[weakref.ref, float, float, int]] = {}
        # Bounding-box corners of the solid elements, for the per-view near plane.
        self._box_corners = np.stack([
            np.array(np.meshgrid(*e.mesh.bounds.T, indexing="ij")).reshape(3, -1).T
            for e in elements if e.kind != "ground"
        ])
        #: Seconds spent building textures/meshes and loading them (excludes the first render).
        self.load_time_s = time.perf_counter() - start

    # ------------------------------------------------------------------------------ properties
    @property
    def backend(self) -> str:
        """The backend in use: ``"tiny"`` or ``"egl"`` (what "auto" resolved to)."""
        return self._client.backend

    @property
    def client_id(self) -> int:
        """This world's pybullet client id (pass it as ``physicsClientId``).

        Call :meth:`activate` before calling pybullet yourself with it (see there).
        """
        return self._client.client_id

    def activate(self) -> None:
        """Make this world's EGL context current before direct pybullet calls on its client.

        The EGL plugin never re-binds its own context, so with several EGL worlds in a process,
        a pybullet call that creates, changes or removes visual shapes must run with the right
        context current. :class:`SiteWorld`'s own methods do this; a no-op for TinyRenderer.
        """
        self._check_open()
        self._client.activate()

    @property
    def body_ids(self) -> dict[str, int]:
        """Pybullet body id of every site element, by element name (``"column C1-03"``, ...)."""
        return dict(self.scene.body_ids)

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run."""
        return not self._finalizer.alive

    def _check_open(self) -> None:
        if self.closed:
            raise ClosedError("this SiteWorld is closed (close() released its pybullet client)")

    # ------------------------------------------------------------------------------ rendering
    def render(
        self,
        cam_from_world: ArrayLike,
        camera: Camera | None = None,
        *,
        depth: bool = False,
        segmentation: bool = False,
    ) -> RenderResult:
        """Render the view of ``camera`` at pose ``cam_from_world``.

        Args:
            cam_from_world: (4, 4) OpenCV camera pose.
            camera: intrinsics and image size (default :attr:`camera`).
            depth: also return metric depth.
            segmentation: also return the body-id mask (an extra render pass with EGL).

        Returns:
            :class:`RenderResult`; pixels that show no geometry are sky-coloured.
        """
        self._check_open()
        camera = self.camera if camera is None else camera
        if not isinstance(camera, Camera):
            raise TypeError(
                f"camera must be a uav_struct_env.sim.camera.Camera, got {type(camera).__name__}"
            )
        T = check_transform("cam_from_world", cam_from_world)
        used = camera._replaced(near=self._near_plane(T, camera))  # checked: >= near, < far
        raw = self._client.render(view_matrix(T), used, segmentation=segmentation, light=self.light)
        rgb = raw.rgb
        background = raw.depth_buffer >= _BACKGROUND_DEPTH
        rgb[background] = SKY_RGB
        metric = None
        if depth:
            metric = depth_from_buffer(raw.depth_buffer, used)
            metric[background] = used.far
        bits = 16 if self.backend == "egl" else 24
        if metric is not None:
            self._remember_depth(metric, used, bits)
        return RenderResult(rgb, metric, raw.segmentation, used, bits)

    def _remember_depth(self, depth: NDArray[np.float32], camera: Camera, bits: int) -> None:
        """Note how a returned depth image was made.

        Passing the bare array to :meth:`landmark_truth` then still gets the tight tolerance
        (weak references, the last 32 renders only).
        """
        self._depth_meta[id(depth)] = (weakref.ref(depth), camera.near, camera.far, bits)
        while len(self._depth_meta) > 32:
            self._depth_meta.pop(next(iter(self._depth_meta)))

    def _near_plane(self, cam_from_world: NDArray[np.float64], camera: Camera) -> float:
        """80 % of the smallest depth that scene geometry can have in this view (>= camera.near)."""
        R, t = cam_from_world[:3, :3], cam_from_world[:3, 3]
        corners = self._box_corners
        if self._extra_bodies:
            _, poses, halves = self._added_boxes()
            local = BOX_CORNER_SIGNS[None] * halves[:, None, :]  # (B, 8, 3)
            extra = np.einsum("bij,bkj->bki", poses[:, :3, :3], local) + poses[:, None, :3, 3]
            # Added bodies wholly outside the view (site activity beside or under the camera)
            # must not pull the near plane in: cull them against the image's side planes.
            cam = extra @ R.T + t  # (B, 8, 3) camera frame
            K = camera.K
            lo_x, hi_x = (-0.5 - K[0, 2]) / K[0, 0], (camera.width - 0.5 - K[0, 2]) / K[0, 0]
            lo_y, hi_y = (-0.5 - K[1, 2]) / K[1, 1], (camera.height - 0.5 - K[1, 2]) / K[1, 1]
            x, y, zc = cam[..., 0], cam[..., 1], cam[..., 2]
            # all eight corners beyond one side plane (the four tests stacked: one reduction)
            sides = np.stack([x < lo_x * zc, x > hi_x * zc, y < lo_y * zc, y > hi_y * zc])
            outside = sides.all(axis=2).any(axis=0)
            corners = np.concatenate([corners, extra[~outside]])
        z = corners @ R[2] + t[2]  # (boxes, 8) depth of every box corner
        nearest_corner = z[z.max(axis=1) > 0].min(axis=1)  # of each box in front of the camera
        if (nearest_corner <= camera.near).any():
            return camera.near  # a box straddles the camera plane or is very close
        nearest = float(nearest_corner.min()) if nearest_corner.size else np.inf
        # Ground plane z = 0: 1/depth is affine over the image, so its extremes are at the corners.
        centre_z = float(-(R.T @ t)[2])
        if centre_z <= 0:
            return camera.near
        descent = -(R.T @ _image_corner_rays(camera))[2]  # metres down per metre of depth
        if descent.max() > 0:
            nearest = min(nearest, centre_z / float(descent.max()))
        if not np.isfinite(nearest):
            return camera.near
        return float(min(max(camera.near, 0.8 * nearest), 0.5 * camera.far))

    def landmark_truth(
        self,
        name: str,
        cam_from_world: ArrayLike,
        camera: Camera | None,
        depth: RenderResult | ArrayLike,
    ) -> dict[str, NDArray]:
        """Ground truth for landmark set ``name`` in a rendered view.

        Args:
            name: a landmark set of the site (``"column_tops"``, ``"aruco"``, ...).
            cam_from_world: (4, 4) pose the depth was rendered from.
            camera: the camera it was rendered with (None: :attr:`camera`).
            depth: the :class:`RenderResult` of ``render(..., depth=True)`` or its ``.depth``
                (H, W) metric depth. Either way the occlusion tolerance uses the near plane and
                depth-buffer resolution that render used (for a depth array this world did not
                return, it assumes ``camera.near`` and this backend's buffer: looser).

        Returns:
            ``ids``, ``xyz``, ``uv``, ``in_frame``, ``visible``: see
            :func:`uav_struct_env.sim.visibility.landmark_visibility`.
        """
        camera = self.camera if camera is None else camera
        bits = 16 if self.backend == "egl" else 24
        if isinstance(depth, RenderResult):
            if depth.depth is None:
                raise ValueError("landmark_truth needs a render made with depth=True")
            bits = depth.depth_bits
            if depth.camera is not None:
                camera = camera._replaced(near=depth.camera.near, far=depth.camera.far)
            depth = depth.depth
        else:
            meta = self._depth_meta.get(id(depth))
            if meta is not None and meta[0]() is depth:
                camera = camera._replaced(near=meta[1], far=meta[2])
                bits = meta[3]
        return landmark_visibility(
            self.site.landmarks(name), cam_from_world, camera, depth, depth_bits=bits
        )

    def landmark_truth_raycast(
        self, name: str, cam_from_world: ArrayLike, camera: Camera | None = None, *,
        skip_body: int | None = None,
    ) -> dict[str, NDArray]:
        """:meth:`landmark_truth` without a render: the same depth test on ray-cast depths.

        Casts rays through the pixel centres around each landmark's projection against the
        triangles this world renders and the bodies added with :meth:`add_body` (at their
        current poses); see :mod:`uav_struct_env.sim.raycast` for how closely it agrees.
        ``skip_body``: an added body the rays pass through unseen (the camera's own airframe).

        Raises:
            ValueError: if ``skip_body`` was not added with :meth:`add_body`.
        """
        self._check_open()
        camera = self.camera if camera is None else camera
        self._sync_ray_boxes()
        skip = -1
        if skip_body is not None:
            if skip_body not in self._body_row:
                raise ValueError(f"skip_body {skip_body!r} was not added with add_body")
            skip = self._body_row[skip_body]  # row order = the ray scene's box order
        points = self.site.landmarks(name)
        return raycast_visibility(self._rays, points.xyz, points.ids, cam_from_world, camera,
                                  skip_box=skip)

    def first_hits(
        self,
        origin: ArrayLike,
        directions: ArrayLike,
        t_min: float = 0.0,
        skip_bodies: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """First surface hit ``t`` of rays ``origin + t * directions[i]`` (inf: none), no render.

        Against the triangles this world renders and the bodies added with :meth:`add_body` at
        their current poses (:class:`~uav_struct_env.sim.raycast.RayScene`). ``skip_bodies``
        (R,): per ray, the id of an added body that ray passes through unseen (-1: none).
        """
        self._check_open()
        ids = self._sync_ray_boxes()
        skip = None
        if skip_bodies is not None:
            index = {body: k for k, body in enumerate(ids)}
            skip = np.array([index.get(int(b), -1) for b in np.asarray(skip_bodies).reshape(-1)])
        return self._rays.first_hit(origin, directions, t_min, skip)

    def _added_boxes(self) -> tuple[list[int], NDArray[np.float64], NDArray[np.float64]]:
        """``(body ids, world_from_body (B, 4, 4), half extents (B, 3))`` of the added bodies."""
        ids = list(self._extra_bodies)  # insertion order = row order
        poses = self._body_poses
        halves = np.array(list(self._extra_bodies.values())).reshape(-1, 3)
        return ids, poses, halves

    def added_bodies(self) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64],
                                    NDArray[np.float64]]:
        """The bodies added with :meth:`add_body`, at their current poses.

        Returns:
            ``(body ids (B,), world_from_body (B, 4, 4), half extents (B, 3) m, rgba (B, 4))``,
            in the order they were added (the pose array is this world's own: do not write to it).
        """
        ids, poses, halves = self._added_boxes()
        rgba = np.array([self._extra_rgba[b] for b in ids], dtype=np.float64).reshape(-1, 4)
        return np.array(ids, dtype=np.int64), poses, halves, rgba

    def _sync_ray_boxes(self) -> list[int]:
        """Give the ray scene the added bodies at their current poses; their ids in box order."""
        ids, poses, halves = self._added_boxes()
        self._rays.set_boxes(poses, halves)
        return ids

    # ------------------------------------------------------------------------------ extra bodies
    def add_body(
        self,
        half_extents: tuple[float, float, float] = (0.2, 0.2, 0.06),
        rgba: tuple[float, float, float, float] = (0.15, 0.15, 0.17, 1.0),
        world_from_body: ArrayLike | None = None,
    ) -> int:
        """Add a visual-only box (e.g. a UAV body) and return its body id."""
        self._check_open()
        if len(half_extents) != 3 or min(half_extents) <= 0:
            raise ValueError(f"half_extents must be three positive lengths, got {half_extents!r}")
        self._client.activate()
        shape = p.createVisualShape(
            p.GEOM_BOX, halfExtents=list(map(float, half_extents)), rgbaColor=list(rgba),
            physicsClientId=self.client_id,
        )
        body = p.createMultiBody(
            baseMass=0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=shape,
            physicsClientId=self.client_id,
        )
        self._extra_bodies[body] = np.asarray(half_extents, dtype=np.float64)
        self._extra_rgba[body] = tuple(float(c) for c in rgba)
        self._body_row[body] = len(self._body_poses)
        self._body_poses = np.concatenate([self._body_poses, np.eye(4)[None]])
        if world_from_body is not None:
            self.move_body(body, world_from_body)
        return body

    def move_body(self, body_id: int, world_from_body: ArrayLike) -> None:
        """Place a body added with :meth:`add_body` at the 4x4 pose ``world_from_body``."""
        self._check_open()
        if body_id not in self._extra_bodies:
            raise ValueError(
                f"body {body_id!r} was not added with add_body (site bodies are static)"
            )
        T = check_transform("world_from_body", world_from_body)
        w, x, y, z = quat_wxyz_from_matrix(T)
        self._client.activate()
        p.resetBasePositionAndOrientation(
            body_id, T[:3, 3].tolist(), [x, y, z, w], physicsClientId=self.client_id
        )
        self._body_poses[self._body_row[body_id]] = T

    def place_body(self, body_id: int, position: tuple[float, float, float], yaw: float) -> None:
        """:meth:`move_body` for an upright pose turned ``yaw`` (rad) about z, without validation.

        The fast path for bodies moved every step (airframes, workers): no validation of a general
        4x4 pose.
        ``body_id`` must come from :meth:`add_body` (unchecked).
        """
        c, s = math.cos(yaw), math.sin(yaw)
        h = 0.5 * yaw
        p.resetBasePositionAndOrientation(
            body_id, position, (0.0, 0.0, math.sin(h), math.cos(h)), physicsClientId=self.client_id
        )
        pose = self._body_poses[self._body_row[body_id]]
        pose[:3, :3] = ((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0))
        pose[:3, 3] = position

    def remove_body(self, body_id: int) -> None:
        """Remove a body added with :meth:`add_body`."""
        self._check_open()
        if body_id not in self._extra_bodies:
            raise ValueError(f"body {body_id!r} was not added with add_body")
        self._client.activate()
        p.removeBody(body_id, physicsClientId=self.client_id)
        del self._extra_bodies[body_id]
        del self._extra_rgba[body_id]
        self._body_poses = np.delete(self._body_poses, self._body_row.pop(body_id), axis=0)
        self._body_row = {b: k for k, b in enumerate(self._extra_bodies)}

    # ------------------------------------------------------------------------------ lifetime
    def close(self) -> None:
        """Disconnect the client (idempotent)."""
        self._finalizer()

    def __enter__(self) -> SiteWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self.closed else f"client {self.client_id}"
        return (f"SiteWorld(site={self.site.name!r}, stage={self.site.stage!r}, "
                f"backend={self.backend!r}, {state})")
