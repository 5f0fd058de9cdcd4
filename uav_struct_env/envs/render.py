"""The ``rgb_array`` frame: the agents' camera views side by side plus a top-down site map.

Pure drawing (numpy + OpenCV) on data the env already has; no pybullet here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from uav_struct_env.site import Site

__all__ = ["AGENT_COLORS", "MapView", "UavMarker", "compose_frame", "draw_site_map"]

#: RGB colour per agent index (cycled).
AGENT_COLORS = (
    (230, 60, 60),
    (60, 160, 230),
    (240, 190, 40),
    (150, 90, 220),
    (60, 200, 120),
    (240, 120, 200),
)


@dataclass(frozen=True)
class UavMarker:
    """What the map shows of one UAV.

    Its label, true position (3,), heading (rad), prior position (3,) or None, and whether it is
    still flying.
    """

    label: str
    position: NDArray[np.float64]
    yaw: float
    prior_position: NDArray[np.float64] | None
    alive: bool = True


@dataclass(frozen=True)
class MapView:
    """A square top-down window: ``center`` (2,) m, ``half_size`` m, ``pixels`` per side."""

    center: tuple[float, float]
    half_size: float
    pixels: int

    def to_px(self, xy: NDArray[np.float64]) -> tuple[int, int]:
        """Pixel of a project-frame point (x right, y up on the map)."""
        s = self.pixels / (2.0 * self.half_size)
        u = (float(xy[0]) - self.center[0] + self.half_size) * s
        v = (self.half_size - (float(xy[1]) - self.center[1])) * s
        lim = 4 * self.pixels
        return int(round(min(max(u, -lim), lim))), int(round(min(max(v, -lim), lim)))

    @property
    def scale(self) -> float:
        """Pixels per metre."""
        return self.pixels / (2.0 * self.half_size)


def _polygon(
    img: NDArray[np.uint8], view: MapView, outline: NDArray[np.float64], color, thickness: int
) -> None:
    pts = np.array([view.to_px(p) for p in outline], np.int32)
    if thickness < 0:
        cv2.fillPoly(img, [pts], color, cv2.LINE_AA)
    else:
        cv2.polylines(img, [pts], True, color, thickness, cv2.LINE_AA)


def draw_site_map(site: Site, uavs: Sequence[UavMarker], view: MapView) -> NDArray[np.uint8]:
    """Top-down map (pixels x pixels x 3, uint8 RGB) of the site and the UAVs.

    Shows the built elements (slabs with their openings, beams, walls), the cast columns
    (darker: exposed tops), the ArUco
    markers, a 10 m scale bar and, per UAV, its ground-truth position (filled disc) with a heading
    tick, its prior position (ring) joined to the truth by a thin line, and its label. A finished
    UAV is drawn with a cross.
    """
    n = view.pixels
    img = np.full((n, n, 3), (214, 210, 196), np.uint8)
    # 10 m grid
    step = 10.0
    x0 = math.floor((view.center[0] - view.half_size) / step) * step
    y0 = math.floor((view.center[1] - view.half_size) / step) * step
    k = 0
    while x0 + k * step <= view.center[0] + view.half_size:
        u, _ = view.to_px((x0 + k * step, 0.0))
        cv2.line(img, (u, 0), (u, n - 1), (200, 196, 182), 1)
        k += 1
    k = 0
    while y0 + k * step <= view.center[1] + view.half_size:
        _, v = view.to_px((0.0, y0 + k * step))
        cv2.line(img, (0, v), (n - 1, v), (200, 196, 182), 1)
        k += 1
    for element in sorted((e for e in site.built if e.kind != "column"), key=lambda e: e.z_top):
        _polygon(img, view, element.outline, (175, 170, 160), -1)
        _polygon(img, view, element.outline, (90, 90, 90), 1)
        for hole in getattr(element, "holes", ()):
            _polygon(img, view, hole.outline, (214, 210, 196), -1)
            _polygon(img, view, hole.outline, (90, 90, 90), 1)
    exposed = {c.guid for c in site.exposed_columns}
    for col in sorted(site.columns, key=lambda c: c.guid in exposed):
        _polygon(img, view, col.outline, (40, 40, 40) if col.guid in exposed else (110, 110, 110), -1)
    for m in site.markers:
        c = m.corners_world[:, :2]
        pts = np.array([view.to_px(p) for p in c], np.int32)
        cv2.fillPoly(img, [pts], (20, 20, 20))
    # scale bar
    bar = int(round(10.0 * view.scale))
    cv2.line(img, (8, n - 10), (8 + bar, n - 10), (0, 0, 0), 2)
    cv2.putText(
        img, "10 m", (10, n - 16), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA
    )
    r = max(3, int(round(0.012 * n)))
    for i, uav in enumerate(uavs):
        color = AGENT_COLORS[i % len(AGENT_COLORS)]
        p = view.to_px(uav.position[:2])
        if uav.prior_position is not None:
            q = view.to_px(uav.prior_position[:2])
            cv2.line(img, p, q, color, 1, cv2.LINE_AA)
            cv2.circle(img, q, r, color, 1, cv2.LINE_AA)
        tip = (
            p[0] + int(round(3 * r * math.cos(uav.yaw))),
            p[1] - int(round(3 * r * math.sin(uav.yaw))),
        )
        cv2.line(img, p, tip, (0, 0, 0), 2, cv2.LINE_AA)
        cv2.circle(img, p, r, color, -1, cv2.LINE_AA)
        if not uav.alive:
            cv2.line(img, (p[0] - r, p[1] - r), (p[0] + r, p[1] + r), (0, 0, 0), 2)
            cv2.line(img, (p[0] - r, p[1] + r), (p[0] + r, p[1] - r), (0, 0, 0), 2)
        cv2.putText(
            img,
            uav.label,
            (p[0] + r + 2, p[1] - r),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.35,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    return img


def compose_frame(
    views: Mapping[str, NDArray[np.uint8] | None],
    site_map: NDArray[np.uint8],
    view_height: int,
    aspect: float,
) -> NDArray[np.uint8]:
    """Tile the agents' views (two per row, each ``view_height`` px high, labelled) left of the map.

    ``views`` maps agent labels to images (None: a black tile). The map is resized to the height
    of the view grid. Returns one uint8 (H, W, 3) RGB frame.
    """
    tile_w = max(1, int(round(view_height * aspect)))
    labels = list(views)
    cols = 1 if len(labels) == 1 else 2
    rows = max(1, math.ceil(len(labels) / cols))
    grid = np.zeros((rows * view_height, cols * tile_w, 3), np.uint8)
    for k, label in enumerate(labels):
        r, c = divmod(k, cols)
        img = views[label]
        tile = np.zeros((view_height, tile_w, 3), np.uint8)
        if img is not None:
            interp = cv2.INTER_AREA if img.shape[0] > view_height else cv2.INTER_NEAREST
            tile = cv2.resize(img, (tile_w, view_height), interpolation=interp)
        color = AGENT_COLORS[k % len(AGENT_COLORS)]
        cv2.rectangle(tile, (0, 0), (tile_w - 1, view_height - 1), color, 2)
        cv2.putText(tile, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, color, 1, cv2.LINE_AA)
        grid[r * view_height : (r + 1) * view_height, c * tile_w : (c + 1) * tile_w] = tile
    h = grid.shape[0]
    side = cv2.resize(
        site_map,
        (h, h),
        interpolation=cv2.INTER_AREA if site_map.shape[0] > h else cv2.INTER_LINEAR,
    )
    return np.ascontiguousarray(np.concatenate([grid, side], axis=1))
