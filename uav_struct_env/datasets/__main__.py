"""``python -m uav_struct_env.datasets OUT_DIR``: render a labelled landmark dataset."""

from __future__ import annotations

import argparse
import sys

from uav_struct_env.datasets.landmarks import DatasetConfig, generate
from uav_struct_env.outputs import OutputExistsError
from uav_struct_env.processes import WorkerDied


def main(argv: list[str] | None = None) -> int:
    """Parse arguments and write the dataset (format: :mod:`uav_struct_env.datasets.landmarks`)."""
    ap = argparse.ArgumentParser(prog="python -m uav_struct_env.datasets", description=__doc__)
    ap.add_argument("out_dir")
    ap.add_argument("--layouts", type=int, default=200, help="random sites (default 200)")
    ap.add_argument("--views", type=int, default=15, help="viewpoints per site (default 15)")
    ap.add_argument("--seed", type=int, default=0, help="dataset seed (held-out sets: another)")
    ap.add_argument("--scale", type=float, default=0.5, help="saved image scale of 1280x720")
    ap.add_argument("--renderer", default="auto", choices=["auto", "tiny", "egl"])
    ap.add_argument("--site", default="random",
                    help="random (a new random site per layout, default) or a site file (*.json) / "
                         "IFC file (*.ifc): that building at a stage drawn per layout")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--overwrite", action="store_true",
                    help="replace a dataset already in out_dir (otherwise such a folder is refused)")
    args = ap.parse_args(argv)
    prog = ap.prog
    try:
        config = DatasetConfig(n_layouts=args.layouts, views_per_layout=args.views, seed=args.seed,
                               scale=args.scale, renderer=args.renderer, site=args.site)
    except ValueError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return 2
    try:
        path = generate(config, args.out_dir, workers=args.workers, overwrite=args.overwrite)
    except (OutputExistsError, NotADirectoryError) as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return 2
    except WorkerDied as err:
        print(f"{prog}: error: {err}; nothing written to {args.out_dir}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; nothing written to {args.out_dir}", file=sys.stderr)
        return 130
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
