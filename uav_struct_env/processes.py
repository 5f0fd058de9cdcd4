"""Run work in spawned worker processes that stop cleanly on Ctrl-C and never hang on a dead one.

:func:`run_chunks` replaces ``multiprocessing.Pool.imap_unordered`` for the study and the dataset
generator, because the pool (a) printed a ``KeyboardInterrupt`` traceback from every worker on
Ctrl-C and (b) waits forever, or quietly loses the work, when a worker is killed (out of
memory, ``kill -9``). Here:

* workers ignore SIGINT (a terminal's Ctrl-C goes to the whole process group): only the parent
  sees it, raises ``KeyboardInterrupt`` from :func:`run_chunks`, and the workers are terminated
  and joined before it propagates, so no process outlives the call;
* each worker talks to the parent over its own pipe, and the parent waits on the pipes and on
  the processes' sentinels together: a worker that ends while it still has work raises
  :class:`WorkerDied`, naming the worker, its pid and its exit code or signal.

:func:`stop_on_sigterm` makes SIGTERM (``kill``, a scheduler, a closing terminal session) end a
command as Ctrl-C does: it raises :class:`Terminated`, a ``KeyboardInterrupt``, so the same
clean-up runs (workers stopped, staged files removed, one line), and :func:`interrupted_status`
gives the exit status a shell expects: 130 after SIGINT, 143 (128 + 15) after SIGTERM.
"""

from __future__ import annotations

import multiprocessing as mp
import signal
import threading
import traceback
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from multiprocessing.connection import wait
from typing import Any, TypeVar

__all__ = [
    "Terminated",
    "WorkerDied",
    "describe_exit",
    "interrupted_status",
    "run_chunks",
    "stop_on_sigterm",
]

T = TypeVar("T")
R = TypeVar("R")

#: Seconds a terminated worker gets before it is killed.
_TERMINATE_GRACE_S = 2.0


class Terminated(KeyboardInterrupt):
    """SIGTERM asked this process to stop (handled like Ctrl-C; see :func:`stop_on_sigterm`)."""


#: Signals received by :func:`_raise_terminated`, in order.
_RECEIVED: list[int] = []


def _raise_terminated(signum: int, frame: Any) -> None:
    _RECEIVED.append(signum)
    signal.signal(signum, signal.SIG_IGN)  # the clean-up runs once, not again on a second signal
    raise Terminated(f"stopped by {signal.Signals(signum).name}")


def stop_on_sigterm() -> None:
    """From now on SIGTERM raises :class:`Terminated` in the main thread (a no-op elsewhere)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _raise_terminated)


def interrupted_status() -> int:
    """The exit status of an interrupted command: 143 after SIGTERM, else 130 (Ctrl-C)."""
    return 128 + signal.SIGTERM if _RECEIVED else 130


class WorkerDied(RuntimeError):
    """A worker process ended before it had finished its work."""

    def __init__(self, name: str, pid: int | None, exitcode: int | None, done: int, total: int):
        self.name, self.pid, self.exitcode, self.done, self.total = name, pid, exitcode, done, total
        super().__init__(
            f"worker {name} (pid {pid}) {describe_exit(exitcode)} after {done} of {total} work "
            "items had completed; the run is incomplete (out of memory? see the system log)"
        )


def describe_exit(exitcode: int | None) -> str:
    """``"was killed by SIGKILL"`` / ``"exited with status 3"`` for a process exit code."""
    if exitcode is None:
        return "stopped responding"
    if exitcode < 0:
        try:
            return f"was killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"was killed by signal {-exitcode}"
    return f"exited with status {exitcode}"


def _serve(conn, fn: Callable[[Any], Any]) -> None:
    """Worker loop: receive a chunk (list of items) or None; send ("ok", result) per item."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        while True:
            chunk = conn.recv()
            if chunk is None:
                return
            for item in chunk:
                try:
                    result = fn(item)
                except BaseException as exc:  # reported to the parent, which raises it
                    conn.send(("error", _portable(exc)))
                    return
                conn.send(("ok", result))
            conn.send(("idle", None))
    except (EOFError, BrokenPipeError, KeyboardInterrupt):
        return  # the parent is gone or stopping us
    finally:
        conn.close()


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError carrying its traceback text."""
    import pickle

    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        return RuntimeError(f"in a worker process:\n{text}")


def run_chunks(
    fn: Callable[[T], R],
    chunks: Sequence[Sequence[T]],
    workers: int,
    *,
    name: str = "worker",
) -> Iterator[R]:
    """Yield ``fn(item)`` for every item of every chunk, in completion order.

    Args:
        fn: a picklable (module-level) function, run in ``workers`` spawned processes. A worker
            takes one chunk at a time (its items run in order, in that one process).
        chunks: the work, split into chunks.
        workers: number of processes (at most the number of chunks are started).
        name: worker names are ``f"{name}-{i}"`` (in :class:`WorkerDied` messages).

    Raises:
        WorkerDied: a worker ended while it still had work.
        KeyboardInterrupt: Ctrl-C in the parent; all workers are stopped first.
        Exception: whatever ``fn`` raised in a worker (the other workers are stopped first).
    """
    chunks = [list(c) for c in chunks if len(c)]
    total = sum(len(c) for c in chunks)
    if not chunks:
        return
    ctx = mp.get_context("spawn")
    procs: list[Any] = []
    conns: list[Any] = []
    # Started with SIGINT ignored (inherited through exec): a Ctrl-C while a worker boots does
    # not give it a traceback; _serve keeps ignoring it.
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if in_main else None
    try:
        for i in range(min(workers, len(chunks))):
            parent_end, child_end = ctx.Pipe()
            proc = ctx.Process(target=_serve, args=(child_end, fn), name=f"{name}-{i}", daemon=True)
            proc.start()
            child_end.close()  # so that the parent's recv sees EOF when the worker dies
            procs.append(proc)
            conns.append(parent_end)
    finally:
        if in_main:
            signal.signal(signal.SIGINT, previous)
    queue = deque(chunks)
    busy = [False] * len(procs)
    done = 0
    clean = False
    try:
        for i, conn in enumerate(conns):
            busy[i] = _dispatch(conn, queue)
        while done < total:
            waiting = [c for i, c in enumerate(conns) if busy[i]]
            waiting += [procs[i].sentinel for i in range(len(procs)) if busy[i]]
            if not waiting:
                raise RuntimeError(f"workers went idle after {done} of {total} work items")
            for ready in wait(waiting):
                i = conns.index(ready) if ready in conns else [p.sentinel for p in procs].index(ready)
                conn = conns[i]
                # Messages sent before a worker ended are still read; then its end is judged.
                while busy[i] and _has_message(conn):
                    kind, payload = _recv(conn, procs[i], done, total)
                    if kind == "ok":
                        done += 1
                        yield payload
                    elif kind == "error":
                        raise payload
                    else:
                        busy[i] = _dispatch(conn, queue)
                if busy[i] and not procs[i].is_alive():
                    procs[i].join()
                    if _RECEIVED:  # a SIGTERM to the process group reached the worker first
                        raise Terminated("stopped by SIGTERM")
                    raise WorkerDied(procs[i].name, procs[i].pid, procs[i].exitcode, done, total)
        clean = True
    finally:
        _stop(procs, conns, clean)


def _has_message(conn) -> bool:
    try:
        return conn.poll()
    except (EOFError, OSError):
        return True  # _recv reports the EOF


def _recv(conn, proc, done: int, total: int):
    try:
        return conn.recv()
    except (EOFError, OSError):
        proc.join(_TERMINATE_GRACE_S)
        raise WorkerDied(proc.name, proc.pid, proc.exitcode, done, total) from None


def _dispatch(conn, queue: deque) -> bool:
    """Send the next chunk (True) or the stop message (False)."""
    chunk = queue.popleft() if queue else None
    try:
        conn.send(chunk)
    except (BrokenPipeError, OSError):
        return chunk is not None  # the sentinel then tells what happened
    return chunk is not None


def _stop(procs: list, conns: list, clean: bool) -> None:
    """Stop and reap every worker: politely after a clean run, by SIGTERM/SIGKILL otherwise."""
    if clean:
        for conn in conns:
            try:
                conn.send(None)
            except (BrokenPipeError, OSError):
                pass
        for proc in procs:
            proc.join(_TERMINATE_GRACE_S)
    for proc in procs:
        if proc.is_alive():
            proc.terminate()
    for proc in procs:
        proc.join(_TERMINATE_GRACE_S)
        if proc.is_alive():
            proc.kill()
            proc.join()
    for conn in conns:
        conn.close()
