"""A camera beyond the pinhole: lens distortion, rolling shutter and motion blur.

A :class:`CameraModel` is intrinsics (at the camera's own resolution, scaled to the env's image
size like :meth:`Camera.scaled`), OpenCV's distortion coefficients ``(k1, k2, p1, p2, k3)``
(:mod:`localization.geometry.distortion`), the rolling shutter's readout time and the exposure time.
:class:`LensView` renders through one at a fixed image size and gives the ground truth of where
each landmark appears in the delivered image.

**Time convention** (docs/design.md, Conventions). The step's pose (``info["world_from_cam"]``)
is the pose at ``t = 0``. Rows are read top to bottom; row ``v`` (continuous, pixel centres at
integers) is exposed during ``[t(v) - e/2, t(v) + e/2]`` with
``t(v) = readout_time * ((v + 0.5) / H - 0.5)``: the middle of the frame is exposed at the step's
pose, the first row half a readout earlier, the last half a readout later. During the frame the
camera moves with constant world velocity ``v`` and angular velocity ``w`` (:class:`Motion`):
``C(t) = C + v t``, ``world_R_cam(t) = exp([w t]x) world_R_cam``. The UAV's kinematic model holds
its commanded velocities over the control period, so the step's velocities are exact for the rows
read before ``t = 0`` and extrapolated for the rows after.

**Rendering.** One pinhole render per view, wider than the delivered image (its field covers every
delivered pixel's undistorted ray plus a margin for the motion), then one ``cv2.remap``: each
delivered pixel ``(u, v)`` looks along its undistorted ray from the pose at ``t(v)``; the ray is
moved into the render's frame and meets the rendered surface at the render's depth there (two
fixed-point steps on the depth buffer, so parallax is depth-correct on smooth surfaces). The
static part of the map (distortion) is computed once; the motion part is evaluated on a grid of
``grid_px`` pixels and interpolated, so at depth edges it blends the two surfaces' parallax over
that many pixels. The render keeps at most ``max_render_ratio`` times the delivered pixel count:
if the widened field needs more, the render's focal length is scaled down (``render_scale`` < 1:
the centre is resampled from coarser pixels; 0.81 for ``mavic2pro`` at 1280 x 720, where the full
density would need 1.67x the pixels and twice the render time). Motion blur is a line kernel along the
median image motion during the exposure (symmetric, so it moves no feature's centre).

**Ground truth.** :meth:`LensView.project` solves ``v = v(X seen from the pose at t(v))`` by
fixed-point iteration (the shift per row is far below a row) and distorts exactly, so
``uv`` is where the landmark appears in the delivered image; occlusion is the depth test of
:mod:`uav_struct_env.sim.visibility` on the wide render at the step's pose.

Presets (:data:`CAMERA_MODELS`): ``"paper"`` is the paper's ideal pinhole (the env renders exactly
as without this module); ``"mavic2pro"`` is the DJI Mavic 2 Pro's Hasselblad L1D-20c, see
:data:`MAVIC2PRO` for every number and its source.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from localization.geometry.distortion import (
    check_distortion,
    distort_normalized,
    is_pinhole,
    undistort_normalized,
)
from localization.geometry.transforms import check_transform, so3_log
from uav_struct_env.errors import ConfigError
from uav_struct_env.named import resolve_named
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.uav import UavState, wrap_angle

__all__ = [
    "CAMERA_MODELS",
    "MAVIC2PRO",
    "CameraModel",
    "LensView",
    "Motion",
    "make_camera_model",
]


@dataclass(frozen=True, eq=False)
class Motion:
    """The camera's world velocity (m/s, (3,)) and world angular velocity (rad/s, (3,))."""

    velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    angular_velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        for name in ("velocity", "angular_velocity"):
            arr = np.asarray(getattr(self, name), dtype=np.float64).reshape(-1)
            if arr.shape != (3,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"Motion.{name} must be 3 finite numbers, got {getattr(self, name)!r}")
            object.__setattr__(self, name, arr)

    @property
    def is_static(self) -> bool:
        """True when the camera does not move."""
        return not (np.any(self.velocity) or np.any(self.angular_velocity))

    @classmethod
    def between(cls, before: UavState, after: UavState, dt: float) -> Motion:
        """The constant velocities that moved ``before`` to ``after`` in ``dt`` s (the step's).

        Yaw and gimbal pitch rates are turned into the world angular velocity of the camera at
        ``after`` (``exp([w h]x) R(after) = R(after with both angles advanced by rate * h)``).
        """
        if dt <= 0:
            return cls()
        velocity = (after.xyz - before.xyz) / dt
        yaw_rate = float(wrap_angle(after.yaw - before.yaw)) / dt
        pitch_rate = (after.pitch - before.pitch) / dt
        h = 1e-4
        ahead = UavState(after.position, after.yaw + yaw_rate * h, after.pitch + pitch_rate * h)
        R0, R1 = after.world_from_cam[:3, :3], ahead.world_from_cam[:3, :3]
        return cls(velocity, so3_log(R1 @ R0.T) / h)


def _rotate(rotvec: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``exp([rotvec]x) @ v`` row by row (Rodrigues), (N, 3) and (N, 3) -> (N, 3)."""
    theta = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    safe = np.where(theta > 0, theta, 1.0)
    k = rotvec / safe
    cos, sin = np.cos(theta), np.sin(theta)
    kxv = np.cross(k, v)
    return v * cos + kxv * sin + k * np.sum(k * v, axis=-1, keepdims=True) * (1.0 - cos)


@dataclass(frozen=True)
class CameraModel:
    """A real camera: intrinsics, lens distortion, rolling shutter and exposure.

    Attributes:
        name: preset name, for reports.
        intrinsics: the pinhole part at the camera's own resolution; the env uses
            ``intrinsics.scaled(W, H)`` (same field of view at its image size).
        distortion: OpenCV's ``(k1, k2, p1, p2, k3)`` on the normalized image plane (so they hold
            at any resolution).
        readout_time: seconds from the first row's exposure to the last row's (0: global shutter).
        exposure_time: seconds each row integrates (0: no motion blur).
        max_render_ratio: the wide render has at most this many times the delivered pixels.
        grid_px: spacing of the grid the rolling-shutter warp is evaluated on, px.
    """

    name: str = "paper"
    intrinsics: Camera = Camera()
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    readout_time: float = 0.0
    exposure_time: float = 0.0
    max_render_ratio: float = 1.0
    grid_px: int = 4

    def __post_init__(self) -> None:
        if not isinstance(self.intrinsics, Camera):
            raise ConfigError(f"CameraModel.intrinsics must be a Camera, got {self.intrinsics!r}")
        try:
            d = check_distortion("CameraModel.distortion", self.distortion)
        except (TypeError, ValueError) as exc:
            raise ConfigError(str(exc)) from None
        object.__setattr__(self, "distortion", tuple(float(x) for x in d))
        for name, hi in (("readout_time", 1.0), ("exposure_time", 1.0)):
            check_number(f"CameraModel.{name} (s)", getattr(self, name), 0, hi,
                         error=ConfigError, type_error=ConfigError)
        check_number("CameraModel.max_render_ratio", self.max_render_ratio, 1, 4,
                     error=ConfigError, type_error=ConfigError)
        check_number("CameraModel.grid_px", self.grid_px, 1, 64, integer=True,
                     error=ConfigError, type_error=ConfigError)

    @property
    def is_ideal(self) -> bool:
        """True for a pinhole with a global, instantaneous shutter (renders as the paper's camera)."""
        return is_pinhole(self.distortion) and self.readout_time == 0 and self.exposure_time == 0

    def camera(self, width: int, height: int) -> Camera:
        """The pinhole intrinsics of this camera's images at ``width`` x ``height``."""
        return self.intrinsics.scaled(width, height)


#: The DJI Mavic 2 Pro's camera, the Hasselblad L1D-20c, in 16:9 (video and the env's frames).
#:
#: * Intrinsics: 1-inch sensor 13.2 x 8.8 mm, 5472 x 3648 px (DJI's Mavic 2 Pro specifications),
#:   so 2.412 um pixels; focal length 10.26 mm (the EXIF ``FocalLength`` of its stills; "28 mm
#:   equivalent" in DJI's specifications): fx = fy = 10.26 / 0.002412 = 4253.5 px. A 16:9 frame
#:   uses the full width and 3078 rows (5472 x 3078); principal point at the centre. At
#:   1280 x 720 this is fx = 995 px, a 65.5 deg horizontal field (the paper's camera: 60 deg).
#: * Distortion: DJI publishes no calibration of the L1D-20c. The coefficients are DJI's published
#:   factory calibration of its closest camera with one, the Phantom 4 RTK's (same 1-inch 20 MP
#:   sensor class; ``DewarpData`` in every image's XMP, order fx, fy, cx, cy, k1, k2, p1, p2, k3
#:   per DJI's manuals): k1 = -0.269478, k2 = 0.115681, p1 = -8.75619e-5, p2 = -3.06177e-4,
#:   k3 = -0.0357628 (normalized-plane coefficients; a 12 % barrel at this frame's corners).
#:   That the L1D-20c's uncorrected frames are strongly distorted is on record (Lensfun
#:   calibration request #474: "really huge distortion"; DJI's Mobile SDK undistorts its live
#:   video, DJIWidget's ``DJIMavic2ProCameraImageCalibrateFilterDataSource``), but not in
#:   OpenCV's terms. A calibrated unit's own coefficients replace these:
#:   ``CameraModel(..., distortion=...)``.
#: * Rolling shutter: OpenDroneMap's measured readout table (``opendm/rollingshutter.py``,
#:   ``RS_DATABASE['hasselblad l1d-20c']``, measured with the RSCalibration LED method): 47 ms at
#:   16:10 (16.8 MP), 56 ms at 3:2 (19.9 MP, 3648 rows, so 15.4 us per row); a 16:9 frame reads
#:   3078 rows, 47 ms. ``readout_time = 0.047``.
#: * Exposure: 1/500 s, a common daylight survey shutter (our choice; the camera spans 8 s to
#:   1/8000 s). ``exposure_time = 0.002``.
MAVIC2PRO = CameraModel(
    name="mavic2pro",
    intrinsics=Camera(width=5472, height=3078, fx=4253.5, fy=4253.5, cx=2735.5, cy=1538.5),
    distortion=(-0.269478, 0.115681, -8.75619e-5, -3.06177e-4, -0.0357628),
    readout_time=0.047,
    exposure_time=0.002,
)

#: Named camera models (the env's ``camera`` setting).
CAMERA_MODELS: dict[str, CameraModel] = {"paper": CameraModel(), "mavic2pro": MAVIC2PRO}


def make_camera_model(camera: str | CameraModel) -> CameraModel:
    """Resolve a preset name or pass a :class:`CameraModel` through.

    Raises:
        ConfigError: for an unknown name or another type.
    """
    return resolve_named("camera", camera, CAMERA_MODELS, CameraModel, "a CameraModel")


class LensView:
    """Render and project through ``model`` at ``width`` x ``height`` (see the module docstring).

    Attributes:
        camera: the delivered images' pinhole intrinsics (``info["intrinsics"]``).
        distortion: (5,) the coefficients (``info["distortion"]``).
        render_camera: the wide pinhole camera each view is rendered with.
        render_scale: the render's pixels per delivered pixel at the image centre.
    """

    #: Margin of the wide render for the motion during readout, as a fraction of the image side.
    MOTION_MARGIN = 0.02

    def __init__(self, model: CameraModel, width: int, height: int) -> None:
        self.model = model
        self.camera = model.camera(width, height)
        self.distortion = np.array(model.distortion)
        W, H = self.camera.width, self.camera.height
        # The undistorted normalized ray of every delivered pixel centre.
        cols, rows = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        rays = self._rays_at(cols, rows)
        if not np.all(np.isfinite(rays)):
            raise ConfigError(
                f"camera {model.name!r}: the distortion {model.distortion} cannot be inverted over "
                f"a {W} x {H} image (the model folds over inside the frame)"
            )
        # The lens's field: a little beyond the image's widest ray, and never past the radius where
        # the radial polynomial folds over (points beyond it would "appear" at wrong places).
        r2_image = float(np.max(np.sum(rays**2, axis=-1)))
        self._r2_max = min(1.44 * r2_image, _fold_r2(self.distortion))
        fx, fy = self.camera.fx, self.camera.fy
        lo = rays.reshape(-1, 2).min(axis=0) * (fx, fy)
        hi = rays.reshape(-1, 2).max(axis=0) * (fx, fy)
        margin = self.MOTION_MARGIN * max(W, H) if model.readout_time > 0 else 0.0
        lo, hi = lo - margin - 1.0, hi + margin + 1.0  # pinhole-pixel offsets from the centre
        span = hi - lo
        scale = min(1.0, float(np.sqrt(model.max_render_ratio * W * H / (span[0] * span[1]))))
        Wr, Hr = int(np.ceil(span[0] * scale)), int(np.ceil(span[1] * scale))
        self.render_scale = scale
        self.render_camera = replace(
            self.camera, width=Wr, height=Hr, fx=fx * scale, fy=fy * scale,
            cx=-lo[0] * scale - 0.5, cy=-lo[1] * scale - 0.5, skew=self.camera.skew * scale,
        )
        mx, my = self._to_render(rays[..., 0], rays[..., 1])
        self._static = (mx.astype(np.float32), my.astype(np.float32))
        self._fixed = cv2.convertMaps(self._static[0], self._static[1], cv2.CV_16SC2)
        self._static_xy = np.dstack(self._static)
        # The grid the motion part of the map is evaluated on (block centres of grid_px blocks).
        g = model.grid_px
        gw, gh = -(-W // g), -(-H // g)
        gc, gr = np.meshgrid((np.arange(gw) + 0.5) * g - 0.5, (np.arange(gh) + 0.5) * g - 0.5)
        self._grid_shape = (gh, gw)
        self._grid_rows = gr
        grid_rays = self._rays_at(gc, gr)
        self._grid_rays = grid_rays.astype(np.float32)
        self._grid_static = np.stack(self._to_render(grid_rays[..., 0], grid_rays[..., 1]), -1)

    # ------------------------------------------------------------------ geometry
    def _rays_at(self, cols: NDArray, rows: NDArray) -> NDArray[np.float64]:
        """Undistorted normalized coordinates (..., 2) of delivered pixels."""
        K = self.camera.K
        y = (rows - K[1, 2]) / K[1, 1]
        x = (cols - K[0, 2] - K[0, 1] * y) / K[0, 0]
        return undistort_normalized(np.stack([x, y], axis=-1), self.distortion)

    def _to_render(self, x: NDArray, y: NDArray) -> tuple[NDArray, NDArray]:
        Kr = self.render_camera.K
        return Kr[0, 0] * x + Kr[0, 1] * y + Kr[0, 2], Kr[1, 1] * y + Kr[1, 2]

    def row_time(self, v: ArrayLike) -> NDArray[np.float64]:
        """Exposure-centre time (s, relative to the step's pose) of image row ``v`` (continuous)."""
        return self.model.readout_time * ((np.asarray(v, dtype=np.float64) + 0.5) / self.camera.height - 0.5)

    def _moves(self, motion: Motion | None) -> bool:
        m = self.model
        return motion is not None and not motion.is_static and (m.readout_time > 0 or m.exposure_time > 0)

    def project(
        self, cam_from_world: ArrayLike, xyz: ArrayLike, motion: Motion | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """Where world points (N, 3) appear in the delivered image: ``(uv, depth, in_field)``.

        ``uv`` (N, 2) px, ``depth`` (N,) m, ``in_field`` (N,) bool.

        Distortion exact; rolling shutter by fixed-point iteration on the row (to 1e-6 px); depth
        along the optical axis at the step's pose. ``in_field`` is False behind the camera and
        outside the lens's field (more than 1.2 times the image corner's tangent off-axis, or
        where the distortion polynomial folds over). ``uv`` is NaN at or behind the camera (as
        the pinhole truth of :mod:`uav_struct_env.sim.visibility`); outside the field it is the
        undistorted pinhole projection at the step's pose (finite, not in the image).
        """
        T = check_transform("cam_from_world", cam_from_world)
        X0 = np.asarray(xyz, dtype=np.float64).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
        depth = X0[:, 2].copy()
        moving = self._moves(motion) and self.model.readout_time > 0
        v_cam = T[:3, :3] @ motion.velocity if moving else None
        w_cam = T[:3, :3] @ motion.angular_velocity if moving else None
        t = np.zeros(len(X0))
        uv = np.full((len(X0), 2), np.nan)
        for iteration in range(10 if moving else 1):
            Xt = X0 if not moving else _rotate(-w_cam * t[:, None], X0 - v_cam * t[:, None])
            with np.errstate(divide="ignore", invalid="ignore"):
                xy = Xt[:, :2] / Xt[:, 2:3]
            with np.errstate(invalid="ignore"):
                xy[np.sum(xy**2, axis=1) > self._r2_max] = np.nan
            xy_d = distort_normalized(xy, self.distortion)
            K = self.camera.K
            new = np.stack([K[0, 0] * xy_d[:, 0] + K[0, 1] * xy_d[:, 1] + K[0, 2],
                            K[1, 1] * xy_d[:, 1] + K[1, 2]], axis=1)
            with np.errstate(invalid="ignore"):
                done = iteration > 0 and np.nanmax(np.abs(new - uv), initial=0.0) < 1e-6
            uv = new
            if done or not moving:
                break
            t = np.where(np.isfinite(uv[:, 1]), self.row_time(uv[:, 1]), 0.0)
        in_field = (depth > 0) & np.all(np.isfinite(uv), axis=1)
        K = self.camera.K
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = X0[:, :2] / X0[:, 2:3]
        pinhole = np.stack([K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2],
                            K[1, 1] * xy[:, 1] + K[1, 2]], axis=1)
        uv = np.where(in_field[:, None], uv, pinhole)
        uv[depth <= 0] = np.nan
        return uv, depth, in_field

    def _motion_map(
        self, cam_from_world: NDArray, motion: Motion, depth: NDArray[np.float32], dt: float = 0.0,
        step: int = 1,
    ) -> NDArray[np.float64]:
        """Render coordinates (gh, gw, 2) of the grid's pixels seen at their row time + ``dt``.

        ``step`` > 1 evaluates every ``step``-th grid row and column only.
        """
        R = cam_from_world[:3, :3]
        v_cam, w_cam = R @ motion.velocity, R @ motion.angular_velocity
        rays = self._grid_rays[::step, ::step]
        t = self.row_time(self._grid_rows[::step, 0]) + dt  # (rows,)
        # Per grid row: the rotation from the camera at its time to the step's pose (Rodrigues).
        theta = float(np.linalg.norm(w_cam))
        k = w_cam / theta if theta > 0 else np.zeros(3)
        Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        a = (theta * t)[:, None, None]
        Rt = (np.eye(3) + np.sin(a) * Kx + (1.0 - np.cos(a)) * (Kx @ Kx)).astype(np.float32)
        # float32 throughout (1e-4 px at these coordinates): the warp's cost is this function.
        rx, ry = rays[..., 0], rays[..., 1]
        px, py, pz = (rx * Rt[:, None, i, 0] + ry * Rt[:, None, i, 1] + Rt[:, None, i, 2] for i in range(3))
        o = (v_cam[None, :] * t[:, None]).astype(np.float32)
        ox, oy, oz = o[:, 0, None], o[:, 1, None], o[:, 2, None]
        fx, sk, cx, fy, cy = (np.float32(v) for v in self.render_camera.K[[0, 0, 0, 1, 1], [0, 1, 2, 1, 2]])
        Hr, Wr = depth.shape
        x, y = px / pz, py / pz
        qx, qy = fx * x + sk * y + cx, fy * y + cy
        for _ in range(2):  # meet the rendered surface: depth at the current guess, then re-project
            col = np.clip(qx + 0.5, 0, Wr - 1).astype(np.int32)
            row = np.clip(qy + 0.5, 0, Hr - 1).astype(np.int32)
            s = (depth[row, col] - oz) / pz
            z = oz + s * pz
            x, y = (ox + s * px) / z, (oy + s * py) / z
            qx, qy = fx * x + sk * y + cx, fy * y + cy
        return np.stack([qx, qy], axis=-1).astype(np.float64)

    def _full(self, grid: NDArray[np.float64]) -> NDArray[np.float32]:
        """A grid field (gh, gw[, 2]) upsampled to the delivered image (H, W[, 2]), block centres aligned."""
        g = self.model.grid_px
        gh, gw = self._grid_shape
        up = cv2.resize(grid.astype(np.float32), (gw * g, gh * g), interpolation=cv2.INTER_LINEAR)
        return up[: self.camera.height, : self.camera.width]

    def landmark_truth(
        self, wide: dict[str, NDArray], cam_from_world: ArrayLike, motion: Motion | None = None
    ) -> dict[str, NDArray]:
        """Landmark truth of the delivered image from the truth of the wide render.

        ``wide`` is ``SiteWorld.landmark_truth`` (or ``landmark_truth_raycast``) with
        :attr:`render_camera`: its occlusion test (at the step's pose) is kept; ``uv`` becomes
        where each landmark appears in the delivered image (:meth:`project`) and ``in_frame``
        tests that position against the delivered image.
        """
        uv, z, in_field = self.project(cam_from_world, wide["xyz"], motion)
        W, H = self.camera.size
        with np.errstate(invalid="ignore"):
            in_frame = (
                in_field & (z > self.camera.near)
                & (uv[:, 0] >= -0.5) & (uv[:, 0] < W - 0.5)
                & (uv[:, 1] >= -0.5) & (uv[:, 1] < H - 0.5)
            )
        return {**wide, "uv": uv, "in_frame": in_frame, "visible": wide["visible"] & in_frame}

    # ------------------------------------------------------------------ rendering
    def warp(
        self,
        rgb: NDArray[np.uint8],
        depth: NDArray[np.float32] | None,
        cam_from_world: ArrayLike,
        motion: Motion | None = None,
        *,
        warp_depth: bool = False,
    ) -> tuple[NDArray[np.uint8], NDArray[np.float32] | None]:
        """The delivered image (and depth, with ``warp_depth``) from a render of :attr:`render_camera`.

        ``depth`` (the render's metric depth) is needed when ``motion`` moves the camera.
        """
        T = check_transform("cam_from_world", cam_from_world)
        if not self._moves(motion):
            out = cv2.remap(rgb, *self._fixed, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            dep = None
            if warp_depth and depth is not None:
                dep = cv2.remap(depth, *self._fixed, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
            return out, dep
        if depth is None:
            raise ValueError("a moving camera's warp needs the render's depth (render with depth=True)")
        if self.model.readout_time > 0:
            correction = self._motion_map(T, motion, depth) - self._grid_static
            # Fixed-point maps (1/32 px, as the static ones): faster to remap than float maps.
            maps = cv2.convertMaps(self._static_xy + self._full(correction), None, cv2.CV_16SC2)
        else:
            maps = self._fixed
        out = cv2.remap(rgb, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        dep = None
        if warp_depth:
            dep = cv2.remap(depth, *maps, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        e = self.model.exposure_time
        if e > 0:
            step = max(1, self._grid_shape[0] // 16)
            a = self._motion_map(T, motion, depth, -e / 2, step)
            b = self._motion_map(T, motion, depth, e / 2, step)
            blur = np.nanmedian((b - a).reshape(-1, 2), axis=0) / self.render_scale
            out = line_blur(out, blur)
        return out, dep


def _fold_r2(coefficients: NDArray[np.float64]) -> float:
    """Squared normalized radius where ``r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` stops increasing (inf: never)."""
    k1, k2, _, _, k3 = coefficients
    r2 = np.linspace(0.0, 16.0, 160001)
    slope = 1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2**2 + 7.0 * k3 * r2**3  # d r_d / d r
    bad = np.flatnonzero(slope <= 0)
    return float(r2[bad[0]]) if len(bad) else float("inf")


def line_blur(image: NDArray[np.uint8], vector: ArrayLike) -> NDArray[np.uint8]:
    """``image`` convolved with a uniform segment of ``vector`` (px, centred); shorter than 0.5 px: as is.

    The kernel is symmetric about its centre, so the blur moves no feature's centroid.
    """
    vx, vy = (float(x) for x in np.asarray(vector, dtype=np.float64).reshape(2))
    length = float(np.hypot(vx, vy))
    if not np.isfinite(length) or length < 0.5:
        return image
    half = int(np.ceil(length / 2)) + 1
    size = 2 * half + 1
    kernel = np.zeros((size, size), np.float32)
    n = max(2, int(np.ceil(4 * length)))
    for s in np.linspace(-0.5, 0.5, n):  # bilinear splats along the segment
        x, y = half + s * vx, half + s * vy
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        kernel[y0, x0] += (1 - fx) * (1 - fy)
        kernel[y0, x0 + 1] += fx * (1 - fy)
        kernel[y0 + 1, x0] += (1 - fx) * fy
        kernel[y0 + 1, x0 + 1] += fx * fy
    kernel /= kernel.sum()
    return cv2.filter2D(image, -1, kernel, borderType=cv2.BORDER_REPLICATE)
