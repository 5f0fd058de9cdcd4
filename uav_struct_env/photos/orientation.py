"""The EXIF orientation tag: detect on the upright image, report the sensor's camera.

A camera stores its sensor's pixels and states in EXIF ``Orientation`` (274) how a viewer must
turn them to show the scene upright: 1 as stored, 6 a quarter turn clockwise, 3 a half turn, 8 a
quarter turn anticlockwise (DJI's cameras write 1; a camera rolled on its gimbal or held
upright writes 6 or 8). The gimbal angles and a calibration made on the stored pixels refer to
the sensor's layout, while the learned detector was trained on upright views (its training flips
images left-right but never turns them). So a photo whose tag turns it is localized on the
upright image with the *upright camera* -- the sensor's camera turned about its optical axis by
the same quarter turns, its intrinsics and distortion carried through the same pixel map -- and
the estimate is turned back: poses, detections and the camera a photo reports are the sensor's
and the stored pixels'. The covariance, in (camera centre, world-frame rotation vector), and the
prior's sigmas, in the same parameters, do not change under a turn of the camera frame.

Tags 2, 4, 5 and 7 mirror the image: no pinhole camera sees a mirrored scene, and no drone
camera writes them, so they are refused (:func:`upright_turns`).

A quarter turn clockwise maps a stored pixel ``(u, v)`` of a ``W x H`` image to ``(H - 1 - v, u)``
of the ``H x W`` upright one (pixel centres at integers) and the camera axes ``(x, y, z)`` to
``(-y, x, z)``: ``K' = A K R^T`` with ``A`` the pixel map and ``R`` the axis turn, and OpenCV's
tangential distortion ``(p1, p2)`` becomes ``(p2, -p1)`` (the radial terms do not change).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uav_struct_env.photos.errors import PhotoError

__all__ = ["ORIENTATION_TURNS", "turn_camera", "turn_image", "turn_points", "turn_pose", "upright_turns"]

#: Quarter turns clockwise that show the stored pixels upright, by EXIF orientation tag.
ORIENTATION_TURNS = {1: 0, 6: 1, 3: 2, 8: 3}
#: The camera axes' quarter turn clockwise (as seen in the image): ``(x, y, z) -> (-y, x, z)``.
_AXES_TURN = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def upright_turns(orientation: int, where: str = "photo") -> int:
    """Quarter turns clockwise (0-3) that show a photo of EXIF ``orientation`` upright.

    Raises:
        PhotoError: a mirrored tag (2, 4, 5, 7) or a value outside 1-8, naming ``where``.
    """
    if orientation in ORIENTATION_TURNS:
        return ORIENTATION_TURNS[orientation]
    if orientation in (2, 4, 5, 7):
        raise PhotoError(f"{where}: EXIF Orientation {orientation} mirrors the image, which no camera's "
                         "projection does; expected 1, 3, 6 or 8 (store the pixels unmirrored)")
    raise PhotoError(f"{where}: EXIF Orientation must be 1-8, got {orientation!r}")


def turn_image(image: NDArray, turns: int) -> NDArray:
    """``image`` (H, W, ...) turned ``turns`` quarter turns clockwise (negative: anticlockwise)."""
    return np.ascontiguousarray(np.rot90(image, -int(turns)))


def turn_points(uv: ArrayLike, size: tuple[int, int], turns: int) -> NDArray[np.float64]:
    """(N, 2) pixels of a ``size = (W, H)`` image after turning it ``turns`` quarter turns clockwise."""
    out = np.asarray(uv, dtype=np.float64).reshape(-1, 2).copy()
    w, h = size
    for _ in range(int(turns) % 4):
        out = np.column_stack([h - 1 - out[:, 1], out[:, 0]])
        w, h = h, w
    return out


def turn_camera(K: ArrayLike, distortion: ArrayLike, size: tuple[int, int],
                turns: int) -> tuple[NDArray[np.float64], NDArray[np.float64], tuple[int, int]]:
    """The camera of the image turned ``turns`` quarter turns clockwise: ``(K, distortion, size)``.

    ``K`` (3, 3) px, ``distortion`` OpenCV's (5,) ``(k1, k2, p1, p2, k3)``, ``size = (W, H)``.
    """
    K2 = np.asarray(K, dtype=np.float64).copy()
    d = np.asarray(distortion, dtype=np.float64).reshape(-1).copy()
    w, h = size
    for _ in range(int(turns) % 4):
        A = np.array([[0.0, -1.0, h - 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        K2 = A @ K2 @ _AXES_TURN.T
        d[2], d[3] = d[3], -d[2]
        w, h = h, w
    return K2, d, (w, h)


def turn_pose(cam_from_world: ArrayLike, turns: int) -> NDArray[np.float64]:
    """(4, 4) ``cam_from_world`` of the camera turned ``turns`` quarter turns about its optical axis."""
    T = np.eye(4)
    T[:3, :3] = np.linalg.matrix_power(_AXES_TURN, int(turns) % 4)
    return T @ np.asarray(cam_from_world, dtype=np.float64)
