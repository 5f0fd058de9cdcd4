"""Load a site's textured meshes into a pybullet client, once.

Each :class:`~uav_struct_env.site.mesh.SiteElement` is written as OBJ + MTL + BMP
(:func:`~uav_struct_env.site.mesh.obj_files`) and loaded as a static visual-only body
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
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from uav_struct_env.sim.client import p  # imported quietly there
from uav_struct_env.site.mesh import SiteElement, obj_files

__all__ = ["LoadedScene", "load_elements"]


@dataclass(frozen=True)
class LoadedScene:
    """Body ids of the loaded elements, by element name and by kind."""

    body_ids: dict[str, int]
    kinds: dict[str, str]

    def bodies_of_kind(self, kind: str) -> list[int]:
        """Body ids of every element of ``kind`` ("column", "slab", "ground", "marker")."""
        return [b for name, b in self.body_ids.items() if self.kinds[name] == kind]


def load_elements(client_id: int, elements: Sequence[SiteElement]) -> LoadedScene:
    """Create one static body per element, from its files (:func:`_content_dir`).

    Returns:
        The body id of every element.
    """
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
                stem = f"e{k:03d}_{element.kind}"
                path = _content_dir(*_element_files(element, stem), root) / f"{stem}.obj"
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


#: Each element's files and their digest, by stem, for as long as the element lives: a site's
#: elements are shared by the worlds of a process (:func:`~uav_struct_env.site.mesh.shared_site_elements`),
#: so a world of a site loaded before writes the same bytes without formatting them again.
_FILES: weakref.WeakKeyDictionary[SiteElement, dict[str, tuple[dict[str, bytes], str]]] = (
    weakref.WeakKeyDictionary()
)


def _element_files(element: SiteElement, stem: str) -> tuple[dict[str, bytes], str]:
    """``element``'s files (:func:`~uav_struct_env.site.mesh.obj_files`) and their digest (under the lock)."""
    by_stem = _FILES.setdefault(element, {})
    if stem not in by_stem:
        files = obj_files(element, stem)
        by_stem[stem] = (files, _digest(files))
    return by_stem[stem]


def _digest(files: dict[str, bytes]) -> str:
    """The name of the folder that holds ``files``: a digest of their names and bytes."""
    digest = hashlib.sha256()
    for name in sorted(files):
        digest.update(name.encode() + b"\0" + files[name] + b"\0")
    return digest.hexdigest()[:32]


def _content_dir(files: dict[str, bytes], digest: str, root: Path) -> Path:
    """Write ``files`` (bytes by file name) into ``root/<digest>/`` (:func:`_digest`).

    The folder's name is a function of what it holds, so a path always holds the same bytes.
    """
    target = root / digest
    if not target.exists():
        target.mkdir()
        for name, data in files.items():
            (target / name).write_bytes(data)
    return target
