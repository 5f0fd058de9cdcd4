"""``uav-struct render``: render the four UAV views of a site (and the site map) to PNG files."""

from __future__ import annotations

import re
import sys
from collections.abc import Sequence
from pathlib import Path

import cv2

from localization.geometry.camera import PAPER_IMAGE_SIZE
from uav_struct_env.errors import RendererUnavailableError
from uav_struct_env.outputs import StagedOutput, atomic_write_bytes
from uav_struct_env.sim.schedule import ScheduleSpec
from uav_struct_env.validate import (
    INPUT_ERRORS,
    CommandParser,
    check_option,
    check_output_dir,
    check_site,
    image_size_argument,
    refuse,
)

__all__ = ["main", "render_views"]


def render_views(
    out: str | Path,
    *,
    stage: str = "columns",
    seed: int = 0,
    viewpoint: int = 0,
    renderer: str = "auto",
    image_size: tuple[int, int] = PAPER_IMAGE_SIZE,
    site: str = "paper",
) -> list[Path]:
    """Render every UAV's view at scripted ``viewpoint`` plus the ``rgb_array`` frame; return the paths.

    Each PNG is written atomically (no truncated file after an interruption). ``uav-struct
    render`` writes through :class:`uav_struct_env.outputs.StagedOutput` (no earlier run lost).
    """
    import uav_struct_env

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    env = uav_struct_env.parallel_env(
        stage=stage, site=site, renderer=renderer, image_size=image_size, render_mode="rgb_array"
    )
    tag = re.sub(r"[^A-Za-z0-9_.-]+", "_", stage)
    try:
        obs, _ = env.reset(seed=seed, options={"viewpoint": viewpoint})
        paths = []
        for agent in env.possible_agents:
            path = out / f"{tag}_{agent}_viewpoint{viewpoint}.png"
            _write_png(path, obs[agent]["image"])
            paths.append(path)
        path = out / f"{tag}_overview_viewpoint{viewpoint}.png"
        _write_png(path, env.render())
        paths.append(path)
    finally:
        env.close()
    return paths


def _write_png(path: Path, rgb) -> None:
    ok, data = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError(f"OpenCV could not encode {path.name}")
    atomic_write_bytes(path, data.tobytes())


#: What ``uav-struct render`` writes (the overview images last).
RENDER_FILES = ("*_overview_viewpoint*.png", "*_viewpoint*.png")


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; every input is checked before anything renders or is written."""
    p = CommandParser(prog="uav-struct render", description=__doc__)
    p.add_argument("--out", default="renders", help="output folder")
    p.add_argument("--site", default="paper",
                   help="paper, random, a site file (*.json) or an IFC file (*.ifc)")
    p.add_argument("--stage", default="both",
                   help="a stage name of the site, or 'both': its floor's slab and columns stages "
                   "(the paper's first floor, an IFC file's last floor)")
    p.add_argument("--seed", type=int, default=0, help="seed of textures (and of --site random)")
    n_viewpoints = ScheduleSpec().n_viewpoints
    p.add_argument("--viewpoint", type=int, default=0,
                   help=f"scripted viewpoint index, 0 to {n_viewpoints - 1}")
    p.add_argument("--renderer", default="auto", choices=("auto", "tiny", "egl"))
    p.add_argument("--image-size", type=image_size_argument, default=PAPER_IMAGE_SIZE, metavar="WxH",
                   help="the views' size, the paper's camera scaled to it (default: the paper's 1280x720)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the images of an earlier run in --out (otherwise refused)")
    args = p.parse_args(argv)
    try:
        check_option("--seed", args.seed, 0, integer=True)
        check_option("--viewpoint", args.viewpoint, 0, n_viewpoints - 1, integer=True)
        site = check_site(args.site, None if args.stage == "both" else args.stage, seed=args.seed)
        if args.stage == "both":
            stages = [s for s in (site.floor_stage("slab"), site.floor_stage("columns")) if s]
            stages = ["slab", "columns"] if args.site in ("paper", "random") else stages
        else:
            stages = [args.stage]
        check_output_dir(args.out, overwrite=args.overwrite)
        staged = StagedOutput(args.out, overwrite=args.overwrite, owned=RENDER_FILES)
    except INPUT_ERRORS as err:
        return refuse(p.prog, err)
    try:
        with staged:
            for stage in stages:
                render_views(staged.stage, stage=stage, seed=args.seed, viewpoint=args.viewpoint,
                             renderer=args.renderer, image_size=args.image_size, site=args.site)
    except (OSError, RendererUnavailableError) as err:
        return refuse(p.prog, f"{err}; nothing written to {args.out}", status=1)
    if args.stage == "both" and len(stages) == 1:
        print(f"{p.prog}: note: the floor of stage {stages[0]!r} has no columns stage; rendered that "
              "stage alone", file=sys.stderr)
    for path in sorted(staged.out.glob("*_viewpoint*.png")):
        print(path.resolve())
    return 0


if __name__ == "__main__":
    sys.exit(main())
