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
* :func:`lock_output` keeps two runs out of one output folder (or file): a second command that
  would write there while the first is still running is refused (:class:`OutputBusyError`, whose
  message names the folder and the other run) instead of replacing the first's results.
  :func:`prepare_output_dir` and :class:`StagedOutput` take the lock; :class:`StagedOutput`
  checks it again just before its commit replaces files.
* :func:`remove_earlier_run` is what ``--overwrite`` means for folders a library fills by
  itself (checkpoints, TensorBoard logs): the old run's files go before the new run writes.
"""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import fnmatch
import json
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

__all__ = [
    "PARTIAL_PREFIX",
    "OutputBusyError",
    "OutputExistsError",
    "OutputLock",
    "PNG_SETTINGS_KEY",
    "StagedOutput",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "check_no_earlier_run",
    "lock_output",
    "lock_path",
    "open_append",
    "prepare_output_dir",
    "real_folder",
    "remove_earlier_run",
    "save_figure",
]

#: The PNG text chunk that carries a figure's settings line (:func:`save_figure`).
PNG_SETTINGS_KEY = "Settings"

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


class OutputBusyError(OutputExistsError):
    """Another running command is writing into the same output folder (or file)."""


#: Name of the lock inside an output folder whose parent this user cannot write into.
INSIDE_LOCK = ".uav-struct.lock"

#: Seconds to wait for a new lock holder to write its pid into the lock file.
_HOLDER_WAIT_S = 0.5


def lock_path(target: str | Path) -> Path:
    """The lock file of the output folder or file ``target``: ``.<name>.lock`` beside it.

    The path is resolved first, so two spellings of one folder (a symlink, ``./``) share a lock.
    When the parent is not writable and ``target`` is an existing folder, the lock lies inside it
    (:data:`INSIDE_LOCK`, which no check counts as an earlier run's file).
    """
    real = Path(os.path.realpath(target))
    if real.is_dir() and not os.access(real.parent, os.W_OK | os.X_OK):
        return real / INSIDE_LOCK
    return real.parent / f".{real.name}.lock"


def _run_entries(out: Path) -> list[str]:
    """The names in ``out`` a run wrote: neither leftovers of an interrupted run nor the lock."""
    return sorted(e for e in os.listdir(out) if not _leftover(e) and e != INSIDE_LOCK)


def _busy(what: str, target: Path, holder: str) -> OutputBusyError:
    """The error for ``target`` while another run (``holder``, described) is writing it."""
    return OutputBusyError(
        f"{what} {str(target)!r} is being written by another run ({holder}); wait for it "
        "to finish or choose another output folder"
    )


def _describe_holder(text: str) -> str:
    pid, _, command = text.strip().partition(" ")
    if not pid.isdigit():
        return "a run that has not said which yet"
    return f"pid {pid}: {command}" if command else f"pid {pid}"


def _read_holder(fd: int) -> str:
    """The lock file's ``"<pid> <command>"`` line (waits briefly for a holder that just took it)."""
    deadline = time.monotonic() + _HOLDER_WAIT_S
    while True:
        text = os.pread(fd, 4096, 0).decode("utf-8", "replace")
        if text.strip() or time.monotonic() > deadline:
            return text
        time.sleep(0.02)


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path, follow_symlinks=False))
    except FileNotFoundError:
        return False


class OutputLock:
    """The lock of one output folder or file, held by this process (see :func:`lock_output`).

    It is an ``flock`` on :func:`lock_path`'s file, which holds ``"<pid> <command line>"``:
    the kernel releases an ``flock`` when its holder dies however it dies, so a lock left by a
    killed run is taken over safely (its file remains, naming a pid that no longer runs, and the
    run that takes it over says so in one line). Re-entrant within the process: every
    :func:`lock_output` of the same target is matched by one :meth:`release`.
    """

    def __init__(self, target: Path, path: Path, fd: int) -> None:
        self.target, self.path, self._fd, self._count = target, path, fd, 1

    def check(self) -> None:
        """Raise :class:`OutputBusyError` unless this process still holds the lock."""
        if self._fd is None or not _same_file(self._fd, self.path):
            raise OutputBusyError(
                f"the lock {str(self.path)!r} of {str(self.target)!r} was removed or replaced while "
                "this run worked (another run may be writing there); nothing replaced"
            )

    def release(self) -> None:
        """Release one hold; the last removes the lock file (before unlocking it) and closes it."""
        self._count -= 1
        if self._count > 0 or self._fd is None:
            return
        _HELD.pop(str(self.path), None)
        if _same_file(self._fd, self.path):
            with contextlib.suppress(OSError):
                os.unlink(self.path)
        os.close(self._fd)
        self._fd = None


_HELD: dict[str, OutputLock] = {}


def lock_output(target: str | Path, *, what: str = "output folder") -> OutputLock:
    """Lock the output folder or file ``target`` for this process (created parents included).

    Raises:
        OutputBusyError: another live process holds the lock (the message names ``target``,
            the other run's pid and command, and what to do).
    """
    target = Path(target)
    path = lock_path(target)
    held = _HELD.get(str(path))
    if held is not None:
        held._count += 1
        return held
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = _take(target, path, what)
    lock = _HELD[str(path)] = OutputLock(target, path, fd)
    return lock


def _take(target: Path, path: Path, what: str) -> int:
    """Open, ``flock`` and stamp the lock file; retried when a releasing run unlinked it."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, _FILE_MODE)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _describe_holder(_read_holder(fd))
            os.close(fd)
            raise _busy(what, target, holder) from None
        if not _same_file(fd, path):  # unlinked by its last holder after we opened it
            os.close(fd)
            continue
        _note_stale(target, os.pread(fd, 4096, 0).decode("utf-8", "replace"))
        stamp = f"{os.getpid()} {' '.join(sys.argv)[:300]}\n".encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, stamp, 0)
        return fd


def _note_stale(target: Path, text: str) -> None:
    pid = text.strip().partition(" ")[0]
    if pid.isdigit() and int(pid) != os.getpid():
        print(f"note: taking over the lock of {str(target)!r} left by {_describe_holder(text)}, "
              "which is no longer running", file=sys.stderr)


def _busy_elsewhere(out: Path) -> str | None:
    """The other run holding ``out``'s lock (described), or None."""
    path = lock_path(out)
    if str(path) in _HELD:
        return None
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return _describe_holder(_read_holder(fd))
    finally:
        os.close(fd)  # also drops the shared lock taken just to look
    return None


@atexit.register
def _release_all() -> None:
    for lock in list(_HELD.values()):
        lock._count = 1
        lock.release()


def prepare_output_dir(path: str | Path, *, overwrite: bool = False, flag: str = "--overwrite") -> Path:
    """Lock and create the output folder ``path``, or check that writing into it loses nothing.

    The lock (:func:`lock_output`) is held until the process exits or the caller calls
    ``lock_output(path).release()`` twice (once for that call, once for this one).

    Args:
        path: the folder (created with its parents if missing).
        overwrite: allow a folder that already holds files (the caller then replaces them).
        flag: how the caller's user asks for ``overwrite``, named in the error message.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        OutputBusyError: another running command is writing into ``path``.
        OutputExistsError: ``path`` holds files (other than leftovers of an interrupted run of
            this module) and ``overwrite`` is false.
        NotADirectoryError: ``path`` exists and is not a folder.
    """
    out = Path(path)
    lock = lock_output(out)
    try:
        return _prepare(out, overwrite, flag)
    except BaseException:
        lock.release()
        raise


def _prepare(out: Path, overwrite: bool, flag: str) -> Path:
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"output folder {str(out)!r} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    _remove_leftovers(out)
    if not overwrite:
        check_no_earlier_run(out, flag)
    return out


def check_no_earlier_run(out: Path, flag: str = "--overwrite") -> None:
    """Raise if the existing folder ``out`` holds files of a run, or another run is writing there.

    Leftovers of an interrupted run of this module, and the lock, do not count.

    Raises:
        OutputBusyError: another live process holds ``out``'s lock (checked first, whatever
            ``out`` holds).
        OutputExistsError: ``out`` holds files (the message names ``flag``).
    """
    holder = _busy_elsewhere(Path(out))
    if holder is not None:
        raise _busy("output folder", Path(out), holder)
    entries = _run_entries(Path(out))
    if entries:
        shown = ", ".join(entries[:4]) + (f" and {len(entries) - 4} more" if len(entries) > 4 else "")
        raise OutputExistsError(
            f"{str(out)!r} already holds results ({shown}); pass {flag} to replace them, "
            "or choose another output folder"
        )


def remove_earlier_run(out: str | Path, names: Sequence[str]) -> list[str]:
    """Remove the top-level entries of ``out`` matching the glob patterns ``names``; returns them.

    ``--overwrite`` of a command whose libraries write folders by themselves (SB3 checkpoints,
    TensorBoard logs): the earlier run's files must go before the new run writes, or the two
    runs' files would sit side by side and be read as one run.
    """
    out = Path(out)
    gone = [e for e in _run_entries(out) if any(fnmatch.fnmatch(e, g) for g in names)]
    for name in gone:
        _remove(out / name)
    return gone


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


def save_figure(fig: Any, path: str | Path, *, settings: str | None = None, **kwargs: Any) -> Path:
    """``fig.savefig(path, **kwargs)`` atomically (the format follows ``path``'s suffix).

    ``settings``: the output's settings line (:mod:`uav_struct_env.provenance`), stored in a PNG's
    ``Settings`` text chunk (read back by :func:`uav_struct_env.provenance.png_settings`).
    """
    path = Path(path)
    kwargs.setdefault("format", path.suffix.lstrip(".") or None)
    if settings is not None and kwargs["format"] == "png":
        kwargs["metadata"] = {**kwargs.get("metadata", {}), PNG_SETTINGS_KEY: settings}
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
        self.lock = lock_output(out)
        try:
            self.out = _prepare(Path(out), overwrite, flag)
            self.stage = Path(tempfile.mkdtemp(prefix=f"{PARTIAL_PREFIX}{os.getpid()}-", dir=self.out))
        except BaseException:
            self.lock.release()
            raise
        self.owned, self.overwrite, self.flag = tuple(owned), overwrite, flag

    def __enter__(self) -> StagedOutput:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                try:
                    self.commit()
                except BaseException:
                    self.discard()
                    raise
            else:
                self.discard()
        finally:
            self.lock.release()

    def discard(self) -> None:
        """Remove the staging folder and everything in it."""
        shutil.rmtree(self.stage, ignore_errors=True)

    def commit(self) -> list[Path]:
        """Move the staged set into :attr:`out`; returns the final paths.

        Checks first that this run still holds the lock and, without ``overwrite``, that the
        folder still holds no run's files: whatever happened meanwhile, nothing is replaced
        that this run was not allowed to replace.

        Raises:
            OutputBusyError / OutputExistsError: the lock was lost, or another run's files
                appeared in :attr:`out` while this one worked (the staged files stay staged).
        """
        self.lock.check()
        if not self.overwrite:
            check_no_earlier_run(self.out, self.flag)
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
