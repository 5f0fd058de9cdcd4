"""UAV airframes drawn in a SiteWorld: each camera sees the other UAVs, never its own airframe.

Each airframe is a visual-only box made with ``SiteWorld.add_body`` (DJI Mavic 2 Pro unfolded,
322 x 242 x 84 mm), level, turned to the heading, its centre 0.1 m above the camera (the gimbal
hangs under the body). Poses are set with ``SiteWorld.place_body``, the unvalidated yaw-only path:
``SiteWorld.move_body`` validates a general 4x4 pose, and a step moves the airframes 12 times.
"""

from __future__ import annotations

from collections.abc import Sequence

from uav_struct_env.sim.uav import UavState

__all__ = ["UAV_HALF_EXTENTS", "UAV_RGBA", "Airframes"]

#: Half extents (m) of the box drawn for a UAV: DJI Mavic 2 Pro unfolded, 322 x 242 x 84 mm.
UAV_HALF_EXTENTS = (0.161, 0.121, 0.042)
UAV_RGBA = (0.18, 0.18, 0.2, 1.0)
_HIDDEN_POSITION = (0.0, 0.0, -500.0)  # far below the ground
_BODY_ABOVE_CAMERA = 0.1


class Airframes:
    """One airframe body per name in a world; all start hidden.

    Args:
        world: the :class:`~uav_struct_env.sim.world.SiteWorld` to draw in.
        names: one airframe per name (agent).
    """

    def __init__(self, world, names: Sequence[str]) -> None:
        hidden = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, _HIDDEN_POSITION[2]], [0, 0, 0, 1.0]]
        self._world = world
        self.bodies = {n: world.add_body(UAV_HALF_EXTENTS, UAV_RGBA, hidden) for n in names}

    def set(self, name: str, state: UavState | None) -> None:
        """Place airframe ``name`` at ``state`` (None: hide it)."""
        body = self.bodies[name]
        if state is None:
            self._world.place_body(body, _HIDDEN_POSITION, 0.0)
            return
        x, y, z = state.position
        self._world.place_body(body, (x, y, z + _BODY_ABOVE_CAMERA), state.yaw)

    def place(self, states: dict[str, UavState | None]) -> None:
        """Place every airframe: at its state, or hidden where the state is None or missing."""
        for name in self.bodies:
            self.set(name, states.get(name))
