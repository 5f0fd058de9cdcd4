"""The study's figures: a Fig. 2-style panel, error CDFs and a top-down map of the viewpoints."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from uav_struct_env.outputs import save_figure
from uav_struct_env.site import Site
from uav_struct_env.study.protocol import METHODS
from uav_struct_env.study.run import ImageResult, Overlay
from uav_struct_env.study.tracking import ViewpointTracking

__all__ = ["draw_overlay", "plot_error_cdfs", "plot_fig2", "plot_viewpoint_map", "plot_worker_tracking"]

# BGR-free: images are RGB, so colours are RGB tuples.
_GREEN, _RED, _YELLOW, _CYAN, _MAGENTA = (
    (40, 220, 40),
    (235, 40, 40),
    (255, 220, 0),
    (0, 220, 255),
    (255, 0, 255),
)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _stamp(fig, settings: str | None) -> float:
    """Write the settings line along the figure's bottom edge; the height (figure fraction) it takes."""
    if not settings:
        return 0.0
    width = max(60, int(fig.get_figwidth() * 18))  # characters per line at 6 pt
    text = "\n".join(textwrap.wrap(settings, width))
    fig.text(0.005, 0.005, text, ha="left", va="bottom", fontsize=6, color="0.3")
    return (text.count("\n") + 1) * 8.5 / 72 / fig.get_figheight()


def draw_overlay(ov: Overlay) -> np.ndarray:
    """Draw one image's detections, associations and final-pose reprojections.

    Circles are detections, lines join each to the prior projection of its assigned landmark
    (green correct, red wrong), cyan crosses are the final-pose reprojections.
    """
    img = np.ascontiguousarray(ov.image.copy())
    h, w = img.shape[:2]
    s = max(1, round(w / 640))

    def pt(uv):
        return int(round(uv[0])), int(round(uv[1]))

    def inside(uv):
        return np.all(np.isfinite(uv)) and -w < uv[0] < 2 * w and -h < uv[1] < 2 * h

    for uv in ov.model_uv_prior:
        if inside(uv):
            cv2.drawMarker(img, pt(uv), _YELLOW, cv2.MARKER_DIAMOND, 10 * s, s)
    for i, uv in enumerate(ov.detections_uv):
        j = ov.assignment[i]
        if j >= 0 and inside(ov.model_uv_prior[j]):
            cv2.line(
                img,
                pt(uv),
                pt(ov.model_uv_prior[j]),
                _GREEN if ov.correct[i] else _RED,
                s,
                cv2.LINE_AA,
            )
        cv2.circle(img, pt(uv), 7 * s, _MAGENTA if j < 0 else _GREEN, s, cv2.LINE_AA)
    if ov.success:
        for uv in ov.model_uv_final:
            if inside(uv):
                cv2.drawMarker(img, pt(uv), _CYAN, cv2.MARKER_CROSS, 14 * s, s)
    return img


def plot_fig2(overlays: Sequence[Overlay], path: Path, settings: str | None = None) -> None:
    """Fig. 2: one image per landmark type with detections, associations and reprojections.

    ``settings`` (the study's settings line) is printed along the bottom, as in every figure here.
    """
    plt = _pyplot()
    order = [m.key for m in METHODS]
    chosen = sorted(
        [o for o in overlays if o.method in ("slab_corners", "opening_corners", "column_tops")],
        key=lambda o: order.index(o.method),
    )
    if not chosen:
        return
    fig, axes = plt.subplots(1, len(chosen), figsize=(6 * len(chosen), 3.9 + 0.3 * bool(settings)),
                             squeeze=False)
    for ax, ov in zip(axes[0], chosen, strict=True):
        ax.imshow(draw_overlay(ov))
        label = next(m.label for m in METHODS if m.key == ov.method)
        ax.set_title(f"{label} — UAV {ov.uav}, viewpoint {ov.viewpoint}", fontsize=10)
        ax.axis("off")
    foot = _stamp(fig, settings)
    fig.text(
        0.5,
        0.01 + foot,
        "circles: detections · yellow diamonds: BIM landmarks projected with the onboard prior · "
        "lines: association (green correct, red wrong) · cyan crosses: final-pose reprojection",
        ha="center",
        fontsize=8,
    )
    fig.tight_layout(rect=(0, 0.04 + foot, 1, 1))
    save_figure(fig, path, dpi=110, settings=settings)
    plt.close(fig)


def plot_error_cdfs(rows: Sequence[ImageResult], path: Path, settings: str | None = None) -> None:
    """Empirical CDFs of translation and rotation error per method (failures never reach 1)."""
    plt = _pyplot()
    fig, (ax_t, ax_r) = plt.subplots(1, 2, figsize=(11, 4))
    for m in METHODS:
        mine = [r for r in rows if r.method == m.key]
        if not mine:
            continue
        n = len(mine)
        for ax, attr in ((ax_t, "translation_error_m"), (ax_r, "rotation_error_deg")):
            v = np.sort([getattr(r, attr) for r in mine if r.success])
            if v.size:
                ax.step(
                    np.concatenate([[v[0] * 0.5], v]),
                    np.arange(v.size + 1) / n,
                    where="post",
                    label=f"{m.label} ({v.size}/{n})",
                )
    for ax, xlabel in ((ax_t, "translation error (m)"), (ax_r, "rotation error (°)")):
        ax.set_xscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("fraction of images")
        ax.set_ylim(0, 1.02)
        ax.grid(True, which="both", alpha=0.3)
    ax_t.legend(fontsize=7, loc="lower right")
    fig.tight_layout(rect=(0, _stamp(fig, settings), 1, 1))
    save_figure(fig, path, dpi=110, settings=settings)
    plt.close(fig)


def plot_viewpoint_map(
    site: Site, rows: Sequence[ImageResult], method: str, path: Path, settings: str | None = None
) -> None:
    """Top-down map: the building, markers and, per image, ground truth, prior and estimate."""
    plt = _pyplot()
    mine = [r for r in rows if r.method == method]
    fig, ax = plt.subplots(figsize=(7, 7))
    for slab in site.floor:
        ax.add_patch(plt.Polygon(slab.outline, closed=True, fill=False, lw=1.5, color="k"))
        for hole in slab.holes:
            ax.add_patch(plt.Polygon(hole.outline, closed=True, fill=False, lw=1.0, color="0.4"))
    for c in site.columns:
        ax.add_patch(plt.Polygon(c.outline, closed=True, color="0.3"))
    for mk in site.markers:
        h = mk.side / 2
        ax.add_patch(plt.Rectangle((mk.center[0] - h, mk.center[1] - h), 2 * h, 2 * h, color="tab:purple"))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for r in mine:
        col = colours[r.uav % len(colours)]
        ax.plot(r.gt_x, r.gt_y, "o", color=col, ms=5)
        ax.plot([r.gt_x, r.prior_x], [r.gt_y, r.prior_y], ":", color=col, lw=0.8)
        ax.plot(r.prior_x, r.prior_y, "x", color=col, ms=5)
        if r.success:
            ax.plot(r.est_x, r.est_y, "+", color="k", ms=7)
    ax.plot([], [], "o", color="0.4", label="ground truth")
    ax.plot([], [], "x", color="0.4", label="onboard prior")
    ax.plot([], [], "+", color="k", label=f"estimate ({method})")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("Viewpoints, one colour per UAV")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout(rect=(0, _stamp(fig, settings), 1, 1))
    save_figure(fig, path, dpi=110, settings=settings)
    plt.close(fig)


def plot_worker_tracking(
    viewpoints: Sequence[ViewpointTracking], path: Path, settings: str | None = None
) -> None:
    """Empirical CDFs of 3D worker error with true, estimated and prior camera poses.

    Each curve counts observations per worker present: a worker not triangulated keeps it below 1,
    a worker split in two by a failed association (the prior's metre errors) can lift it above.
    """
    plt = _pyplot()
    present = max(1, sum(v.n_workers for v in viewpoints))
    observations = [o for v in viewpoints for o in v.observations]
    fig, ax = plt.subplots(figsize=(10, 4))
    top = 1.0
    for label, pick in (
        ("true poses (floor)", lambda o: o.source == "truth"),
        ("estimated poses", lambda o: o.source == "estimated" and o.tracking),
        ("onboard prior poses", lambda o: o.source == "prior"),
    ):
        v = np.sort([o.error_m for o in observations if pick(o)])
        if v.size:
            top = max(top, v.size / present)
            stats = f"median {np.median(v):.3f} m, P95 {np.percentile(v, 95):.3f} m, n = {v.size}"
            ax.step(np.concatenate([[v[0] * 0.5], v]), np.arange(v.size + 1) / present, where="post",
                    label=f"{label}\n{stats}")
    ax.axvline(0.15, color="0.5", ls="--", lw=1, label="target P95 0.15 m")
    ax.set_xscale("log")
    ax.set_xlabel("3D worker error, the larger of feet and head top (m)")
    ax.set_ylabel(f"observations / workers present ({present})")
    ax.set_ylim(0, top + 0.02)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout(rect=(0, _stamp(fig, settings), 1, 1))
    save_figure(fig, path, dpi=110, settings=settings)
    plt.close(fig)
