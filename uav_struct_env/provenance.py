"""How an output was made: the package version and, where available, the git commit.

Outputs that others may copy (the study's ``results.json``, tables and figures) record
:func:`software`, so that a number can be traced to the code that produced it.
"""

from __future__ import annotations

import functools
import subprocess
from pathlib import Path

import uav_struct_env

__all__ = ["git_commit", "software"]

_ROOT = Path(uav_struct_env.__file__).resolve().parents[1]


def _git(*args: str) -> str | None:
    try:
        proc = subprocess.run(
            ["git", "-C", str(_ROOT), *args], capture_output=True, text=True, timeout=10, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return proc.stdout.strip() if proc.returncode == 0 else None


@functools.lru_cache(maxsize=1)
def git_commit() -> tuple[str, bool] | None:
    """``(commit, modified)`` of the checkout the package runs from, or None.

    None when the package is not run from a git checkout of its own (an installed wheel, no git
    on the machine). ``modified`` is true when tracked files differ from the commit.
    """
    top = _git("rev-parse", "--show-toplevel")
    if top is None or Path(top).resolve() != _ROOT:
        return None
    commit = _git("rev-parse", "HEAD")
    if commit is None:
        return None
    status = _git("status", "--porcelain", "--untracked-files=no")
    return commit, bool(status)


def software() -> dict:
    """The ``software`` entry of an output: package name, version, git commit and whether modified."""
    git = git_commit()
    return {
        "package": "uav-struct-env",
        "version": uav_struct_env.__version__,
        "git_commit": git[0] if git else None,
        "git_modified": git[1] if git else None,
    }
