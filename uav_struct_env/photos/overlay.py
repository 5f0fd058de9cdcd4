"""Pictures of a photo localization: the per-photo overlay and the flight summary.

:func:`plot_overlay`: the photo, turned upright by its EXIF orientation tag, with the BIM's
structural edges (every built element's outline at its top and bottom, and its vertical corner
edges) projected through the camera (distortion included) at the prior (orange, dashed) and at
the estimate (green), the model landmarks at the estimate (green +), the detections (red
circles) labelled with the landmark id each was identified as, and a title with the status, the
position and rotation standard deviations or the failure reason.

:func:`plot_flight_summary`: the building's plan with every camera's prior (grey x), its
estimate (dot) joined to the prior, and the estimate's 2-sigma horizontal ellipse (magnified by
the factor the legend states where the ellipses would be too small to see).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localization.geometry.distortion import distort_points
from localization.geometry.transforms import project
from uav_struct_env.outputs import save_figure
from uav_struct_env.photos.localize import PhotoPose
from uav_struct_env.photos.orientation import (
    ORIENTATION_TURNS,
    turn_camera,
    turn_image,
    turn_points,
    turn_pose,
)

__all__ = ["element_edges", "plot_flight_summary", "plot_overlay"]

#: Largest side of an overlay image, px (the photo is shown scaled to it).
OVERLAY_MAX_SIDE = 1600


def element_edges(site: Any) -> NDArray[np.float64]:
    """(E, 2, 3) 3D segments of every built element: outline at top and bottom, vertical corners."""
    segs = []
    for e in site.built:
        ring = np.asarray(e.outline, dtype=np.float64)
        nxt = np.roll(ring, -1, axis=0)
        for z in (e.z_bottom, e.z_top):
            segs += [((a[0], a[1], z), (b[0], b[1], z)) for a, b in zip(ring, nxt, strict=True)]
        if e.kind == "column":
            segs += [((a[0], a[1], e.z_bottom), (a[0], a[1], e.z_top)) for a in ring]
    return np.asarray(segs, dtype=np.float64).reshape(-1, 2, 3)


def _project_segments(pose_cw: NDArray, K: NDArray, dist: NDArray, segs: NDArray,
                      size: tuple[int, int]) -> NDArray[np.float64]:
    """(S, 2, 2) pixel segments of the 3D segments with both ends in front and near the image."""
    uv, depth = project(K, pose_cw, segs.reshape(-1, 3))
    keep = (depth.reshape(-1, 2) > 0.1).all(axis=1)
    uv = uv.reshape(-1, 2, 2)[keep]
    if len(uv) == 0:
        return uv
    uv = distort_points(uv.reshape(-1, 2), K, dist).reshape(-1, 2, 2)
    w, h = size
    near = ((uv[..., 0] > -w) & (uv[..., 0] < 2 * w) & (uv[..., 1] > -h) & (uv[..., 1] < 2 * h)).all(axis=1)
    return uv[near]


def _title(pose: PhotoPose) -> str:
    if not pose.success:
        return f"{pose.photo.name}: NOT localized -- {pose.failure_reason}"
    std = pose.std
    return (f"{pose.photo.name}: localized, {pose.n_inliers} landmarks, RMSE "
            f"{pose.reprojection_rmse_px:.2f} px; std x/y/z {std[0]:.3f}/{std[1]:.3f}/{std[2]:.3f} m, "
            "rotation "
            f"{math.degrees(float(np.linalg.norm(std[3:]))):.3f} deg")


def plot_overlay(pose: PhotoPose, rgb: NDArray[np.uint8], site: Any, landmarks_xyz: NDArray[np.float64],
                 path: str | Path, settings: str = "") -> Path:
    """Write the overlay PNG of one photo (module docstring); returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # Shown as a viewer shows the photo: turned upright by its EXIF orientation tag.
    turns = ORIENTATION_TURNS.get(pose.orientation, 0)
    rgb = turn_image(rgb, turns)
    K, dist, _ = turn_camera(pose.camera.K, pose.camera.distortion, pose.camera.image_size, turns)
    prior_cw, est_cw = turn_pose(pose.prior.cam_from_world, turns), turn_pose(pose.cam_from_world, turns)
    h, w = rgb.shape[:2]
    scale = min(1.0, OVERLAY_MAX_SIDE / max(w, h))
    fig, ax = plt.subplots(figsize=(w * scale / 100, h * scale / 100 + 0.6), dpi=100)
    ax.imshow(rgb, extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    segs = element_edges(site)
    for cw, colour, style, label in ((prior_cw, "orange", "--", "BIM at prior"),
                                     (est_cw, "lime", "-", "BIM at estimate")):
        if cw is est_cw and not pose.success:
            continue
        for k, s in enumerate(_project_segments(cw, K, dist, segs, (w, h))):
            ax.plot(s[:, 0], s[:, 1], style, color=colour, lw=0.8, label=label if k == 0 else None)
    if pose.success and len(landmarks_xyz):
        uv, depth = project(K, est_cw, landmarks_xyz)
        uv = distort_points(uv[depth > 0], K, dist)
        ax.plot(uv[:, 0], uv[:, 1], "+", color="lime", ms=8, mew=1.5, label="landmarks at estimate")
    det = turn_points(pose.detections_uv, pose.camera.image_size, turns)
    if len(det):
        ax.plot(det[:, 0], det[:, 1], "o", mfc="none", mec="red", ms=9, mew=1.2, label="detections")
        for (u, v), i in zip(det, pose.identities, strict=True):
            if i >= 0:
                ax.annotate(str(int(i)), (u, v), xytext=(5, -5), textcoords="offset points", color="yellow",
                            fontsize=7)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_axis_off()
    ax.legend(loc="lower right", fontsize=7, framealpha=0.7)
    ax.set_title(_title(pose), fontsize=8)
    if settings:
        fig.text(0.01, 0.005, settings, fontsize=5, va="bottom")
    out = save_figure(fig, path, dpi=100, settings=settings or None)
    plt.close(fig)
    return out


def _ellipse_axes(cov_xy: NDArray[np.float64]) -> tuple[float, float, float]:
    """(width, height, angle deg) of the 2-sigma ellipse of a 2x2 covariance."""
    vals, vecs = np.linalg.eigh(cov_xy)
    vals = np.maximum(vals, 0.0)
    angle = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))
    return 4.0 * math.sqrt(vals[1]), 4.0 * math.sqrt(vals[0]), angle


def plot_flight_summary(poses: Sequence[PhotoPose], site: Any, path: str | Path, settings: str = "") -> Path:
    """Write the flight summary PNG (module docstring); returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse, Polygon

    fig, ax = plt.subplots(figsize=(8, 7))
    for e in site.built:
        ax.add_patch(Polygon(np.asarray(e.outline), closed=True, fc="0.85", ec="0.4", lw=0.6))
    ok = [p for p in poses if p.success]
    stds = [float(np.sqrt(max(p.covariance[0, 0], p.covariance[1, 1]))) for p in ok]
    span = max(np.ptp(np.array([p.position[:2] for p in poses] + [[0.0, 0.0]]), axis=0).max(), 1.0)
    magnify = max(1.0, 10 ** math.floor(math.log10(0.03 * span / max(np.median(stds), 1e-6)))) if ok else 1.0
    for p in poses:
        prior = p.prior.position
        ax.plot(prior[0], prior[1], "x", color="0.5", ms=6)
        if not p.success:
            ax.annotate(f"{p.photo.name}: failed", prior[:2], fontsize=6, color="red")
            continue
        c = p.position
        ax.plot([prior[0], c[0]], [prior[1], c[1]], "-", color="0.6", lw=0.6)
        ax.plot(c[0], c[1], "o", color="tab:blue", ms=4)
        wd, ht, ang = _ellipse_axes(p.covariance[:2, :2])
        ax.add_patch(Ellipse((c[0], c[1]), wd * magnify, ht * magnify, angle=ang, fc="none", ec="tab:blue"))
        ax.annotate(p.photo.stem, c[:2], xytext=(4, 4), textcoords="offset points", fontsize=6)
    ax.plot([], [], "x", color="0.5", label="prior (photo metadata)")
    ax.plot([], [], "o", color="tab:blue", label=f"estimate, 2-sigma ellipse x{magnify:g}")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("project x [m]")
    ax.set_ylabel("project y [m]")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"{len(ok)} of {len(poses)} photos localized", fontsize=10)
    if settings:
        fig.text(0.01, 0.005, settings, fontsize=5, va="bottom", wrap=True)
    out = save_figure(fig, path, dpi=120, settings=settings or None)
    plt.close(fig)
    return out
