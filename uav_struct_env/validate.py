"""A command's inputs, validated in one place before any work starts or any file is written.

Every command users run (``uav-struct study`` and ``render``, ``python -m
uav_struct_env.datasets``, the trainers in :mod:`uav_struct_env.training`, the examples) builds
its parser with :class:`CommandParser` (``--help`` shows every default; ``--version``), checks its
inputs with the functions below and reports a refusal with :func:`refuse`: one line
``"<prog>: error: <message>"`` on stderr and exit status 2, never a traceback.

* :func:`check_output_dir`: ``--out`` can be created or written into (not a file; its nearest
  existing ancestor a writable folder; a file system that is not full) and holds no earlier run
  unless ``--overwrite``. It creates nothing: the command claims the folder through
  :mod:`uav_struct_env.outputs` once every input has passed.
* :func:`check_output_file`: one output file the user named (``--plot``, ``--json-out``).
* :func:`check_input_file`: an input file (a model, weights) exists and is a file.
* :func:`check_site`: ``--site`` (with ``--stage``) parsed into a :class:`~uav_struct_env.site.Site`
  now, so a malformed site file is refused before the output folder exists.
* :func:`check_option`: a number option in range, through the project's one scalar validator
  (:func:`localization.checks.check_number`), naming the option.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path
from typing import Any

from localization.checks import check_number
from uav_struct_env.errors import ConfigError, UsageError
from uav_struct_env.outputs import OutputExistsError, check_no_earlier_run

__all__ = [
    "INPUT_ERRORS",
    "MIN_FREE_BYTES",
    "CommandParser",
    "check_input_file",
    "check_option",
    "check_output_dir",
    "check_output_file",
    "check_site",
    "refuse",
]

#: What a bad input raises while a command validates it (the project's errors derive from these).
INPUT_ERRORS = (ValueError, TypeError, ImportError, OSError)

#: An output folder's file system needs at least this much free space (a full disk is refused
#: before the work, not after it), bytes.
MIN_FREE_BYTES = 16 * 2**20


def refuse(prog: str, err: BaseException | str, status: int = 2) -> int:
    """Print ``"<prog>: error: <err>"`` as one line on stderr; returns the exit ``status``.

    2 (the default) is a refused input; a command that fails while it works (a disk that fills
    up while results are written) passes 1.
    """
    message = " ".join(str(err).split())
    print(f"{prog}: error: {message}", file=sys.stderr)
    return status


def _nearest_existing(path: Path) -> Path:
    path = path.absolute()
    while not (path.exists() or path.is_symlink()):
        path = path.parent
    return path


def check_output_dir(
    path: Any, *, overwrite: bool = False, option: str = "--out", flag: str = "--overwrite"
) -> Path:
    """Check that the output folder ``path`` can be created or written into; create nothing.

    Raises:
        UsageError: ``path`` is empty, exists and is not a folder, cannot be created (an
            ancestor is a file or not writable), or its file system has less than
            :data:`MIN_FREE_BYTES` free.
        OutputExistsError: ``path`` holds an earlier run and ``overwrite`` is false (the message
            names ``flag``).
    """
    if not isinstance(path, (str, os.PathLike)) or str(path) == "":
        raise UsageError(f"{option} must name a folder, got {path!r}")
    out = Path(path)
    if out.exists() or out.is_symlink():
        if not out.is_dir():
            raise UsageError(f"{option} {str(out)!r} exists and is not a folder")
        if not os.access(out, os.W_OK | os.X_OK):
            raise UsageError(f"{option} {str(out)!r} is a folder this user cannot write into")
        if not overwrite:
            check_no_earlier_run(out, flag)
        base = out
    else:
        base = _nearest_existing(out.parent)
        if not base.is_dir():
            raise UsageError(f"{option} {str(out)!r} cannot be created: {str(base)!r} is not a folder")
        if not os.access(base, os.W_OK | os.X_OK):
            raise UsageError(
                f"{option} {str(out)!r} cannot be created: this user cannot write into {str(base)!r}"
            )
    free = shutil.disk_usage(base).free
    if free < MIN_FREE_BYTES:
        raise UsageError(
            f"{option} {str(out)!r}: its file system has {free / 2**20:.1f} MiB free, less than the "
            f"{MIN_FREE_BYTES // 2**20} MiB a run needs"
        )
    return out


def check_output_file(path: Any, *, overwrite: bool = False, option: str) -> Path:
    """Check that the output file ``path`` can be written (its folder via :func:`check_output_dir`).

    Raises:
        UsageError: ``path`` is a folder, or its folder cannot be created or written into.
        OutputExistsError: ``path`` exists and ``overwrite`` is false.
    """
    if not isinstance(path, (str, os.PathLike)) or str(path) == "":
        raise UsageError(f"{option} must name a file, got {path!r}")
    out = Path(path)
    if out.is_dir():
        raise UsageError(f"{option} {str(out)!r} is a folder; name a file")
    if (out.exists() or out.is_symlink()) and not overwrite:
        raise OutputExistsError(f"{option} {str(out)!r} exists; pass --overwrite to replace it")
    check_output_dir(out.parent, overwrite=True, option=f"{option}'s folder")
    return out


def check_input_file(path: Any, *, option: str, what: str = "file") -> Path:
    """Return ``path`` if it is an existing file; else :class:`UsageError` naming ``option``."""
    if not isinstance(path, (str, os.PathLike)) or str(path) == "":
        raise UsageError(f"{option} must name an existing {what}, got {path!r}")
    p = Path(path)
    if p.is_dir():
        raise UsageError(f"{option} {str(p)!r} is a folder, expected an existing {what}")
    if not p.is_file():
        raise UsageError(f"{option} {str(p)!r} does not exist; expected an existing {what}")
    return p


def check_site(site: Any, stage: str | None = None, *, seed: int = 0, option: str = "--site"):
    """``--site`` (and ``--stage``) resolved now: a :class:`~uav_struct_env.site.Site` at ``stage``.

    ``site`` is a preset name (``paper``), ``random`` (drawn from ``seed``), a site file
    (``*.json``) or an IFC file (``*.ifc``); the file is read and validated completely.

    Raises:
        UsageError: naming ``option`` and the file, with the site's own message (a
            :class:`~uav_struct_env.errors.SiteGeometryError` names the bad field).
    """
    import numpy as np

    from uav_struct_env.site import make_site

    if not isinstance(site, str) or not site:
        raise UsageError(f"{option} must be paper, random, a site file (*.json) or an IFC file, got {site!r}")
    try:
        return make_site(site, stage=stage, marker_size=None, rng=np.random.default_rng(seed))
    except INPUT_ERRORS as err:
        raise UsageError(f"{option} {site!r}: {err}") from None


def check_option(option: str, value: Any, lo: float | None = None, hi: float | None = None,
                 **kwargs: Any) -> Any:
    """:func:`localization.checks.check_number` for a command-line option: raises :class:`UsageError`."""
    return check_number(option, value, lo, hi, error=UsageError, type_error=UsageError, **kwargs)


def image_size_argument(text: str) -> tuple[int, int]:
    """``--image-size WxH`` (``320x180``) as ``(W, H)``, within the env's limits.

    Raises:
        argparse.ArgumentTypeError: not two integers joined by ``x``, a side outside 16-8192 px, or
            more pixels than the env renders (a 20 MP still).
    """
    from uav_struct_env.envs.config import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, check_image_size

    parts = str(text).lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise argparse.ArgumentTypeError(f"must be WIDTHxHEIGHT in pixels (e.g. 320x180), got {text!r}")
    try:
        return check_image_size((int(parts[0]), int(parts[1])))
    except ConfigError:
        raise argparse.ArgumentTypeError(f"each side must be 16-{MAX_IMAGE_SIDE} px and the image at most "
                                         f"{MAX_IMAGE_PIXELS} px, got {text!r}") from None


class CommandParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose ``--help`` shows every option's default and that has ``--version``.

    An option whose help already mentions its default keeps its own wording; flags
    (``store_true``) show none; an option without default shows ``(default: none)``.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        from uav_struct_env import __version__

        self.add_argument("--version", action="version", version=f"%(prog)s {__version__}")

    def format_help(self) -> str:
        """The help text, with "(default: ...)" added to every option that does not say it."""
        for action in self._actions:
            if not action.option_strings or action.default is argparse.SUPPRESS or action.nargs == 0:
                continue  # positionals, --help, --version, flags
            help_ = action.help or ""
            if "default" not in help_.lower():
                shown = "none" if action.default is None else "%(default)s"
                action.help = f"{help_} (default: {shown})".strip()
        return super().format_help()
