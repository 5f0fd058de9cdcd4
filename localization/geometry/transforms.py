"""Rigid transforms and the pinhole camera: the conventions every other module relies on.

Conventions (documented once, here, and tested against renders in ``tests/sim``):

* Rigid transforms are 4x4 float64 arrays named ``b_from_a``; ``b_from_a @ p_a`` gives ``p_b``
  for homogeneous points. The paper's (R, t) is ``cam_from_world``; the camera centre is
  ``C = -R.T @ t``.
* Camera frame: OpenCV (x right, y down, z forward).
* Pixels: ``(u, v)`` with ``u`` to the right and ``v`` down; the centre of the pixel in column
  ``i`` and row ``j`` is at ``(u, v) = (i, j)`` exactly (integer pixel centres, as in OpenCV).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.geometry.kernels import (
    TRANSFORM_LAST_ROW,
    TRANSFORM_NOT_FINITE,
    TRANSFORM_NOT_ROTATION,
    center,
    inverse,
    kernel_array,
    quat_wxyz,
    transform_fault,
)

__all__ = [
    "as_points",
    "camera_center",
    "check_intrinsics",
    "check_transform",
    "inverse_intrinsics",
    "invert",
    "look_at",
    "make_transform",
    "matrix_from_quat_wxyz",
    "project",
    "quat_wxyz_from_matrix",
    "rotation_angle_deg",
    "scaled_intrinsics",
    "skew",
    "so3_exp",
    "so3_log",
    "transform_points",
]


def as_points(name: str, points: ArrayLike, dim: int) -> NDArray[np.float64]:
    """Return ``points`` as a float64 ``(N, dim)`` array, or raise naming ``name``.

    Raises:
        TypeError: if ``points`` is not numeric.
        ValueError: if the shape is not ``(N, dim)``.
    """
    arr = np.asarray(points)
    if arr.dtype == np.float64 and arr.ndim == 2 and arr.shape[1] == dim:
        return arr  # already what is asked (the common case, called several times per frame)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == np.bool_):
        raise TypeError(
            f"{name} must be a numeric array of shape (N, {dim}), got dtype {arr.dtype}"
        )
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, dim)
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name} must have shape (N, {dim}), got {arr.shape}")
    return arr.astype(np.float64, copy=False)


def check_transform(name: str, transform: ArrayLike) -> NDArray[np.float64]:
    """Return ``transform`` as a float64 4x4 rigid transform, or raise naming ``name``.

    Raises:
        TypeError: if it is not numeric.
        ValueError: if it is not 4x4, not finite, its last row is not ``[0, 0, 0, 1]`` or its
            rotation block is not orthonormal with determinant +1 (tolerance 1e-6).
    """
    arr = np.asarray(transform)
    if arr.dtype != np.float64 and (arr.dtype == object or not np.issubdtype(arr.dtype, np.number)):
        raise TypeError(f"{name} must be a numeric 4x4 array, got dtype {arr.dtype}")
    if arr.shape != (4, 4):
        raise ValueError(f"{name} must have shape (4, 4), got {arr.shape}")
    arr = kernel_array(arr, dtype=np.float64)
    # One compiled pass: this check runs on every transform the pipeline and the metrics touch,
    # several times per agent and env step, where numpy's per-call overhead would dominate
    fault = transform_fault(arr)
    if fault == TRANSFORM_NOT_FINITE:
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    if fault == TRANSFORM_LAST_ROW:
        raise ValueError(f"{name} last row must be [0, 0, 0, 1], got {arr[3].tolist()}")
    if fault == TRANSFORM_NOT_ROTATION:
        raise ValueError(f"{name} rotation block must be a proper rotation, got {arr[:3, :3].tolist()}")
    return arr


def inverse_intrinsics(K: ArrayLike) -> NDArray[np.float64]:
    """``K^-1`` of a (3, 3) intrinsic matrix, read-only and cached by its float64 values.

    Every ray through a pixel needs it (``K^-1 [u, v, 1]``) and a camera's ``K`` rarely changes,
    so the inverse is computed once per distinct matrix (an LRU cache of 64).
    """
    arr = np.ascontiguousarray(K, dtype=np.float64)
    if arr.shape != (3, 3):
        raise ValueError(f"K must have shape (3, 3), got {arr.shape}")
    return _inverse_of(arr.tobytes())


def scaled_intrinsics(K: ArrayLike, sx: float, sy: float) -> NDArray[np.float64]:
    """``K`` of the image resized by ``sx`` (x) and ``sy`` (y), pixel centres at integers in both.

    Focal lengths scale by the factors and the principal point as pixel edges do:
    ``cx' = (cx + 0.5) sx - 0.5`` (this module's integer pixel centres).
    """
    Kq = np.array(K, dtype=np.float64)
    Kq[0, :] *= sx
    Kq[1, :] *= sy
    Kq[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    Kq[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return Kq


@functools.lru_cache(maxsize=64)
def _inverse_of(K_bytes: bytes) -> NDArray[np.float64]:
    out = np.linalg.inv(np.frombuffer(K_bytes, dtype=np.float64).reshape(3, 3))
    out.flags.writeable = False
    return out


def check_intrinsics(name: str, K: ArrayLike) -> NDArray[np.float64]:
    """Return ``K`` as a float64 3x3 pinhole intrinsic matrix, or raise naming ``name``.

    Raises:
        TypeError: if it is not numeric.
        ValueError: if it is not 3x3, not finite, has non-positive focal lengths or a last row
            other than ``[0, 0, 1]``.
    """
    arr = np.asarray(K)
    if arr.dtype == object or not np.issubdtype(arr.dtype, np.number):
        raise TypeError(f"{name} must be a numeric 3x3 array, got dtype {arr.dtype}")
    if arr.shape != (3, 3):
        raise ValueError(f"{name} must have shape (3, 3), got {arr.shape}")
    arr = arr.astype(np.float64, copy=False)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    if arr[0, 0] <= 0 or arr[1, 1] <= 0:
        raise ValueError(
            f"{name} focal lengths must be positive, got fx={arr[0, 0]}, fy={arr[1, 1]}"
        )
    if not np.allclose(arr[2], [0.0, 0.0, 1.0]) or arr[1, 0] != 0:
        raise ValueError(
            f"{name} must be upper triangular with last row [0, 0, 1], got {arr.tolist()}"
        )
    return arr


def make_transform(rotation: ArrayLike, translation: ArrayLike) -> NDArray[np.float64]:
    """Build a 4x4 ``b_from_a`` from a 3x3 rotation and a translation (3,)."""
    out = np.eye(4)
    out[:3, :3] = np.asarray(rotation, dtype=np.float64)
    out[:3, 3] = np.asarray(translation, dtype=np.float64).reshape(3)
    return out


def _rigid_rows(name: str, T: ArrayLike) -> NDArray[np.float64]:
    """``T`` as a float64 matrix with the rows ``[R | t]`` a rigid transform starts with.

    The compiled :func:`invert` and :func:`camera_center` read ``T[:3, :4]`` unchecked; this
    raises ``ValueError`` (naming ``name`` and the shape) for anything smaller or not 2-D.
    """
    out = np.asarray(T, dtype=np.float64)
    if out.ndim != 2 or out.shape[0] < 3 or out.shape[1] < 4:
        raise ValueError(f"{name} must be a (4, 4) rigid transform, got shape {out.shape}")
    return kernel_array(out)


def invert(b_from_a: ArrayLike) -> NDArray[np.float64]:
    """Invert a rigid transform exactly (``R.T``, ``-R.T t``), returning ``a_from_b``."""
    return inverse(_rigid_rows("b_from_a", b_from_a))  # compiled


def transform_points(b_from_a: ArrayLike, points_a: ArrayLike) -> NDArray[np.float64]:
    """Apply a 4x4 rigid transform to points ``(N, 3)`` and return ``(N, 3)``."""
    T = np.asarray(b_from_a, dtype=np.float64)
    pts = np.asarray(points_a, dtype=np.float64).reshape(-1, 3)
    return pts @ T[:3, :3].T + T[:3, 3]


def camera_center(cam_from_world: ArrayLike) -> NDArray[np.float64]:
    """Camera centre in the world frame, ``C = -R.T t``, shape (3,)."""
    return center(_rigid_rows("cam_from_world", cam_from_world))  # compiled


def project(
    K: ArrayLike, cam_from_world: ArrayLike, points_world: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Project world points with the pinhole model.

    Args:
        K: (3, 3) intrinsics.
        cam_from_world: (4, 4) rigid transform.
        points_world: (N, 3) points in the world (project) frame, metres.

    Returns:
        ``(uv, depth)``: (N, 2) pixel coordinates (integer pixel centres) and (N,) depth along the
        optical axis in metres. Points with ``depth <= 0`` are behind the camera; their ``uv`` is
        still computed (and meaningless) unless ``depth == 0``, where it is NaN.
    """
    K = np.asarray(K, dtype=np.float64)
    pts_cam = transform_points(cam_from_world, points_world)
    depth = pts_cam[:, 2].copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = pts_cam[:, :2] / depth[:, None]
    uv = xy @ K[:2, :2].T + K[:2, 2]
    uv[depth == 0] = np.nan
    return uv, depth


def _cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``np.cross`` of two (3,) vectors: its products and differences on Python floats.

    On (3,) vectors ``np.cross``'s per-call overhead is nearly all of its cost.
    """
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def look_at(
    eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)
) -> NDArray[np.float64]:
    """``cam_from_world`` of an OpenCV camera at ``eye`` looking at ``target``, image up ~ ``up``.

    Raises:
        ValueError: if ``eye == target`` or the viewing direction is parallel to ``up``.
    """
    eye = np.asarray(eye, dtype=np.float64).reshape(3)
    target = np.asarray(target, dtype=np.float64).reshape(3)
    up = np.asarray(up, dtype=np.float64).reshape(3)
    forward = target - eye
    norm = np.linalg.norm(forward)
    if norm < 1e-12:
        raise ValueError(f"look_at needs eye != target, got eye={eye.tolist()}")
    z = forward / norm
    x = _cross(z, up)  # image right = forward x up
    if np.linalg.norm(x) < 1e-9:
        raise ValueError(
            f"look_at viewing direction {z.tolist()} is parallel to up={up.tolist()}; pass another up"
        )
    x /= np.linalg.norm(x)
    y = _cross(z, x)  # image down
    world_from_cam = np.eye(4)
    world_from_cam[:3, 0] = x
    world_from_cam[:3, 1] = y
    world_from_cam[:3, 2] = z
    world_from_cam[:3, 3] = eye
    return invert(world_from_cam)


def rotation_angle_deg(R_a: ArrayLike, R_b: ArrayLike) -> float:
    """Geodesic angle between two rotations, ``angle(R_a.T @ R_b)``, in degrees."""
    R = (np.asarray(R_a, dtype=np.float64)[:3, :3].T @ np.asarray(R_b, dtype=np.float64)[:3, :3]).tolist()
    # np.trace, np.clip and np.arccos's arithmetic on Python floats (on a 3 x 3 matrix their
    # per-call overhead would be nearly all of the cost)
    cos = min(max((R[0][0] + R[1][1] + R[2][2] - 1.0) / 2.0, -1.0), 1.0)
    return math.degrees(math.acos(cos))


def quat_wxyz_from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion (w, x, y, z) with ``w >= 0`` of a rotation matrix (3x3 or the 4x4's block).

    Shepperd's method, from the largest of 4 w^2, 4 x^2, 4 y^2, 4 z^2 (the best conditioned);
    compiled (:func:`localization.geometry.kernels.quat_wxyz`: every agent's pose, every step).
    """
    m = kernel_array(np.asarray(R, dtype=np.float64)[:3, :3])
    return quat_wxyz(m)


def matrix_from_quat_wxyz(q: ArrayLike) -> NDArray[np.float64]:
    """3x3 rotation matrix of a quaternion (w, x, y, z); the quaternion is normalised first."""
    from scipy.spatial.transform import Rotation

    w, x, y, z = np.asarray(q, dtype=np.float64).reshape(4)
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def skew(v: ArrayLike) -> NDArray[np.float64]:
    """3x3 cross-product matrix ``[v]x`` with ``skew(v) @ w == np.cross(v, w)``."""
    x, y, z = np.asarray(v, dtype=np.float64).reshape(3)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def so3_exp(rotvec: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix of a rotation vector (axis * angle, rad), Rodrigues' formula."""
    w = np.asarray(rotvec, dtype=np.float64).reshape(3)
    theta = float(np.linalg.norm(w))
    W = skew(w)
    if theta < 1e-8:
        return np.eye(3) + W + 0.5 * W @ W
    return np.eye(3) + (np.sin(theta) / theta) * W + ((1.0 - np.cos(theta)) / theta**2) * W @ W


def so3_log(R: ArrayLike) -> NDArray[np.float64]:
    """Rotation vector (axis * angle, rad, angle in [0, pi]) of a rotation matrix."""
    R = np.asarray(R, dtype=np.float64)[:3, :3]
    cos = float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if cos > 0.99:  # small angles: sin(theta) ~ |w| / 2, stable
        s = 0.5 * float(np.linalg.norm(w))
        theta = float(np.arcsin(min(s, 1.0)))
        return w * (0.5 if s < 1e-12 else theta / (2.0 * s))
    if cos > -0.99:
        theta = float(np.arccos(cos))
        return w * (theta / (2.0 * np.sin(theta)))
    from scipy.spatial.transform import Rotation  # near pi: let scipy handle the sign

    return Rotation.from_matrix(R).as_rotvec()
