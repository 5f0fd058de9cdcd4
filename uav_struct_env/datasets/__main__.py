"""``python -m uav_struct_env.datasets OUT_DIR``: render a labelled landmark dataset."""

from __future__ import annotations

import sys

from uav_struct_env.datasets.landmarks import ACTIVITIES, CAMERAS, IMAGINGS, DatasetConfig, generate
from uav_struct_env.outputs import OutputExistsError
from uav_struct_env.processes import WorkerDied, interrupted_status, stop_on_sigterm
from uav_struct_env.sim.imaging import imaging_argument
from uav_struct_env.validate import INPUT_ERRORS, CommandParser, check_option, check_output_dir, refuse


def main(argv: list[str] | None = None) -> int:
    """Parse arguments and write the dataset (format: :mod:`uav_struct_env.datasets.landmarks`)."""
    ap = CommandParser(prog="python -m uav_struct_env.datasets", description=__doc__)
    ap.add_argument("out_dir", help="output folder")
    ap.add_argument("--layouts", type=int, default=200, help="random sites")
    ap.add_argument("--views", type=int, default=15, help="viewpoints per site")
    ap.add_argument("--seed", type=int, default=0, help="dataset seed (held-out sets: another)")
    ap.add_argument("--scale", type=float, default=0.5, help="saved image scale of 1280x720")
    ap.add_argument("--renderer", default="auto", choices=["auto", "tiny", "egl"])
    ap.add_argument("--stages", default=None,
                    help="with a building file: comma-separated stages the layouts draw from (default: all)")
    ap.add_argument("--site", default="random",
                    help="random (a new random site per layout) or a site file (*.json) / IFC file "
                         "(*.ifc): that building at a stage drawn per layout")
    ap.add_argument("--activity", default="none", choices=ACTIVITIES,
                    help="site activity per layout: none, light or busy (workers, equipment, "
                         "materials, scaffolding; they hide landmarks), or mixed (the three in turn)")
    ap.add_argument("--camera", default="paper",
                    help=f"one of {', '.join(CAMERAS)}: paper (the paper's ideal pinhole), mavic2pro "
                         "(lens distortion, rolling shutter "
                         "and motion blur of the DJI Mavic 2 Pro, the camera moving within the UAV's "
                         "flight limits) or mixed (every other image mavic2pro)")
    ap.add_argument("--imaging", default="ideal", choices=IMAGINGS, type=imaging_argument,
                    help="ideal (the render as it is), camera (optics blur, sensor noise and a JPEG "
                         "round trip on every image, as the env's imaging='camera') or mixed (every "
                         "other pair of images)")
    ap.add_argument("--workers", type=int, default=1, help="rendering processes")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace a dataset already in out_dir (otherwise such a folder is refused)")
    args = ap.parse_args(argv)
    prog = ap.prog
    stop_on_sigterm()  # SIGTERM ends the run as Ctrl-C does (exit 143)
    try:
        config = DatasetConfig(n_layouts=args.layouts, views_per_layout=args.views, seed=args.seed,
                               scale=args.scale, renderer=args.renderer, site=args.site,
                               activity=args.activity, camera=args.camera,
                               imaging=args.imaging,
                               stages=tuple(args.stages.split(",")) if args.stages else None)
        check_option("--workers", args.workers, 1, integer=True)
        check_output_dir(args.out_dir, overwrite=args.overwrite, option="out_dir")
    except INPUT_ERRORS as err:
        return refuse(prog, err)
    try:
        path = generate(config, args.out_dir, workers=args.workers, overwrite=args.overwrite)
    except (OutputExistsError, NotADirectoryError) as err:
        return refuse(prog, err)
    except WorkerDied as err:
        print(f"{prog}: error: {err}; nothing written to {args.out_dir}", file=sys.stderr)
        return 1
    except OSError as err:  # e.g. the disk filled up while the images were written
        return refuse(prog, f"{err}; nothing written to {args.out_dir}", status=1)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; nothing written to {args.out_dir}", file=sys.stderr)
        return interrupted_status()
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
