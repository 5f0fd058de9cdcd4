"""Synthetic scenes for tests and benchmarks: viewpoints, the paper's priors, landmark truth, ArUco images.

Test fixtures built on the pure geometry (no simulator): the study's viewpoint ring, the paper's
alternating prior perturbation, the landmark-truth context a detector takes, and a rendered
image of ArUco markers.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.geometry.attitude import attitude_from_world_from_cam, world_from_cam_from_attitude
from localization.geometry.camera import PAPER_IMAGE_SIZE
from localization.geometry.transforms import as_points, check_transform, invert, look_at, project

__all__ = ["landmark_context", "paper_prior", "perturb_attitude", "render_aruco_image", "sample_viewpoints"]


def perturb_attitude(
    cam_from_world: ArrayLike, position_offset_m: ArrayLike, attitude_offset_rad: ArrayLike
) -> NDArray[np.float64]:
    """Add offsets to a camera's position and (roll, pitch, yaw); return the new ``cam_from_world``.

    Attitude convention: :mod:`localization.geometry.attitude`.
    """
    T = check_transform("cam_from_world", cam_from_world)
    position, attitude = attitude_from_world_from_cam(invert(T))
    position = position + np.asarray(position_offset_m, dtype=np.float64).reshape(3)
    attitude = attitude + np.asarray(attitude_offset_rad, dtype=np.float64).reshape(3)
    return invert(world_from_cam_from_attitude(position, attitude))


def paper_prior(cam_from_world: ArrayLike, index: int) -> NDArray[np.float64]:
    """The paper's rough onboard pose: truth + 3 m per axis, 2 deg roll/pitch, 5 deg yaw.

    Signs alternate with ``index``: bit k of ``index`` flips position axis k (k = 0, 1, 2), bit 3
    flips roll, bit 0 pitch, bit 1 yaw, so consecutive images see every combination.
    """
    s = [1.0 if (index >> k) & 1 == 0 else -1.0 for k in range(4)]
    dpos = 3.0 * np.array([s[0], s[1], s[2]])
    datt = np.radians([2.0 * s[3], 2.0 * -s[0], 5.0 * -s[1]])
    return perturb_attitude(cam_from_world, dpos, datt)


def sample_viewpoints(
    rng: np.random.Generator,
    n: int,
    target: ArrayLike,
    distance_m: tuple[float, float] = (15.0, 35.0),
    height_m: tuple[float, float] = (10.0, 25.0),
    footprint: tuple[float, float, float, float] | None = None,
    side: int | None = None,
) -> list[NDArray[np.float64]]:
    """``n`` cameras around a building, aimed at ``target``; returns ``cam_from_world`` (4, 4) each.

    Viewpoint ``i`` belongs to side ``i % 4`` (0: -y, 1: +x, 2: +y, 3: -x; or ``side`` for all),
    as the paper's four UAVs, one per side. Its height is uniform in ``height_m``. Its horizontal
    distance, uniform in ``distance_m``, is measured from ``target`` (the building centre) along
    an azimuth uniform within the side's 90 degree sector when ``footprint`` is None -- the
    distribution that reproduces docs/design.md's Cramér-Rao figures (see :mod:`localization.metrics`);
    with ``footprint = (xmin, ymin, xmax, ymax)`` it is measured outwards from that side of the
    footprint instead, at a uniform position along the side.
    """
    target = np.asarray(target, dtype=np.float64).reshape(3)
    out = []
    for i in range(n):
        k = (i % 4) if side is None else int(side)
        d = rng.uniform(*distance_m)
        h = rng.uniform(*height_m)
        if footprint is None:
            azimuth = -0.5 * np.pi + 0.5 * np.pi * k + rng.uniform(-0.25 * np.pi, 0.25 * np.pi)
            x, y = target[0] + d * np.cos(azimuth), target[1] + d * np.sin(azimuth)
        else:
            xmin, ymin, xmax, ymax = footprint
            if k in (0, 2):
                x = rng.uniform(xmin, xmax)
                y = ymin - d if k == 0 else ymax + d
            else:
                y = rng.uniform(ymin, ymax)
                x = xmax + d if k == 1 else xmin - d
        out.append(look_at([x, y, h], target))
    return out


def landmark_context(
    K: ArrayLike,
    cam_from_world: ArrayLike,
    sets: dict[str, tuple[ArrayLike, ArrayLike]],
    image_size: tuple[int, int] = PAPER_IMAGE_SIZE,
) -> dict[str, Any]:
    """The detector context the environment provides, without occlusion (visible = in frame).

    Args:
        K: (3, 3) intrinsics.
        cam_from_world: (4, 4) true pose.
        sets: name -> (ids (M,), xyz (M, 3)).
        image_size: (W, H).
    """
    w, h = image_size
    out: dict[str, Any] = {"image_size": (w, h), "landmarks": {}}
    for name, (ids, xyz) in sets.items():
        X = as_points(f"{name} xyz", xyz, 3)
        uv, depth = project(K, cam_from_world, X)
        in_frame = (
            (depth > 0)
            & (uv[:, 0] >= -0.5)
            & (uv[:, 0] <= w - 0.5)
            & (uv[:, 1] >= -0.5)
            & (uv[:, 1] <= h - 0.5)
        )
        out["landmarks"][name] = {
            "ids": np.asarray(ids, dtype=np.int64).reshape(-1),
            "xyz": X,
            "uv": uv,
            "in_frame": in_frame,
            "visible": in_frame.copy(),
        }
    return out


def render_aruco_image(
    markers: Sequence[tuple[int, float, ArrayLike]],
    K: ArrayLike,
    cam_from_world: ArrayLike,
    image_size: tuple[int, int] = PAPER_IMAGE_SIZE,
    dictionary: int | None = None,
    quiet_zone: float = 0.25,
    background: int = 110,
    marker_pixels: int = 240,
) -> NDArray[np.uint8]:
    """A grey (H, W) uint8 image of flat ArUco markers seen by a pinhole camera.

    Each marker image (``cv2.aruco.generateImageMarker``, ``marker_pixels`` wide, with a white
    quiet zone of ``quiet_zone`` times the side) is warped into the view by the homography of
    its plane; markers behind the camera are skipped. A test double for rendered frames.

    Args:
        markers: ``(id, side_m, world_from_marker (4, 4))`` each.
        K: (3, 3) intrinsics.
        cam_from_world: (4, 4) camera pose.
        image_size: (W, H).
        dictionary: OpenCV predefined dictionary id (default ``DICT_4X4_50``).
        quiet_zone: white border width as a fraction of the side.
        background: grey level of the ground.
        marker_pixels: resolution of the generated marker (black square), px.
    """
    import cv2

    K = np.asarray(K, dtype=np.float64)
    w, h = image_size
    d = cv2.aruco.getPredefinedDictionary(
        cv2.aruco.DICT_4X4_50 if dictionary is None else dictionary
    )
    out = np.full((h, w), background, dtype=np.uint8)
    for mid, side, world_from_marker in markers:
        tile = cv2.aruco.generateImageMarker(d, int(mid), marker_pixels)
        pad = int(round(quiet_zone * marker_pixels))
        tile = cv2.copyMakeBorder(tile, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
        n = tile.shape[0]
        half = side * (0.5 + quiet_zone)
        plane = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]])
        Tm = np.asarray(world_from_marker, dtype=np.float64)
        world = plane @ Tm[:3, :3].T + Tm[:3, 3]
        uv, depth = project(K, cam_from_world, world)
        if np.any(depth <= 0.1):
            continue
        src = np.array([[-0.5, -0.5], [n - 0.5, -0.5], [n - 0.5, n - 0.5], [-0.5, n - 0.5]])
        H = cv2.getPerspectiveTransform(src.astype(np.float32), uv.astype(np.float32))
        warped = cv2.warpPerspective(tile, H, (w, h), flags=cv2.INTER_AREA)
        mask = cv2.warpPerspective(np.full_like(tile, 255), H, (w, h), flags=cv2.INTER_NEAREST)
        out[mask > 0] = warped[mask > 0]
    return out
