"""The IFC parse cache on disk: a building is tessellated once, then every process loads it.

The importer (:mod:`uav_struct_env.site.ifc`) keeps its parse in-process; this module keeps it
on disk as well, so the second process to load a building (a study worker, an env copy, the
next command) reads it back in a fraction of a second instead of tessellating the file again.

An entry is keyed by the file's SHA-256 (its content, not its path or time), the importer's
version (:func:`importer_version`: the package version, the versions of ifcopenshell, shapely
and numpy, and the SHA-256 of the source of every module the parse runs through -- any edit to
the import rules is a new version) and the ``transform``. It lives in :func:`cache_root`:
``$UAV_STRUCT_IFC_CACHE`` when set (``off`` disables the cache), else
``<user cache>/uav-struct/ifc`` (``$XDG_CACHE_HOME`` or ``~/.cache``, beside ``uav-struct
adapt``'s adapted weights). An entry is a pickle written to a temporary file and moved into
place, so a reader never sees half of one; an entry that cannot be read (another version of
Python, a damaged file) is parsed again and overwritten, and a cache that cannot be written
(a read-only folder, a full disk) is logged at WARNING and the import goes on without it.
Processes that load the same building at once (env copies started together) parse it once: the
first holds a lock on the entry (:func:`entry_lock`) while it parses, the others wait for it and
read its entry. The
folder holds the user's own parses: like any pickle, an entry is code to Python, so point the
variable only at a folder you alone write.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import logging
import os
import pickle
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from uav_struct_env.outputs import atomic_path

__all__ = ["IFC_CACHE_ENV", "cache_path", "cache_root", "entry_lock", "importer_version", "read_entry",
           "write_entry"]

log = logging.getLogger(__name__)

#: The environment variable that moves the cache (a folder) or disables it (``off``).
IFC_CACHE_ENV = "UAV_STRUCT_IFC_CACHE"
# The modules whose source the importer's version hashes: the parse, its guards, the element
# classes it builds (pickled by reference), the outline and landmark rules it calls, this cache.
_SOURCES = ("ifc.py", "ifc_file.py", "ifc_cache.py", "ifc_export.py", "elements.py", "polygons.py",
            "landmarks.py", "markers.py", "mesh.py")


def cache_root() -> Path | None:
    """The folder: ``$UAV_STRUCT_IFC_CACHE``, else ``<user cache>/uav-struct/ifc``; None when ``off``."""
    raw = os.environ.get(IFC_CACHE_ENV)
    if raw is not None and raw.strip().lower() == "off":
        return None
    if raw:
        return Path(raw).expanduser()
    cache = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(cache) / "uav-struct" / "ifc"


@functools.lru_cache(maxsize=1)
def importer_version() -> str:
    """The importer's version: 16 hex digits of the SHA-256 of the software versions and the sources."""
    import numpy
    import shapely

    import uav_struct_env

    try:
        import ifcopenshell

        ios = ifcopenshell.version
    except ImportError:
        ios = "none"
    digest = hashlib.sha256(f"{uav_struct_env.__version__} {ios} {shapely.__version__} "
                            f"{numpy.__version__}".encode())
    here = Path(__file__).parent
    for name in (*_SOURCES, "../errors.py"):
        digest.update(name.encode())
        digest.update((here / name).read_bytes())
    return digest.hexdigest()[:16]


def cache_path(sha256: str, transform: bytes, root: Path | None = None) -> Path | None:
    """Where the parse of the file with SHA-256 ``sha256`` under ``transform`` is kept (None: no cache)."""
    root = cache_root() if root is None else root
    if root is None:
        return None
    t = hashlib.sha256(transform).hexdigest()[:12]
    return root / f"{sha256}-{importer_version()}-{t}.pickle"


def read_entry(path: Path | None) -> Any | None:
    """The object stored at ``path``, or None when there is no entry or it cannot be read."""
    if path is None or not path.is_file():
        return None
    try:
        with open(path, "rb") as fh:
            return pickle.load(fh)
    except Exception as exc:  # a damaged or foreign entry: parse again and overwrite it
        log.warning("IFC parse cache: %s cannot be read (%s: %s); parsing the file again",
                    path, type(exc).__name__, exc)
        return None


def write_entry(path: Path | None, obj: Any) -> bool:
    """Store ``obj`` at ``path`` (written beside it, then moved into place); whether it was written."""
    if path is None:
        return False
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            pickle.dump(obj, fh, protocol=pickle.HIGHEST_PROTOCOL)
        return True
    except OSError as exc:
        log.warning("IFC parse cache: cannot write %s (%s); the import goes on without it", path, exc)
        return False


@contextlib.contextmanager
def entry_lock(path: Path | None) -> Iterator[None]:
    """Hold an exclusive lock on the entry ``path`` (a ``.lock`` file beside it) while parsing it.

    Another process that asks for the same entry waits until the holder has written it. Without
    a cache, or where the lock file cannot be made, nothing is locked.
    """
    if path is None:
        yield
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(path.with_name(path.name + ".lock"), "a+b")
    except OSError:
        yield
        return
    with fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
