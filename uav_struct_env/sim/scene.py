"""Load a site's textured meshes into a pybullet client, once.

Each :class:`~uav_struct_env.site.mesh.SiteElement` is written as OBJ + MTL + PNG into a
directory owned by the caller and loaded as a static visual-only body
(``createVisualShape(GEOM_MESH, fileName=...)``, no collision shape). The texture reaches both
renderers through the MTL's ``map_Kd``: passing vertices directly to ``createVisualShape`` works
with TinyRenderer but crashes the EGL plugin, which only loads meshes from files.

**Memory.** pybullet keeps every mesh and texture file it reads in a process-wide cache keyed by
the file's path, which ``disconnect`` and ``resetSimulation`` do not empty; the EGL plugin keeps
its own such cache, which ``enableFileCaching=0`` does not reach. Loading from a fresh temporary
folder each time therefore leaked the whole site on every environment made and closed (measured
with 100 create/close cycles: 11 MiB a cycle with TinyRenderer, 23 MiB with EGL). Clients turn
the physics server's cache off (:class:`~uav_struct_env.sim.client.RenderClient`), and the files
are loaded from a path named by their content (:func:`_content_dir`) in a folder that lives only
during the load: loading the same site again hits the EGL plugin's cache instead of adding to it
(a path always holds the same bytes, so a cache hit is always right). What remains is pybullet's:
with EGL, each *distinct* site loaded in a process stays cached (about 12 MiB for the paper
site at the default texture size).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from uav_struct_env.sim.client import p  # imported quietly there
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
    names = [e.name for e in elements]
    for name in names:
        if names.count(name) > 1:
            raise ValueError(f"element names must be unique, {name!r} appears twice")
    with _LOAD_LOCK:
        root = _load_root()
        try:
            for k, element in enumerate(elements):
                scratch = directory / f"e{k:03d}"
                scratch.mkdir(parents=True, exist_ok=True)
                stem = f"e{k:03d}_{element.kind}"
                write_obj(element, scratch, stem)
                path = _content_dir(scratch, root) / f"{stem}.obj"
                shape = p.createVisualShape(
                    p.GEOM_MESH, fileName=str(path), rgbaColor=[1, 1, 1, 1],
                    physicsClientId=client_id,
                )
                if shape < 0:
                    raise RuntimeError(
                        f"pybullet could not load the mesh of {element.name!r} from {path}"
                    )
                body = p.createMultiBody(
                    baseMass=0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=shape,
                    physicsClientId=client_id,
                )
                body_ids[element.name] = body
                kinds[element.name] = element.kind
        finally:
            shutil.rmtree(root, ignore_errors=True)
    return LoadedScene(body_ids, kinds)


#: One load at a time per process: they share the content-named folder.
_LOAD_LOCK = threading.Lock()


def _load_root() -> Path:
    """The folder meshes are loaded from: the same path for the whole process (see above)."""
    root = Path(tempfile.gettempdir()) / f"uav_struct_env_meshes_{os.getuid()}_{os.getpid()}"
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(mode=0o700)
    return root


def _content_dir(scratch: Path, root: Path) -> Path:
    """Move the files of ``scratch`` into ``root/<digest of their names and bytes>/``."""
    digest = hashlib.sha256()
    files = sorted(scratch.iterdir())
    for f in files:
        digest.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    target = root / digest.hexdigest()[:32]
    if not target.exists():
        os.replace(scratch, target)
    return target
