"""The ``uav-struct`` command: ``study …``, ``sweep …``, ``render …``, ``localize …`` and ``adapt …``."""

from __future__ import annotations

import sys
from collections.abc import Sequence

USAGE = """usage: uav-struct <command> [options]

commands:
  study    reproduce the paper's four-UAV study (Tables I and II, Fig. 2)
  sweep    the study over many sites and seeds (a process pool, or Ray), merged into one table
  render   render the four UAV views of a site to PNG files
  localize localize drone photos (EXIF GPS + DJI XMP) against an IFC model
  adapt    fine-tune the learned detector on renders of one IFC building (needs torch)

`uav-struct <command> --help` describes each command's options and their defaults;
`uav-struct --version` prints the version."""


def main(argv: Sequence[str] | None = None) -> int:
    """Dispatch to a sub-command; returns the exit status.

    Ctrl-C and SIGTERM end a command the same way, in one line without a traceback (workers
    stopped, nothing half-written): exit status 130 after Ctrl-C, 143 after SIGTERM.
    """
    from uav_struct_env.processes import interrupted_status, stop_on_sigterm

    stop_on_sigterm()
    try:
        status = _dispatch(argv)
    except KeyboardInterrupt:
        print("uav-struct: interrupted", file=sys.stderr)
        return interrupted_status()
    return interrupted_status() if status == 130 else status


def _dispatch(argv: Sequence[str] | None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if args else 2
    if args[0] in ("-V", "--version"):
        from uav_struct_env import __version__

        print(f"uav-struct {__version__}")
        return 0
    command, rest = args[0], args[1:]
    if command == "study":
        from uav_struct_env.study import main as study_main

        return study_main(rest)
    if command == "sweep":
        from uav_struct_env.study.sweep import main as sweep_main

        return sweep_main(rest)
    if command == "render":
        from uav_struct_env.demo import main as render_main

        return render_main(rest)
    if command == "localize":
        from uav_struct_env.photos.command import main as localize_main

        return localize_main(rest)
    if command == "adapt":
        from uav_struct_env.training.adapt import main as adapt_main

        return adapt_main(rest)
    print(f"uav-struct: unknown command {command!r}\n\n{USAGE}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
