"""How an output was made: the package version, where available the git commit, and the settings.

Every file a command writes says how it was made, so that a number can be traced to the code
and the settings that produced it:

* JSON (``results.json``, ``train.json``, ``eval.json``, ``labels.json``): a ``"software"``
  entry (:func:`software`) and a ``"settings"`` entry, the settings line;
* CSV and Markdown tables: a first line with the settings line (``# Settings: ...`` in a CSV);
* PNG figures: a ``Settings`` text chunk (:data:`PNG_SETTINGS_KEY`, read back by
  :func:`png_settings`); the study's figures also draw the line along their bottom edge;
* files in a library's own format (``model.zip``, ``*.npz``, ``*.pkl``, TensorBoard events,
  ``progress.jsonl``): the ``train.json`` of the run folder they belong to.

The settings line is ``uav-struct-env VERSION (git COMMIT[, modified]) · setting · setting ...``;
the study spells its settings out (:func:`uav_struct_env.study.report.settings_line`), the
other commands list theirs as ``name value`` (:func:`settings_line`).
"""

from __future__ import annotations

import functools
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import uav_struct_env
from uav_struct_env.outputs import PNG_SETTINGS_KEY

__all__ = ["PNG_SETTINGS_KEY", "git_commit", "png_settings", "settings_line", "software", "version_text"]

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


def version_text(sw: Mapping[str, Any] | None = None) -> str:
    """``uav-struct-env 0.1.0 (git 975f9df0f9, modified)``: the head of a settings line.

    ``sw``: a recorded :func:`software` entry (default: this process's).
    """
    sw = software() if sw is None else sw
    text = f"{sw.get('package', 'uav-struct-env')} {sw.get('version', '?')}"
    if sw.get("git_commit"):
        text += f" (git {sw['git_commit'][:10]}{', modified' if sw.get('git_modified') else ''})"
    return text


def _value(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return ",".join(_value(v) for v in value)
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k} {_value(v)}" for k, v in value.items()) + "}"
    return str(value)


def settings_line(settings: Mapping[str, Any], sw: Mapping[str, Any] | None = None) -> str:
    """One line that says how an output was made: the software, then each setting as ``name value``.

    Settings whose value is None (not given) are left out; the order is the mapping's.

    Args:
        settings: the command's options (names as the command's keyword arguments).
        sw: a recorded :func:`software` entry (default: this process's).
    """
    parts = [version_text(sw)]
    parts += [f"{k} {_value(v)}" for k, v in settings.items() if v is not None]
    return " · ".join(" ".join(p.split()) for p in parts)


def png_settings(path: str | Path) -> str | None:
    """The settings line a PNG figure carries in its text chunk, or None if it carries none."""
    from PIL import Image

    with Image.open(path) as im:
        im.load()
        return getattr(im, "text", {}).get(PNG_SETTINGS_KEY)
