"""How closely the batched renderer agrees with pybullet's: random views, the same world, both renders.

:func:`random_views` draws camera poses around a world's site (distances, heights and aim
points like the env's viewpoints, some looking past the building); :func:`compare` renders them
with pybullet (``SiteWorld.render``) and with :func:`~uav_struct_env.sim.batch.render_batch`
and counts the pixels whose body id agrees, the landmark-views whose visibility
(``SiteWorld.landmark_truth`` on each render's depth) agrees, and the mean absolute RGB difference
on pixels showing the same body. ``benchmarks/batch_render.py`` runs thousands of views;
``tests/sim/test_batch_render.py`` a few dozen.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.geometry.transforms import invert
from uav_struct_env.sim.batch import BatchScene, BatchView, render_batch
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.uav import UavState

__all__ = ["Agreement", "compare", "random_views"]


@dataclass(frozen=True)
class Agreement:
    """Counts over a set of views (add two with ``+``).

    Attributes:
        views: views compared.
        pixels: pixels compared; ``pixels_equal``: of them, same body id (or sky) in both.
        landmark_views: (landmark, view) pairs in the image in either render; ``landmarks_equal``: of
            them, the same ``visible`` in both; ``landmarks_visible``: visible in pybullet's.
        rgb_abs_diff_sum: sum over views of the mean absolute RGB difference (0-255) on pixels
            that show the same body.
    """

    views: int = 0
    pixels: int = 0
    pixels_equal: int = 0
    landmark_views: int = 0
    landmarks_equal: int = 0
    landmarks_visible: int = 0
    rgb_abs_diff_sum: float = 0.0

    def __add__(self, other: Agreement) -> Agreement:
        return Agreement(*(a + b for a, b in zip(self._values(), other._values(), strict=True)))

    def _values(self) -> tuple:
        return (self.views, self.pixels, self.pixels_equal, self.landmark_views, self.landmarks_equal,
                self.landmarks_visible, self.rgb_abs_diff_sum)

    @property
    def pixel_agreement(self) -> float:
        """Share of pixels with the same body id."""
        return self.pixels_equal / max(self.pixels, 1)

    @property
    def landmark_agreement(self) -> float:
        """Share of landmark-views with the same visibility."""
        return self.landmarks_equal / max(self.landmark_views, 1)

    @property
    def rgb_mean_abs_diff(self) -> float:
        """Mean absolute RGB difference per view (0-255) where both show the same body."""
        return self.rgb_abs_diff_sum / max(self.views, 1)


def random_views(world, rng: np.random.Generator, n: int) -> list[NDArray[np.float64]]:
    """``n`` random ``cam_from_world`` (4, 4) around ``world``'s built elements.

    Camera 1-3 building radii from the centre of the elements' bounding box (and at least 6 m
    out), 2-35 m up, aimed at a random point of the box, pitch and heading jittered by up to
    15 and 25 degrees (some views miss the building).
    """
    boxes = np.array([e.mesh.bounds for e in world.elements if e.kind not in ("ground", "marker")])
    lo, hi = boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)
    centre, radius = (lo + hi) / 2, max(float(np.linalg.norm(hi[:2] - lo[:2])) / 2, 3.0)
    out = []
    for _ in range(n):
        heading = rng.uniform(0, 2 * math.pi)
        distance = max(rng.uniform(1.0, 3.0) * radius, 6.0)
        xyz = np.array([centre[0] + distance * math.cos(heading), centre[1] + distance * math.sin(heading),
                        rng.uniform(2.0, 35.0)])
        aim = rng.uniform(lo, hi) - xyz
        yaw = math.atan2(aim[1], aim[0]) + math.radians(rng.uniform(-25, 25))
        pitch = math.atan2(-aim[2], math.hypot(aim[0], aim[1])) + math.radians(rng.uniform(-15, 15))
        state = UavState.make(xyz, yaw, float(np.clip(pitch, -0.3, 1.5)))
        out.append(invert(state.world_from_cam))
    return out


def compare(
    world, scene: BatchScene, views: Sequence[NDArray[np.float64]], camera: Camera,
    landmark_sets: Sequence[str] = ("slab_corners", "opening_corners", "column_tops", "aruco"),
) -> Agreement:
    """Render ``views`` with pybullet and in one batch; count the agreement (:class:`Agreement`).

    Landmark sets the site lacks (no openings at this stage, no markers) are skipped.
    """
    batch = render_batch([BatchView(scene, T, camera) for T in views])
    sets = [s for s in landmark_sets if len(world.site.landmarks(s).xyz)]
    total = Agreement()
    for T, ours in zip(views, batch, strict=True):
        ref = world.render(T, camera, depth=True, segmentation=True)
        same = ours.segmentation == ref.segmentation
        diff = np.abs(ours.rgb.astype(np.int16) - ref.rgb.astype(np.int16))[same]
        n_lm = eq = vis = 0
        for name in sets:
            a = world.landmark_truth(name, T, camera, ref)
            b = world.landmark_truth(name, T, camera, ours)
            framed = a["in_frame"] | b["in_frame"]
            n_lm += int(framed.sum())
            eq += int((a["visible"] == b["visible"])[framed].sum())
            vis += int(a["visible"][framed].sum())
        total = total + Agreement(1, same.size, int(same.sum()), n_lm, eq, vis,
                                  float(diff.mean()) if diff.size else 0.0)
    return total
