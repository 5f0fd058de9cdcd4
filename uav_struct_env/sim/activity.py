"""The activity layer in a SiteWorld: its boxes as pybullet bodies, workers moved each step.

:class:`ActivityBodies` adds one visual box per :class:`~uav_struct_env.site.activity.Box` of a
:class:`~uav_struct_env.site.activity.SiteActivity` with ``SiteWorld.add_body`` -- so the renderer
draws them and the ray-cast visibility (``SiteWorld.landmark_truth_raycast``,
``SiteWorld.first_hits``) hits them -- and moves the workers to their poses at a time with the
fast ``SiteWorld.place_body``. :meth:`ActivityBodies.remove` takes every body out again (the
environment lays out a new site activity at each reset).
"""

from __future__ import annotations

import numpy as np

from uav_struct_env.site.activity import WORKER_HALF_EXTENTS, SiteActivity

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

    def remove(self) -> None:
        """Remove every body of this layout from the world (idempotent; a closed world is skipped)."""
        if not self._world.closed:
            for body in [*self.static_ids.values(), *self.worker_ids.values()]:
                self._world.remove_body(body)
        self.static_ids, self.worker_ids = {}, {}
