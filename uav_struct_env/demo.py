"""``uav-struct render``: render the four UAV views of a site (and the site map) to PNG files."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import cv2

from localization.synthetic import PAPER_IMAGE_SIZE

__all__ = ["main", "render_views"]


def render_views(
    out: str | Path,
    *,
    stage: str = "columns",
    seed: int = 0,
    viewpoint: int = 0,
    renderer: str = "auto",
    image_size: tuple[int, int] = PAPER_IMAGE_SIZE,
) -> list[Path]:
    """Render every UAV's view at scripted ``viewpoint`` plus the ``rgb_array`` frame; return the paths."""
    import uav_struct_env

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    env = uav_struct_env.parallel_env(
        stage=stage, renderer=renderer, image_size=image_size, render_mode="rgb_array"
    )
    try:
        obs, _ = env.reset(seed=seed, options={"viewpoint": viewpoint})
        paths = []
        for agent in env.possible_agents:
            path = out / f"{stage}_{agent}_viewpoint{viewpoint}.png"
            cv2.imwrite(str(path), cv2.cvtColor(obs[agent]["image"], cv2.COLOR_RGB2BGR))
            paths.append(path)
        path = out / f"{stage}_overview_viewpoint{viewpoint}.png"
        cv2.imwrite(str(path), cv2.cvtColor(env.render(), cv2.COLOR_RGB2BGR))
        paths.append(path)
    finally:
        env.close()
    return paths


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point."""
    p = argparse.ArgumentParser(prog="uav-struct render", description=__doc__)
    p.add_argument("--out", default="renders", help="output folder (default: renders)")
    p.add_argument("--stage", default="both", choices=("slab", "columns", "both"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--viewpoint", type=int, default=0, help="scripted viewpoint index (0-9)")
    p.add_argument("--renderer", default="auto", choices=("auto", "tiny", "egl"))
    args = p.parse_args(argv)
    stages = ("slab", "columns") if args.stage == "both" else (args.stage,)
    for stage in stages:
        for path in render_views(
            args.out, stage=stage, seed=args.seed, viewpoint=args.viewpoint, renderer=args.renderer
        ):
            print(path.resolve())
    return 0


if __name__ == "__main__":
    sys.exit(main())
