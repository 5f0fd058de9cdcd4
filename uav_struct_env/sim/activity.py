"""The activity layer in a SiteWorld: its boxes as pybullet bodies, workers moved each step.

:class:`ActivityBodies` adds one visual box per :class:`~uav_struct_env.site.activity.Box` of a
:class:`~uav_struct_env.site.activity.SiteActivity` with ``SiteWorld.add_body`` -- so the renderer
draws them and the ray-cast visibility (``SiteWorld.landmark_truth_raycast``,
``SiteWorld.first_hits``) hits them -- and moves the workers to their poses at a time with the
fast ``SiteWorld.place_body``. :meth:`ActivityBodies.remove` takes every body out again (the
environment lays out a new site activity at each reset).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.geometry.transforms import check_transform
from localization.geometry.transforms import project as pinhole_project
from uav_struct_env.sim.camera import Camera
from uav_struct_env.site.activity import (
    WORKER_HALF_EXTENTS,
    WORKER_SAMPLE_HEIGHTS,
    SiteActivity,
    worker_sample_points,
)

#: Slack (m) before a surface in front of a worker's sample point hides it.
_VISIBILITY_SLACK = 0.02

__all__ = ["ActivityBodies"]


class ActivityBodies:
    """The bodies of one activity layout in a world.

    Args:
        world: the :class:`~uav_struct_env.sim.world.SiteWorld` to draw in.
        layout: the activity layout.
        t: time (s) the workers start at.

    Attributes:
        static_ids: body id of every static box, by box name.
        worker_ids: body id of every worker, by worker name.
    """

    def __init__(self, world, layout: SiteActivity, t: float = 0.0) -> None:
        self._world = world
        self.layout = layout
        self.static_ids = {
            b.name: world.add_body(tuple(b.half_extents), b.rgba, b.world_from_box) for b in layout.static
        }
        self.worker_ids = {w.name: world.add_body(WORKER_HALF_EXTENTS, w.rgba) for w in layout.workers}
        self.update(t)

    def update(self, t: float) -> None:
        """Move every worker to its pose at time ``t`` (s)."""
        half_height = WORKER_HALF_EXTENTS[2]
        for w in self.layout.workers:
            (x, y, z), heading = w.at(t)
            self._world.place_body(self.worker_ids[w.name], (x, y, z + half_height), heading)

    def worker_body_ids(self) -> np.ndarray:
        """(N,) body ids of the workers, in layout order."""
        return np.array([self.worker_ids[w.name] for w in self.layout.workers], dtype=np.int64)

    def worker_visibility(
        self,
        t: float,
        cam_from_world: ArrayLike,
        camera: Camera,
        project: Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.bool_]]] | None = None,
    ) -> dict[str, float]:
        """Per worker, the fraction of its sample points a camera sees at time ``t`` (ray casting).

        The points are :func:`~uav_struct_env.site.activity.worker_sample_points` (five along the
        worker's vertical axis). One counts when it projects inside the image in front of the
        near plane and the ray from the camera centre to it meets nothing first but the worker's
        own body (within 2 cm): the building, the other activity bodies and every other body in
        the world (airframes: hide the camera's own first) hide it. The workers are moved to ``t``.
        ``project`` maps world points (N, 3) to ``(uv (N, 2), usable (N,))`` in the delivered
        image of a real camera (``sim.lens.LensView.project``: distortion, rolling shutter); the
        default is ``camera``'s pinhole in front of its near plane.
        """
        T = check_transform("cam_from_world", cam_from_world)
        self.update(t)
        workers = self.layout.workers
        if not workers:
            return {}
        per = len(WORKER_SAMPLE_HEIGHTS)
        samples = np.concatenate([worker_sample_points(w.points_at(t)) for w in workers])  # (5N, 3)
        if project is None:
            uv, depth = pinhole_project(camera.K, T, samples)
            usable = depth > camera.near
        else:
            uv, usable = project(samples)
        w, h = camera.width, camera.height
        with np.errstate(invalid="ignore"):
            in_image = (usable & (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5)
                        & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5))
        origin = -T[:3, :3].T @ T[:3, 3]
        rays = samples - origin
        skip = np.repeat(self.worker_body_ids(), per)
        hit = self._world.first_hits(origin, rays, 0.0, skip_bodies=skip)
        clear = hit >= 1.0 - _VISIBILITY_SLACK / np.linalg.norm(rays, axis=1)
        seen = (in_image & clear).reshape(len(workers), per).mean(axis=1)
        return {wk.name: float(v) for wk, v in zip(workers, seen, strict=True)}

    def remove(self) -> None:
        """Remove every body of this layout from the world (idempotent; a closed world is skipped)."""
        if not self._world.closed:
            for body in [*self.static_ids.values(), *self.worker_ids.values()]:
                self._world.remove_body(body)
        self.static_ids, self.worker_ids = {}, {}
