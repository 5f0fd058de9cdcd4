"""Load a site's textured meshes into a pybullet client, once.

Each :class:`~uav_struct_env.site.mesh.SiteElement` is written as OBJ + MTL + PNG into a
directory owned by the caller and loaded as a static visual-only body
(``createVisualShape(GEOM_MESH, fileName=...)``, no collision shape). The texture reaches both
renderers through the MTL's ``map_Kd``: passing vertices directly to ``createVisualShape`` works
with TinyRenderer but crashes the EGL plugin, which only loads meshes from files.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pybullet as p

from uav_struct_env.site.mesh import SiteElement, write_obj

__all__ = ["LoadedScene", "load_elements"]


@dataclass(frozen=True)
class LoadedScene:
    """Body ids of the loaded elements, by element name and by kind."""

    body_ids: dict[str, int]
    kinds: dict[str, str]

    def bodies_of_kind(self, kind: str) -> list[int]:
        """Body ids of every element of ``kind`` ("column", "slab", "ground", "marker")."""
        return [b for name, b in self.body_ids.items() if self.kinds[name] == kind]


def load_elements(
    client_id: int, elements: Sequence[SiteElement], directory: str | Path
) -> LoadedScene:
    """Write ``elements`` to ``directory`` and create one static body per element.

    Returns:
        The body id of every element.
    """
    directory = Path(directory)
    body_ids: dict[str, int] = {}
    kinds: dict[str, str] = {}
    for k, element in enumerate(elements):
        if element.name in body_ids:
            raise ValueError(f"element names must be unique, {element.name!r} appears twice")
        path = write_obj(element, directory, f"e{k:03d}_{element.kind}")
        shape = p.createVisualShape(
            p.GEOM_MESH, fileName=str(path), rgbaColor=[1, 1, 1, 1], physicsClientId=client_id
        )
        if shape < 0:
            raise RuntimeError(f"pybullet could not load the mesh of {element.name!r} from {path}")
        body = p.createMultiBody(
            baseMass=0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=shape,
            physicsClientId=client_id,
        )
        body_ids[element.name] = body
        kinds[element.name] = element.kind
    return LoadedScene(body_ids, kinds)
