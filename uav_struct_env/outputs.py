"""Output folders that never lose a user's earlier run and never hold a half-written file.

Every command that writes files (``uav-struct study``, ``uav-struct render``, the dataset
generator, the training scripts, the examples) goes through this module:

* :func:`prepare_output_dir` creates the folder, or refuses (:class:`OutputExistsError`, whose
  message names ``--overwrite``) when it already holds something: an earlier run is never
  replaced without being asked.
* :func:`atomic_path` / :func:`atomic_write_text` / :func:`atomic_write_json` /
  :func:`save_figure` write a file under a temporary name in the same folder and rename it over
  the destination (``os.replace``): a reader, or an interrupted run, sees the previous file or the
  complete new one, never a truncated one. A symlink at the destination is replaced, not followed.
* :class:`StagedOutput` writes a whole *set* of files into a hidden folder inside the output
  folder and moves them into place only when the command has finished (with Ctrl-C held off for
  the few milliseconds the moves take): an interrupted run leaves the previous set or the new
  one, never a mix, and files of the previous run that the new one does not write are removed.
"""

from __future__ import annotations

import contextlib
import fnmatch
import json
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

__all__ = [
    "PARTIAL_PREFIX",
    "OutputExistsError",
    "StagedOutput",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "check_no_earlier_run",
    "open_append",
    "prepare_output_dir",
    "real_folder",
    "save_figure",
]

#: Name prefix of the hidden staging folders and temporary files this module creates.
PARTIAL_PREFIX = ".partial-"


class OutputExistsError(FileExistsError):
    """The output folder already holds files and ``overwrite`` was not asked for."""


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: Mode of the files written here: what ``open()`` would give (``mkstemp`` makes them 0600).
_FILE_MODE = 0o666 & ~_umask()


def _leftover(name: str) -> bool:
    return name.startswith(PARTIAL_PREFIX)


def prepare_output_dir(path: str | Path, *, overwrite: bool = False, flag: str = "--overwrite") -> Path:
    """Create the output folder ``path``, or check that writing into it loses nothing.

    Args:
        path: the folder (created with its parents if missing).
        overwrite: allow a folder that already holds files (the caller then replaces them).
        flag: how the caller's user asks for ``overwrite``, named in the error message.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        OutputExistsError: ``path`` holds files (other than leftovers of an interrupted run of
            this module) and ``overwrite`` is false.
        NotADirectoryError: ``path`` exists and is not a folder.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"output folder {str(out)!r} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    _remove_leftovers(out)
    if not overwrite:
        check_no_earlier_run(out, flag)
    return out


def check_no_earlier_run(out: Path, flag: str = "--overwrite") -> None:
    """Raise :class:`OutputExistsError` if the existing folder ``out`` holds files of a run.

    Leftovers of an interrupted run of this module do not count.
    """
    entries = sorted(e for e in os.listdir(out) if not _leftover(e))
    if entries:
        shown = ", ".join(entries[:4]) + (f" and {len(entries) - 4} more" if len(entries) > 4 else "")
        raise OutputExistsError(
            f"{str(out)!r} already holds results ({shown}); pass {flag} to replace them, "
            "or choose another output folder"
        )


def _remove_leftovers(out: Path) -> None:
    """Remove staging folders / temporary files left by runs whose process is gone."""
    for name in os.listdir(out):
        if not _leftover(name):
            continue
        pid = name[len(PARTIAL_PREFIX):].split("-", 1)[0]
        if pid.isdigit() and _alive(int(pid)):
            continue  # another live run is writing here
        with contextlib.suppress(OSError):
            target = out / name
            if target.is_dir() and not target.is_symlink():
                shutil.rmtree(target)
            else:
                target.unlink()


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _check_inside(path: Path) -> Path:
    if path.name in ("", ".", ".."):
        raise ValueError(f"not a file name: {str(path)!r}")
    return path


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is renamed to ``path``.

    The temporary file keeps ``path``'s suffix (so libraries that pick a format from it work).
    On an exception the temporary file is removed and ``path`` is untouched. A symlink at
    ``path`` is replaced by the file, never written through.
    """
    path = _check_inside(Path(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f"{PARTIAL_PREFIX}{os.getpid()}-", suffix=path.suffix,
                               dir=path.parent)
    os.fchmod(fd, _FILE_MODE)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as fh:  # on disk before the rename makes it visible
            os.fsync(fh.fileno())
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_path`)."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, obj: Any, **kwargs: Any) -> Path:
    """Write ``obj`` as JSON (``json.dumps(obj, **kwargs)`` plus a newline) atomically."""
    return atomic_write_text(path, json.dumps(obj, **kwargs) + "\n")


def save_figure(fig: Any, path: str | Path, **kwargs: Any) -> Path:
    """``fig.savefig(path, **kwargs)`` atomically (the format follows ``path``'s suffix)."""
    path = Path(path)
    kwargs.setdefault("format", path.suffix.lstrip(".") or None)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kwargs)
    return path


def _unlink_symlink(path: Path) -> Path:
    path = _check_inside(Path(path))
    if path.is_symlink():  # replaced, never followed out of the output folder
        path.unlink()
    return path


def real_folder(path: str | Path) -> Path:
    """The folder ``path`` (created), with a symlink there replaced by a real folder.

    For folders a library writes into by itself (SB3 checkpoints, TensorBoard logs): what it
    writes stays inside the output folder even if an earlier run left a link there.
    """
    path = _unlink_symlink(Path(path))
    path.mkdir(parents=True, exist_ok=True)
    return path


def open_append(path: str | Path):
    """Open the text file ``path`` for appending (a log); a symlink there is replaced, not followed."""
    path = _unlink_symlink(Path(path))
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW, _FILE_MODE)
    return os.fdopen(fd, "a", encoding="utf-8")


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """Hold SIGINT/SIGTERM (delivered on exit) while a few renames run, in the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held = {signal.SIGINT, signal.SIGTERM}
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


class StagedOutput:
    """Write a set of files into ``out`` all at once, when the command has finished.

    Use as a context manager around the writing; write every file under :attr:`stage` (a
    hidden folder inside ``out``, same file system). On a normal exit the staged entries are
    moved into ``out`` (``marker``, the file that says a run is complete, last) and files of an
    earlier run that match ``owned`` but were not written again are removed; on an exception
    (Ctrl-C included) the staging folder is removed and ``out`` is as it was.

    Args:
        out: the output folder (see :func:`prepare_output_dir`).
        overwrite: allow replacing an earlier run in ``out``.
        owned: glob patterns of the top-level names this command writes (stale ones are removed
            on commit); ``owned[0]`` is the marker, moved last.
        flag: named in the :class:`OutputExistsError` message.
    """

    def __init__(self, out: str | Path, *, overwrite: bool = False, owned: Sequence[str],
                 flag: str = "--overwrite") -> None:
        if not owned:
            raise ValueError("owned must name at least the marker file")
        self.out = prepare_output_dir(out, overwrite=overwrite, flag=flag)
        self.owned = tuple(owned)
        self.stage = Path(tempfile.mkdtemp(prefix=f"{PARTIAL_PREFIX}{os.getpid()}-", dir=self.out))

    def __enter__(self) -> StagedOutput:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()

    def discard(self) -> None:
        """Remove the staging folder and everything in it."""
        shutil.rmtree(self.stage, ignore_errors=True)

    def commit(self) -> list[Path]:
        """Move the staged set into :attr:`out`; returns the final paths."""
        names = sorted(os.listdir(self.stage))
        marker = self.owned[0]
        names.sort(key=lambda n: fnmatch.fnmatch(n, marker))  # the marker last
        stale = [
            n for n in os.listdir(self.out)
            if not _leftover(n) and n not in names and any(fnmatch.fnmatch(n, g) for g in self.owned)
        ]
        with _signals_held():
            old_marker = [n for n in os.listdir(self.out) if fnmatch.fnmatch(n, marker)]
            for n in old_marker:  # the set is not complete while it is being replaced
                _remove(self.out / n)
            for n in stale:
                _remove(self.out / n)
            for n in names:
                src, dst = self.stage / n, self.out / n
                if src.is_dir() or (dst.is_dir() and not dst.is_symlink()):
                    _remove(dst)  # rename replaces a file or link, not a folder
                os.replace(src, dst)
            os.rmdir(self.stage)
        return [self.out / n for n in names]


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()
