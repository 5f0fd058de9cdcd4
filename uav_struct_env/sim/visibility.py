"""Ground-truth landmark visibility: pixel position, inside the image, and not occluded.

No pybullet: the depth image may come from any renderer, so this is testable on synthetic depth
maps. The test runs for every agent at every env step, so it is compiled (numba): the projection
and the windows (:func:`_windows`), the tolerances (:func:`_tolerances`) and the window test on a
depth image (:func:`_image_windows`); the ray cast (:mod:`uav_struct_env.sim.raycast`) makes the
same test on ray-cast depths with the same windows and tolerances.

A landmark is **visible** when it is in front of the camera (depth > near), its projection lies
inside the image (``-0.5 <= u < W - 0.5`` and the same for ``v``: the area covered by pixels) and
the rendered surface there is not in front of it. Landmarks sit *on* surfaces, at convex edges
(column-top centres, slab corners) or on the ground (marker corners), so the pixel at the
projection may show either the landmark's own surface (same depth) or what lies behind the edge
(larger depth). The test samples the rendered depth in a ``(2r+1) x (2r+1)`` pixel window around
the rounded projection and accepts the landmark if **any** sample is at least
``z - tolerance(z)``: only a surface in front of the landmark over the whole window hides it.

``tolerance(z) = abs_tol + rel_tol * z + 2 * q(z)`` where ``q(z) = z**2 (f - n) / (f n 2**bits)``
is one step of a ``bits``-bit depth buffer at depth ``z`` (near ``n``, far ``f``; the EGL plugin's
buffer has 16 bits, TinyRenderer's is float). With the defaults that is about 3 cm + 0.4 % of the
distance, 0.23 m at 50 m, plus the buffer steps (a few mm with the near plane ``SiteWorld`` uses).
An occluder must be farther than that in front of the landmark to hide it; anything a metre or
more in front (a column, the slab edge) always does.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from localization.geometry.transforms import as_points, check_transform
from uav_struct_env.sim.camera import Camera
from uav_struct_env.site.landmarks import LandmarkSet

__all__ = ["depth_tolerance", "landmark_visibility"]


def depth_tolerance(
    z: ArrayLike,
    camera: Camera,
    *,
    abs_tol: float = 0.03,
    rel_tol: float = 0.004,
    depth_bits: int = 24,
) -> NDArray[np.float64]:
    """Depth tolerance (m) of the occlusion test at depth ``z`` (m); see the module docstring."""
    z = np.asarray(z, dtype=np.float64)
    out = _tolerances(np.ascontiguousarray(z.reshape(-1)), float(camera.near), float(camera.far),
                      float(abs_tol), float(rel_tol), int(depth_bits))
    return out.reshape(z.shape)


@njit(cache=True, nogil=True)
def _tolerances(
    z: NDArray, near: float, far: float, abs_tol: float, rel_tol: float, depth_bits: int
) -> NDArray:
    """:func:`depth_tolerance` of each depth in ``z`` (1-D), compiled (also the ray cast's)."""
    out = np.empty(z.shape[0])
    scale = far * near * 2.0**depth_bits
    for i in range(z.shape[0]):
        step = z[i] ** 2 * (far - near) / scale
        out[i] = abs_tol + rel_tol * abs(z[i]) + 2.0 * step
    return out


def landmark_visibility(
    landmarks: LandmarkSet | ArrayLike,
    cam_from_world: ArrayLike,
    camera: Camera,
    depth: ArrayLike,
    *,
    ids: ArrayLike | None = None,
    radius: int = 1,
    abs_tol: float = 0.03,
    rel_tol: float = 0.004,
    depth_bits: int = 24,
) -> dict[str, NDArray]:
    """Project landmarks and decide which are visible in a rendered depth image.

    Args:
        landmarks: a :class:`LandmarkSet`, or an (M, 3) array of project-frame points.
        cam_from_world: (4, 4) camera pose.
        camera: the camera the depth image was rendered with.
        depth: (H, W) metric depth along the optical axis (m), as ``SiteWorld.render`` returns.
        ids: (M,) ids when ``landmarks`` is an array (default ``0..M-1``).
        radius: half size of the pixel window searched for an unoccluded depth sample.
        abs_tol: constant part of the depth tolerance (m), see :func:`depth_tolerance`.
        rel_tol: part of the tolerance proportional to the landmark's depth.
        depth_bits: resolution of the depth buffer the depth came from (16 for EGL); pass the
            camera with the near plane it was rendered with (``RenderResult.camera``).

    Returns:
        A dict of arrays: ``ids`` (M,) int64, ``xyz`` (M, 3) float64, ``uv`` (M, 2) float64
        (NaN for points at or behind the camera centre), ``in_frame`` (M,) bool (in front of the
        near plane and inside the image), ``visible`` (M,) bool (in frame and not occluded).

    Raises:
        TypeError, ValueError: for malformed inputs, naming the bad argument.
    """
    if isinstance(landmarks, LandmarkSet):
        xyz = landmarks.xyz.reshape(-1, 3)
        ids_arr = np.asarray(landmarks.ids, dtype=np.int64)
    else:
        xyz = as_points("landmarks", landmarks, 3)
        ids_arr = np.arange(len(xyz), dtype=np.int64) if ids is None else np.asarray(ids)
        if ids_arr.shape != (len(xyz),) or not np.issubdtype(ids_arr.dtype, np.integer):
            raise ValueError(f"ids must be ({len(xyz)},) integers, got shape {ids_arr.shape}")
        ids_arr = ids_arr.astype(np.int64)
    T = check_transform("cam_from_world", cam_from_world)
    if not isinstance(camera, Camera):
        raise TypeError(
            f"camera must be a uav_struct_env.sim.camera.Camera, got {type(camera).__name__}"
        )
    if depth is None:
        raise TypeError("depth must be the (H, W) metric depth image of the render, got None")
    D = np.asarray(depth, dtype=np.float64)
    if D.shape != (camera.height, camera.width):
        raise ValueError(
            f"depth must have the camera's shape (H, W) = {(camera.height, camera.width)}, "
            f"got {D.shape}"
        )
    check_number("radius (pixels)", radius, 0, integer=True, type_error=ValueError)

    # A writable copy, returned too: numba compiles the kernel once per argument type, and a site's
    # read-only landmarks would be another type than an array's.
    xyz = np.array(xyz, dtype=np.float64, order="C")
    uv, in_frame, visible = _image_windows(
        xyz, np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]),
        camera.K, int(camera.width), int(camera.height), float(camera.near), float(camera.far),
        int(radius), float(abs_tol), float(rel_tol), int(depth_bits), np.ascontiguousarray(D),
    )
    return {"ids": ids_arr.copy(), "xyz": xyz, "uv": uv, "in_frame": in_frame, "visible": visible}


@njit(cache=True, nogil=True)
def _image_windows(
    xyz: NDArray, R: NDArray, t: NDArray, K: NDArray, width: int, height: int, near: float, far: float,
    radius: int, abs_tol: float, rel_tol: float, depth_bits: int, depth: NDArray,
) -> tuple[NDArray, NDArray, NDArray]:
    """The test of the module docstring on a depth image, compiled: ``(uv, in_frame, visible)``.

    The windows and limits of :func:`_window_limits`; a landmark is visible when any pixel of its
    window has a depth of at least its limit. The ray cast makes the same test on ray-cast depths
    (:func:`uav_struct_env.sim.raycast.raycast_visibility`).
    """
    uv, in_frame, rows, cols, idx, limit = _window_limits(
        xyz, R, t, K, width, height, near, far, radius, abs_tol, rel_tol, depth_bits
    )
    visible = np.zeros(xyz.shape[0], dtype=np.bool_)
    k = 2 * radius + 1
    for j in range(rows.shape[0]):
        for a in range(k):
            for b in range(k):
                if depth[rows[j, a, b], cols[j, a, b]] >= limit[j]:
                    visible[idx[j]] = True
    return uv, in_frame, visible


@njit(cache=True, nogil=True)
def _window_limits(
    xyz: NDArray, R: NDArray, t: NDArray, K: NDArray, width: int, height: int, near: float, far: float,
    radius: int, abs_tol: float, rel_tol: float, depth_bits: int,
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """:func:`_windows` and the depth each in-frame landmark's window must reach to show it.

    Returns ``(uv, in_frame, rows, cols, idx, limit)``: ``idx`` (F,) the in-frame landmarks'
    indices, ``limit`` (F,) their ``z - tolerance(z)`` (:func:`_tolerances`).
    """
    uv, z, in_frame, rows, cols = _windows(xyz, R, t, K, width, height, near, radius)
    idx = np.flatnonzero(in_frame)
    zf = np.empty(idx.shape[0])
    for j in range(idx.shape[0]):
        zf[j] = z[idx[j]]
    return uv, in_frame, rows, cols, idx, zf - _tolerances(zf, near, far, abs_tol, rel_tol, depth_bits)


@njit(cache=True, nogil=True, error_model="numpy")
def _windows(
    xyz: NDArray, R: NDArray, t: NDArray, K: NDArray, width: int, height: int, near: float, radius: int
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Projections and the pixel windows around them, compiled.

    Returns ``(uv (M, 2), z (M,), in_frame (M,), rows (F, k, k), cols (F, k, k))``: pixels (NaN
    at or behind the camera) and depths of the points ``xyz`` at ``cam_from_world`` (R, t) as
    :func:`localization.geometry.transforms.project` gives them; which are in front of ``near`` and inside
    the image; and for the F in-frame ones, in order, the integer pixels of the
    ``k x k`` (``k = 2 radius + 1``) window around the rounded projection, clipped to the image.
    """
    m = xyz.shape[0]
    uv = np.empty((m, 2))
    z = np.empty(m)
    in_frame = np.zeros(m, dtype=np.bool_)
    for i in range(m):
        x = xyz[i, 0] * R[0, 0] + xyz[i, 1] * R[0, 1] + xyz[i, 2] * R[0, 2] + t[0]
        y = xyz[i, 0] * R[1, 0] + xyz[i, 1] * R[1, 1] + xyz[i, 2] * R[1, 2] + t[1]
        z[i] = xyz[i, 0] * R[2, 0] + xyz[i, 1] * R[2, 1] + xyz[i, 2] * R[2, 2] + t[2]
        if z[i] <= 0.0:
            uv[i, 0] = np.nan
            uv[i, 1] = np.nan
            continue
        xs, ys = x / z[i], y / z[i]
        uv[i, 0] = xs * K[0, 0] + ys * K[0, 1] + K[0, 2]
        uv[i, 1] = xs * K[1, 0] + ys * K[1, 1] + K[1, 2]
        in_frame[i] = (z[i] > near and -0.5 <= uv[i, 0] < width - 0.5 and -0.5 <= uv[i, 1] < height - 0.5)
    k = 2 * radius + 1
    f = int(in_frame.sum())
    rows = np.empty((f, k, k), dtype=np.intp)
    cols = np.empty((f, k, k), dtype=np.intp)
    j = 0
    for i in range(m):
        if not in_frame[i]:
            continue
        col = min(max(int(np.rint(uv[i, 0])), 0), width - 1)
        row = min(max(int(np.rint(uv[i, 1])), 0), height - 1)
        for a in range(k):
            for b in range(k):
                rows[j, a, b] = min(max(row + a - radius, 0), height - 1)
                cols[j, a, b] = min(max(col + b - radius, 0), width - 1)
        j += 1
    return uv, z, in_frame, rows, cols
