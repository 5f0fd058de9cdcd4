"""Localize drone photos against an IFC model: :func:`localize_photos` (``uav-struct localize``).

Per photo: read its metadata (:mod:`~uav_struct_env.photos.metadata`), its camera (a calibration
file or EXIF, :mod:`~uav_struct_env.photos.calibration`) and its prior in the IFC's project frame
(:mod:`~uav_struct_env.photos.prior` through :mod:`~uav_struct_env.photos.georef`); then the
project's localization stack (:func:`uav_struct_env.stack.build_stack`: the learned detector, or
the BIM-guided one with the IFC stage as its building model, robust association, PnP, covariance)
against the IFC stage's landmarks.

Every input is checked for every photo before any photo is localized (:func:`prepare_photos`):
not an image, no prior and none given, no georeferencing and none given, a prior farther than
``max_distance_m`` from the building's plan, a calibration file that does not parse -- each a
:class:`~uav_struct_env.photos.errors.PhotoError` naming the photo and what is wrong. A photo that
does not localize is a :class:`PhotoPose` with ``success=False`` and its reason, at its prior,
never a pose presented as found.

The EXIF orientation tag is honoured (:mod:`~uav_struct_env.photos.orientation`): the detector
runs on the image turned upright, the localizer with the camera and prior turned with it, and
the pose, detections and camera reported are the sensor's and the stored pixels' (the layout the
gimbal attitude and calibrations refer to). Mirrored tags are refused.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localization import PriorSigmas
from localization.geometry.transforms import invert
from uav_struct_env.photos.calibration import CameraModel, resolve_camera
from uav_struct_env.photos.errors import PhotoError
from uav_struct_env.photos.georef import Georeference, read_control_points, read_ifc_georeference
from uav_struct_env.photos.metadata import PhotoMetadata, read_metadata
from uav_struct_env.photos.orientation import turn_camera, turn_image, turn_points, turn_pose, upright_turns
from uav_struct_env.photos.prior import PhotoPrior, prior_from_metadata, prior_from_string

__all__ = ["MAX_DISTANCE_M", "PhotoJob", "PhotoPlan", "PhotoPose", "localize_photos", "plan_photos",
           "pose_summary", "prepare_photos", "resolve_georeference", "rtk_accuracy", "run_plan"]

#: A photo whose prior lies farther than this from the building's plan is refused, m.
MAX_DISTANCE_M = 500.0


@dataclass(frozen=True, eq=False)
class PhotoJob:
    """One photo's checked inputs: metadata, camera and prior."""

    meta: PhotoMetadata
    camera: CameraModel
    prior: PhotoPrior


@dataclass(frozen=True, eq=False)
class PhotoPose:
    """One photo's result.

    Attributes:
        photo: the file.
        success: True when a pose was estimated.
        cam_from_world: (4, 4) the estimate in the project frame (the prior when failed).
        covariance: (6, 6) in ``(camera centre m, rotation vector rad)``
            (:class:`localization.PoseEstimate`); inf when failed.
        identities: (N,) model landmark id of each detection, -1 unassigned.
        detections_uv: (N, 2) the detections, px of the stored image.
        failure_reason: why it failed, or None.
        prior: the prior it started from.
        camera: the camera model used.
        n_inliers: correspondences in the pose.
        reprojection_rmse_px: RMSE of the inliers, px.
        latency_s: detection + localization wall time, s.
        orientation: the photo's EXIF orientation tag.
    """

    photo: Path
    success: bool
    cam_from_world: NDArray[np.float64]
    covariance: NDArray[np.float64]
    identities: NDArray[np.int64]
    detections_uv: NDArray[np.float64]
    failure_reason: str | None
    prior: PhotoPrior
    camera: CameraModel
    n_inliers: int = 0
    reprojection_rmse_px: float = float("inf")
    latency_s: float = 0.0
    orientation: int = 1

    @property
    def world_from_cam(self) -> NDArray[np.float64]:
        """(4, 4) inverse of ``cam_from_world``."""
        return invert(self.cam_from_world)

    @property
    def position(self) -> NDArray[np.float64]:
        """(3,) camera centre, project frame, m."""
        return self.world_from_cam[:3, 3]

    @property
    def rtk_error_m(self) -> float:
        """Distance of the estimate from the photo's RTK-fixed position, m (NaN without either)."""
        if not (self.success and self.prior.rtk_fixed):
            return float("nan")
        return float(np.linalg.norm(self.position - self.prior.position))

    @property
    def std(self) -> NDArray[np.float64]:
        """(6,) standard deviations: position x, y, z [m], rotation [rad] (inf when failed)."""
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))


def resolve_georeference(ifc: str | os.PathLike, georef: Georeference | str | None,
                         control_points: str | os.PathLike | None = None) -> Georeference | None:
    """The georeferencing to use: given, from ``--georef``, from control points, else the IFC's own.

    Returns None when none is given and the IFC states none.
    """
    if isinstance(georef, Georeference):
        return georef
    if georef is not None:
        return Georeference.from_string(georef)
    if control_points is not None:
        xyz, lla = read_control_points(control_points)
        return Georeference.from_control_points(xyz, lla)
    return read_ifc_georeference(ifc)


def _plan_distance(site: Any, xyz: NDArray[np.float64]) -> float:
    """Horizontal distance of a point from the building's plan bounding box, m."""
    lo = np.array([min(e.bounds[0] for e in site.elements), min(e.bounds[1] for e in site.elements)])
    hi = np.array([max(e.bounds[2] for e in site.elements), max(e.bounds[3] for e in site.elements)])
    return float(np.linalg.norm(np.maximum(0.0, np.maximum(lo - xyz[:2], xyz[:2] - hi))))


def prepare_photos(photos: Sequence[str | os.PathLike], site: Any, *, georef: Georeference | None,
                   camera: str | os.PathLike | CameraModel | None = None, prior: str | None = None,
                   takeoff_z: float | None = None, prior_sigmas: PriorSigmas | None = None,
                   max_distance_m: float = MAX_DISTANCE_M) -> list[PhotoJob]:
    """Check every photo's inputs (module docstring) and return their jobs; nothing is localized.

    Raises:
        PhotoError: the first photo whose inputs cannot work, naming it and why.
        FileNotFoundError: a photo or calibration file that does not exist.
    """
    if not photos:
        raise PhotoError("no photos given")
    if georef is None and prior is None:
        raise PhotoError("the IFC file states no georeferencing (IfcMapConversion + IfcProjectedCRS) and "
                         "none was given: pass --georef E,N,H,rotation_deg,EPSG, --control-points FILE or "
                         "--prior")
    jobs = []
    for photo in photos:
        meta = read_metadata(photo)
        upright_turns(meta.orientation, str(meta.path))
        cam = resolve_camera(camera, meta)
        p = (prior_from_string(prior, prior_sigmas) if prior is not None
             else prior_from_metadata(meta, georef, takeoff_z=takeoff_z, sigmas=prior_sigmas))
        distance = _plan_distance(site, p.position)
        if distance > max_distance_m:
            raise PhotoError(f"{meta.path}: its prior lies {distance:.0f} m from the building's plan, more "
                             f"than {max_distance_m:g} m: a wrong georeferencing (map units?) or another "
                             "site")
        jobs.append(PhotoJob(meta, cam, p))
    return jobs


def _load_rgb(path: Path) -> NDArray[np.uint8]:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


class _Stacks:
    """One localization stack per camera model (photos of one camera share it)."""

    def __init__(self, site: Any, landmarks: str, detector: Any) -> None:
        from uav_struct_env.stack import StackSpec

        self.site = site
        self.model = site.landmarks(landmarks)
        self.spec = StackSpec(landmarks=landmarks, detector=detector, association="robust")
        self._built: dict[bytes, Any] = {}

    def __call__(self, camera: CameraModel) -> Any:
        from uav_struct_env.stack import build_stack

        key = camera.K.tobytes() + camera.distortion.tobytes() + bytes(str(camera.image_size), "ascii")
        if key not in self._built:
            self._built[key] = build_stack(self.spec, camera.K, camera.image_size, model_xyz=self.model.xyz,
                                           model_ids=self.model.ids, distortion=camera.distortion,
                                           site=self.site)
        return self._built[key]


def _localize_one(job: PhotoJob, stacks: _Stacks) -> PhotoPose:
    """Localize on the upright image with the upright camera, report the sensor's (orientation.py)."""
    turns = upright_turns(job.meta.orientation, str(job.meta.path))
    cam = job.camera
    K, dist, size = turn_camera(cam.K, cam.distortion, cam.image_size, turns)
    stack = stacks(CameraModel(K, dist, size, cam.source, cam.calibrated))
    t0 = time.perf_counter()
    frame = stack.localize(turn_image(_load_rgb(job.meta.path), turns), None,
                           turn_pose(job.prior.cam_from_world, turns), prior_sigmas=job.prior.sigmas)
    est = frame.estimate
    ids = np.where(est.assignment >= 0, stack.model_ids[np.maximum(est.assignment, 0)], -1)
    return PhotoPose(
        photo=job.meta.path, success=bool(est.success), cam_from_world=turn_pose(est.cam_from_world, -turns),
        covariance=est.covariance if est.success else np.full((6, 6), np.inf), identities=ids,
        detections_uv=turn_points(frame.detections.uv, size, -turns),
        failure_reason=est.failure_reason, prior=job.prior, camera=job.camera,
        n_inliers=int(est.n_inliers), reprojection_rmse_px=float(est.reprojection_rmse_px),
        latency_s=time.perf_counter() - t0, orientation=job.meta.orientation,
    )


@dataclass(frozen=True, eq=False)
class PhotoPlan:
    """Everything checked before the work: the site at its stage, the georeferencing, the jobs.

    Attributes:
        ifc: the IFC file.
        site: the :class:`~uav_struct_env.site.Site` at the stage localized against.
        landmarks: the landmark set's name.
        georef: the georeferencing used (None with a user prior).
        jobs: one :class:`PhotoJob` per photo, in order.
    """

    ifc: Path
    site: Any
    landmarks: str
    georef: Georeference | None
    jobs: list[PhotoJob]


def plan_photos(
    photos: Sequence[str | os.PathLike], ifc: str | os.PathLike, *, stage: str | None = None,
    landmarks: str = "all", camera: str | os.PathLike | CameraModel | None = None,
    georef: Georeference | str | None = None, control_points: str | os.PathLike | None = None,
    prior: str | None = None, takeoff_z: float | None = None, prior_sigmas: PriorSigmas | None = None,
    max_distance_m: float = MAX_DISTANCE_M,
) -> PhotoPlan:
    """Load the IFC stage and check every photo's inputs; localize nothing (:func:`localize_photos`).

    Raises:
        PhotoError, FileNotFoundError: an input that cannot work.
        IfcImportError, ConfigError: an IFC file or stage that cannot be loaded.
    """
    from uav_struct_env.site import LANDMARK_SETS, load_ifc

    if landmarks not in LANDMARK_SETS or landmarks == "aruco":
        names = [n for n in LANDMARK_SETS if n != "aruco"]
        raise PhotoError(f"landmarks must be one of {names}, got {landmarks!r}")
    site = load_ifc(ifc, stage)
    n = len(site.landmarks(landmarks))
    if n < 4:
        raise PhotoError(f"stage {site.stage!r} of {str(ifc)!r} exposes {n} {landmarks} landmarks; at "
                         "least 4 are needed")
    geo = resolve_georeference(ifc, georef, control_points)
    jobs = prepare_photos(photos, site, georef=geo, camera=camera, prior=prior, takeoff_z=takeoff_z,
                          prior_sigmas=prior_sigmas, max_distance_m=max_distance_m)
    return PhotoPlan(Path(ifc), site, landmarks, geo, jobs)


def run_plan(plan: PhotoPlan, detector: Any = "learned",
             progress: Callable[[int], None] | None = None) -> list[PhotoPose]:
    """Localize every photo of a :class:`PhotoPlan` (``detector`` as :func:`localize_photos`'s).

    ``progress`` is called with 1 after each photo.
    """
    stacks = _Stacks(plan.site, plan.landmarks, detector)
    out = []
    for job in plan.jobs:
        out.append(_localize_one(job, stacks))
        if progress is not None:
            progress(1)
    return out


def localize_photos(
    photos: Sequence[str | os.PathLike], ifc: str | os.PathLike, *, detector: Any = "learned",
    progress: Callable[[int], None] | None = None, **options: Any,
) -> list[PhotoPose]:
    """Localize each photo in the IFC's project frame (module docstring).

    Args:
        photos: JPEG (or any Pillow-readable) files.
        ifc: the building's IFC file.
        detector: ``"learned"`` (default), ``"learned:NAME"`` (a weight set of
            :mod:`localization.detect.weights`), ``"guided"`` (the BIM-guided detector,
            :mod:`uav_struct_env.stack.guided`: its templates are rendered from the IFC stage),
            ``"guided:NAME"`` (the same with a weight set) or a :class:`localization.Detector` object.
        progress: called with 1 after each photo.
        **options: :func:`plan_photos`'s: ``stage`` (an :func:`~uav_struct_env.site.ifc_stages`
            name; None: the last), ``landmarks`` (default ``all``), ``camera`` (a calibration file
            or :class:`CameraModel`; None: EXIF, with a warning), ``georef`` (a
            :class:`Georeference` or ``"E,N,H,rotation_deg,EPSG"``; None: the IFC's),
            ``control_points`` (a CSV of ``x,y,z,lat,lon,alt``), ``prior``
            (``"x,y,z,yaw,pitch,roll"`` for every photo), ``takeoff_z`` (m), ``prior_sigmas``,
            ``max_distance_m``.

    Returns:
        One :class:`PhotoPose` per photo, in order: pose, 6x6 covariance, identities, failure reason.

    Raises:
        PhotoError, FileNotFoundError: an input that cannot work, before any photo is localized.
        IfcImportError, ConfigError: an IFC file or stage that cannot be loaded.
    """
    return run_plan(plan_photos(photos, ifc, **options), detector, progress)


def pose_summary(pose: PhotoPose) -> dict[str, Any]:
    """One photo's result as plain data for poses.json (degrees for angles, metres)."""
    from localization.geometry.attitude import attitude_from_world_from_cam

    def _pose(cam_from_world: NDArray[np.float64]) -> dict[str, Any]:
        xyz, rpy = attitude_from_world_from_cam(invert(cam_from_world))
        return {"xyz_m": [round(float(v), 4) for v in xyz],
                "yaw_pitch_roll_deg": [round(math.degrees(float(v)), 4) for v in rpy[::-1]]}

    std = pose.std
    finite = bool(np.all(np.isfinite(std)))
    return {
        "photo": pose.photo.name, "status": "localized" if pose.success else "failed",
        "reason": pose.failure_reason, "pose": _pose(pose.cam_from_world),
        "std": {"xyz_m": [round(float(v), 4) for v in std[:3]] if finite else None,
                "rotation_deg": [round(math.degrees(float(v)), 4) for v in std[3:]] if finite else None},
        "prior": {**_pose(pose.prior.cam_from_world), "source": pose.prior.source,
                  "std_xyz_m": list(pose.prior.sigmas.position_m),
                  "std_rotation_deg": [round(math.degrees(v), 3) for v in pose.prior.sigmas.rotation_rad]},
        "identities": [int(i) for i in pose.identities], "n_detections": int(len(pose.identities)),
        "n_inliers": pose.n_inliers,
        "reprojection_rmse_px": round(pose.reprojection_rmse_px, 3) if pose.success else None,
        "camera": {"source": pose.camera.source, "calibrated": pose.camera.calibrated,
                   "image_size": list(pose.camera.image_size)},
        "orientation": pose.orientation, "latency_s": round(pose.latency_s, 3),
        "rtk_error_m": round(pose.rtk_error_m, 4) if pose.prior.rtk_fixed and pose.success else None,
    }


def rtk_accuracy(poses: Sequence[PhotoPose]) -> dict[str, Any] | None:
    """Estimate vs RTK-fixed position over the photos that state one (docs/photos.md), or None.

    ``{"rtk_fixed": n, "localized": k, "median_m", "p90_m", "max_m"}`` (errors over the localized).
    """
    fixed = [p for p in poses if p.prior.rtk_fixed]
    if not fixed:
        return None
    errors = np.array([p.rtk_error_m for p in fixed if p.success])
    stats: dict[str, Any] = {"median_m": None, "p90_m": None, "max_m": None}
    if len(errors):
        stats = {"median_m": round(float(np.median(errors)), 4),
                 "p90_m": round(float(np.percentile(errors, 90)), 4), "max_m": round(float(errors.max()), 4)}
    return {"rtk_fixed": len(fixed), "localized": int(len(errors)), **stats}
