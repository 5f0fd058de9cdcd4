"""``uav-struct localize``: drone photos localized against an IFC model, with poses.csv/json and figures.

Writes into ``--out``: ``poses.csv`` (one row per photo, a first ``# Settings:`` line),
``poses.json`` (settings, software, one record per photo), and unless ``--no-figures`` an
overlay per photo (``overlays/<photo>.png``) and ``flight_summary.png``. Every input is checked
for every photo before anything is localized or written; a refusal is one line and exit status 2.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from localization import PriorSigmas
from localization.detect.weights import WEIGHT_NAMES
from localization.geometry.attitude import attitude_from_world_from_cam
from uav_struct_env.outputs import StagedOutput, atomic_write_json
from uav_struct_env.photos.errors import PhotoError
from uav_struct_env.photos.localize import (
    MAX_DISTANCE_M,
    PhotoPlan,
    PhotoPose,
    plan_photos,
    pose_summary,
    rtk_accuracy,
    run_plan,
)
from uav_struct_env.provenance import software, version_text
from uav_struct_env.validate import INPUT_ERRORS, CommandParser, check_input_file, check_output_dir, refuse

__all__ = ["LOCALIZE_FILES", "PoseRow", "expand_photos", "main", "parse_prior_sigmas", "settings_line",
           "write_outputs"]

#: What ``uav-struct localize`` writes (poses.json is the marker, moved last).
LOCALIZE_FILES = ("poses.json", "poses.csv", "flight_summary.png", "overlays")


@dataclass(frozen=True)
class PoseRow:
    """One poses.csv row: the estimate (project frame; the prior when failed), its stds, the prior."""

    photo: str
    status: str
    reason: str
    x_m: float
    y_m: float
    z_m: float
    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    std_x_m: float
    std_y_m: float
    std_z_m: float
    std_rotation_deg: float
    prior_x_m: float
    prior_y_m: float
    prior_z_m: float
    prior_yaw_deg: float
    prior_pitch_deg: float
    prior_roll_deg: float
    prior_source: str
    n_detections: int
    n_inliers: int
    identities: str
    reprojection_rmse_px: float
    camera: str
    rtk_error_m: float


def _xyz_ypr(cam_from_world: np.ndarray) -> list[float]:
    xyz, rpy = attitude_from_world_from_cam(np.linalg.inv(cam_from_world))
    return [round(float(v), 4) for v in xyz] + [round(math.degrees(float(v)), 4) for v in rpy[::-1]]


def pose_row(p: PhotoPose) -> PoseRow:
    """The poses.csv row of one photo (failed: the pose columns hold the prior, stds are NaN)."""
    std = p.std if p.success else np.full(6, np.nan)
    return PoseRow(
        p.photo.name, "localized" if p.success else "failed", p.failure_reason or "",
        *_xyz_ypr(p.cam_from_world), *(round(float(v), 4) for v in std[:3]),
        round(math.degrees(float(np.linalg.norm(std[3:]))), 4), *_xyz_ypr(p.prior.cam_from_world),
        p.prior.source, int(len(p.identities)), p.n_inliers, " ".join(str(int(i)) for i in p.identities),
        round(p.reprojection_rmse_px, 3) if p.success else float("nan"), p.camera.source,
        round(p.rtk_error_m, 4),
    )


def settings_line(plan: PhotoPlan, detector: str, camera: str | None, prior: str | None,
                  sigmas: PriorSigmas | None) -> str:
    """One line saying how the outputs were made: software, IFC and stage, stack, georeferencing, prior."""
    parts = [
        version_text(), f"ifc {plan.ifc.name}, stage {plan.site.stage}", f"landmarks {plan.landmarks}",
        f"{detector} detector, robust association",
        f"georeference {plan.georef.describe()}" if plan.georef else "no georeference (user prior)",
        f"camera {camera or 'from EXIF (uncalibrated)'}",
        f"prior {prior or 'from photo metadata'}" + (
            f", sigmas {sigmas.position_m} m, "
            f"{tuple(round(math.degrees(v), 3) for v in sigmas.rotation_rad)} deg" if sigmas else ""),
    ]
    return " · ".join(parts)


def check_detector(name: str) -> str:
    """``--detector``: ``guided``, ``learned``, ``learned:NAME`` or ``guided:NAME``; returned unchanged.

    NAME is a weight set of :mod:`localization.detect.weights`.

    Raises:
        PhotoError: naming the value and the names accepted.
    """
    names = ("guided", "learned", *(f"{kind}:{n}" for kind in ("learned", "guided") for n in WEIGHT_NAMES))
    if name not in names:
        raise PhotoError(f"--detector must be one of {names}, got {name!r}")
    return name


def parse_prior_sigmas(text: str | None) -> PriorSigmas | None:
    """``"H,V,TILT_DEG,YAW_DEG"`` as :class:`PriorSigmas` (None for None).

    Raises:
        PhotoError: not four positive finite numbers.
    """
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 4 or not all(math.isfinite(v) and v > 0 for v in values):
        raise PhotoError(f"--prior-sigmas must be H,V,TILT_DEG,YAW_DEG (4 positive numbers), got {text!r}")
    h, v, tilt, yaw = values
    return PriorSigmas((h, h, v), (math.radians(tilt), math.radians(tilt), math.radians(yaw)))


def write_outputs(folder: Path, plan: PhotoPlan, poses: Sequence[PhotoPose], settings: str,
                  figures: bool = True) -> None:
    """poses.csv, poses.json and (``figures``) the overlays and the flight summary into ``folder``."""
    from uav_struct_env.study.cells import write_records_csv

    rows = [pose_row(p) for p in poses]
    write_records_csv(folder / "poses.csv", PoseRow, rows, comment=f"Settings: {settings}")
    if figures:
        from uav_struct_env.photos.localize import _load_rgb
        from uav_struct_env.photos.overlay import plot_flight_summary, plot_overlay

        (folder / "overlays").mkdir(exist_ok=True)
        xyz = plan.site.landmarks(plan.landmarks).xyz
        for p in poses:
            plot_overlay(p, _load_rgb(p.photo), plan.site, xyz, folder / "overlays" / f"{p.photo.stem}.png",
                         settings)
        plot_flight_summary(poses, plan.site, folder / "flight_summary.png", settings)
    atomic_write_json(folder / "poses.json", {
        "settings": settings, "software": software(), "ifc": str(plan.ifc), "stage": plan.site.stage,
        "landmarks": plan.landmarks, "georeference": dataclasses.asdict(plan.georef) if plan.georef else None,
        "rtk_accuracy": rtk_accuracy(poses), "photos": [pose_summary(p) for p in poses],
    }, indent=1)


#: Suffixes of the photos taken from a folder given in place of photos.
PHOTO_SUFFIXES = (".jpg", ".jpeg")


def expand_photos(paths: Sequence[str]) -> list[str]:
    """The photos named, with a folder standing for its JPEG files (sorted by name)."""
    out: list[str] = []
    for path in paths:
        p = Path(path)
        if p.is_dir():
            found = sorted(str(f) for f in p.iterdir() if f.suffix.lower() in PHOTO_SUFFIXES)
            if not found:
                raise PhotoError(f"folder {path!r} holds no JPEG photo (*.jpg, *.jpeg)")
            out += found
        else:
            out.append(str(path))
    return out


def _parser() -> CommandParser:
    p = CommandParser(prog="uav-struct localize", description=__doc__.split("\n")[0])
    p.add_argument("photos", nargs="+",
                   help="drone photos (JPEG with EXIF GPS and DJI XMP), or folders of them")
    p.add_argument("--ifc", required=True, help="the building's IFC file")
    p.add_argument("--stage", default=None, help="IFC stage to localize against (default: the last)")
    p.add_argument("--landmarks", default="all",
                   help="landmark set: all, slab_corners, opening_corners or column_tops")
    p.add_argument("--camera", default=None,
                   help="calibration file: OpenCV YAML/XML/JSON or OpenDroneMap cameras.json "
                   "(default: intrinsics from EXIF, with a warning)")
    p.add_argument("--georef", default=None,
                   help="E,N,H,rotation_deg,EPSG for an IFC without IfcMapConversion (default: the IFC's)")
    p.add_argument("--control-points", default=None,
                   help="CSV of >= 3 surveyed points x,y,z,lat,lon,alt (project m, WGS84 deg, m) "
                   "instead of --georef")
    p.add_argument("--prior", default=None,
                   help="x,y,z,yaw,pitch,roll (project frame, m, deg) for every photo instead of its "
                   "metadata")
    p.add_argument("--takeoff-z", type=float, default=None,
                   help="project-frame height of the take-off point, m: height from RelativeAltitude instead "
                   "of the absolute altitude")
    p.add_argument("--prior-sigmas", default=None,
                   help="H,V,TILT_DEG,YAW_DEG prior standard deviations (default: from RtkFlag, else "
                   "consumer GNSS 3 m, 5 m, 2 deg, 5 deg)")
    p.add_argument("--max-distance", type=float, default=MAX_DISTANCE_M,
                   help="refuse a photo whose prior lies farther than this from the building's plan, m")
    p.add_argument("--detector", default="learned",
                   help="learned (the default weights), learned:NAME, a weight set of "
                   f"localization.detect.weights ({', '.join(WEIGHT_NAMES)}), or guided: the learned "
                   "detector's first pose, then the IFC model's templates matched in the photo "
                   "(docs/photos.md); guided:NAME runs it with the weight set NAME")
    p.add_argument("--out", default="localized", help="output folder")
    p.add_argument("--no-figures", action="store_true", help="write poses.csv and poses.json only")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier run in --out")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; every input is checked before any photo is localized."""
    import warnings

    from tqdm import tqdm

    p = _parser()
    args = p.parse_args(argv)
    try:
        check_input_file(args.ifc, option="--ifc", what="IFC file")
        if args.camera is not None:
            check_input_file(args.camera, option="--camera", what="calibration file")
        check_detector(args.detector)
        sigmas = parse_prior_sigmas(args.prior_sigmas)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            plan = plan_photos(expand_photos(args.photos), args.ifc, stage=args.stage,
                               landmarks=args.landmarks, camera=args.camera, georef=args.georef,
                               control_points=args.control_points, prior=args.prior,
                               takeoff_z=args.takeoff_z, prior_sigmas=sigmas,
                               max_distance_m=args.max_distance)
        for w in {str(w.message) for w in caught}:
            print(f"{p.prog}: warning: {w}", file=sys.stderr)
        check_output_dir(args.out, overwrite=args.overwrite)
        staged = StagedOutput(args.out, overwrite=args.overwrite, owned=LOCALIZE_FILES)
    except (*INPUT_ERRORS, PhotoError) as err:
        return refuse(p.prog, err)
    settings = settings_line(plan, args.detector, args.camera, args.prior, sigmas)
    with staged:
        bar = tqdm(total=len(plan.jobs), desc="localize", unit="photo", file=sys.stderr)
        try:
            poses = run_plan(plan, args.detector, progress=bar.update)
        finally:
            bar.close()
        write_outputs(staged.stage, plan, poses, settings, figures=not args.no_figures)
    n_ok = sum(p.success for p in poses)
    print(f"{n_ok} of {len(poses)} photos localized; {Path(args.out).resolve() / 'poses.csv'}")
    rtk = rtk_accuracy(poses)
    if rtk is not None:
        print(f"RTK-fixed photos: {rtk['localized']} of {rtk['rtk_fixed']} localized; estimate vs RTK "
              f"position median {rtk['median_m']} m, P90 {rtk['p90_m']} m, max {rtk['max_m']} m")
    return 0
