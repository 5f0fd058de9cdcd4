"""A photo's prior pose in the project frame, and its uncertainty, from the photo's own metadata.

Position: WGS84 latitude/longitude (EXIF GPS, else DJI XMP) mapped through the IFC's
georeferencing (:mod:`uav_struct_env.photos.georef`). Height: DJI's AbsoluteAltitude (else EXIF
GPSAltitude) taken in the map's height datum, or -- with ``takeoff_z``, the project-frame height
of the take-off point -- ``takeoff_z + RelativeAltitude`` (barometric, from take-off: far
steadier than the absolute altitude, whose offset reaches tens of metres). Orientation: DJI's
gimbal angles (:mod:`uav_struct_env.photos.attitude`), rotated from local ENU into the project
frame at the photo's position.

Uncertainty (:func:`prior_sigmas`), 1 sigma, as :class:`localization.PriorSigmas`:

* ``RtkFlag`` 50 (RTK fixed): horizontal ``max(RtkStdLon, RtkStdLat)``, vertical ``RtkStdHgt``
  (each at least :data:`RTK_FLOOR_M`), else :data:`RTK_FIXED_M` when the stds are absent;
* ``RtkFlag`` 32-49 (RTK float; DJI's user manuals: "32~49 - Floating point solution
  positioning", 34 the usual value): :data:`RTK_FLOAT_M`;
* otherwise consumer GNSS, :data:`CONSUMER_M` (horizontal, vertical; a vertical of
  :data:`RELATIVE_ALTITUDE_M` with ``takeoff_z``);
* attitude always :data:`ATTITUDE_DEG` (tilt about x and y, yaw): the gimbal's tilt is
  stabilized, its yaw comes from the compass, which steel disturbs.

A user prior (``--prior x,y,z,yaw,pitch,roll``: project frame, metres and degrees, the project's
attitude convention of :mod:`localization.geometry.attitude`: yaw from +x towards +y, positive
pitch looks down) replaces the photo's, with the consumer sigmas.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization import PriorSigmas
from localization.geometry.attitude import world_from_cam_from_attitude
from localization.geometry.transforms import invert
from uav_struct_env.photos.attitude import enu_from_cam_from_dji
from uav_struct_env.photos.errors import PhotoError
from uav_struct_env.photos.georef import Georeference
from uav_struct_env.photos.metadata import PhotoMetadata

__all__ = [
    "ATTITUDE_DEG",
    "CONSUMER_M",
    "RELATIVE_ALTITUDE_M",
    "RTK_FIXED_M",
    "RTK_FLOAT_M",
    "RTK_FLOOR_M",
    "PhotoPrior",
    "prior_from_metadata",
    "prior_from_string",
    "prior_sigmas",
]

#: Consumer GNSS, 1 sigma (horizontal per axis, vertical), m.
CONSUMER_M = (3.0, 5.0)
#: Vertical 1 sigma of ``takeoff_z + RelativeAltitude``, m.
RELATIVE_ALTITUDE_M = 1.0
#: RTK fixed (RtkFlag 50) without RtkStd fields, m.
RTK_FIXED_M = (0.05, 0.1)
#: RTK float (RtkFlag 32-49), m.
RTK_FLOAT_M = (0.5, 1.0)
#: Smallest sigma taken from RtkStd fields, m.
RTK_FLOOR_M = 0.02
#: Gimbal attitude, 1 sigma: tilt about x, tilt about y, yaw, degrees.
ATTITUDE_DEG = (2.0, 2.0, 5.0)


@dataclass(frozen=True, eq=False)
class PhotoPrior:
    """The prior of one photo.

    Attributes:
        cam_from_world: (4, 4) prior pose in the project frame.
        sigmas: its uncertainty.
        source: where it came from, for outputs (``"EXIF GPS + DJI gimbal, consumer GNSS"``).
        rtk_fixed: True when the photo states an RTK-fixed position (RtkFlag 50) and the prior's
            position is it: a reference for the estimate (``rtk_error_m`` in the outputs).
    """

    cam_from_world: NDArray[np.float64]
    sigmas: PriorSigmas
    source: str
    rtk_fixed: bool = False

    @property
    def position(self) -> NDArray[np.float64]:
        """(3,) prior camera centre, project frame, m."""
        return invert(self.cam_from_world)[:3, 3]


def _sigmas(h: float, v: float) -> PriorSigmas:
    return PriorSigmas((h, h, v), tuple(math.radians(d) for d in ATTITUDE_DEG))


def prior_sigmas(meta: PhotoMetadata, relative_altitude: bool = False) -> tuple[PriorSigmas, str]:
    """The prior's sigmas for a photo (module docstring) and a short name of the case."""
    flag = meta.dji.get("RtkFlag")
    if flag == 50:
        stds = [meta.dji.get(k) for k in ("RtkStdLon", "RtkStdLat", "RtkStdHgt")]
        if all(s is not None for s in stds):
            h = max(stds[0], stds[1], RTK_FLOOR_M)
            return _sigmas(h, max(stds[2], RTK_FLOOR_M)), "RTK fixed (RtkStd)"
        return _sigmas(*RTK_FIXED_M), "RTK fixed"
    if flag is not None and 32 <= flag < 50:
        return _sigmas(*RTK_FLOAT_M), "RTK float"
    v = RELATIVE_ALTITUDE_M if relative_altitude else CONSUMER_M[1]
    return _sigmas(CONSUMER_M[0], v), "consumer GNSS"


def _missing(meta: PhotoMetadata, takeoff_z: float | None) -> list[str]:
    missing = []
    if meta.latitude_deg is None or meta.longitude_deg is None:
        missing.append("a GPS position (EXIF GPSLatitude/GPSLongitude or drone-dji:GpsLatitude/GpsLongitude)")
    if takeoff_z is None and meta.absolute_altitude_m is None:
        missing.append("an altitude (drone-dji:AbsoluteAltitude or EXIF GPSAltitude)")
    if takeoff_z is not None and "RelativeAltitude" not in meta.dji:
        missing.append("drone-dji:RelativeAltitude (needed with --takeoff-z)")
    if meta.gimbal_deg() is None:
        missing.append("the gimbal attitude (drone-dji:GimbalYawDegree/GimbalPitchDegree/GimbalRollDegree)")
    return missing


def prior_from_metadata(meta: PhotoMetadata, georef: Georeference, *, takeoff_z: float | None = None,
                        sigmas: PriorSigmas | None = None) -> PhotoPrior:
    """The prior a photo states (module docstring).

    Args:
        meta: the photo's metadata.
        georef: the project frame's georeferencing.
        takeoff_z: project-frame height of the take-off point, m; with it the height is
            ``takeoff_z + RelativeAltitude``. None: the absolute altitude.
        sigmas: override of :func:`prior_sigmas`.

    Raises:
        PhotoError: naming everything the photo lacks for a prior.
    """
    missing = _missing(meta, takeoff_z)
    if missing:
        raise PhotoError(f"{meta.path}: no prior: the photo lacks {'; '.join(missing)}; give --prior "
                         "x,y,z,yaw,pitch,roll (project frame) instead")
    lat, lon = float(meta.latitude_deg), float(meta.longitude_deg)  # type: ignore[arg-type]
    alt = meta.absolute_altitude_m if takeoff_z is None else 0.0
    centre = georef.project_from_wgs84([[lat, lon, float(alt)]])[0]
    if takeoff_z is not None:
        centre[2] = takeoff_z + meta.dji["RelativeAltitude"]
    R = georef.project_from_enu(lat, lon) @ enu_from_cam_from_dji(*meta.gimbal_deg())  # type: ignore[misc]
    world_from_cam = np.eye(4)
    world_from_cam[:3, :3], world_from_cam[:3, 3] = R, centre
    auto, case = prior_sigmas(meta, relative_altitude=takeoff_z is not None)
    height = "take-off + RelativeAltitude" if takeoff_z is not None else "absolute altitude"
    return PhotoPrior(invert(world_from_cam), sigmas or auto,
                      f"GPS + {height} + DJI gimbal, {case}" + (", user sigmas" if sigmas else ""),
                      rtk_fixed=meta.dji.get("RtkFlag") == 50 and takeoff_z is None)


def prior_from_string(text: str, sigmas: PriorSigmas | None = None) -> PhotoPrior:
    """``"x,y,z,yaw,pitch,roll"`` (project frame, m and degrees; module docstring) as a prior.

    Raises:
        PhotoError: not six finite numbers.
    """
    try:
        values = [float(v) for v in str(text).split(",")]
    except ValueError:
        values = []
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise PhotoError(f"--prior must be x,y,z,yaw,pitch,roll (6 numbers: m, degrees), got {text!r}")
    x, y, z, yaw, pitch, roll = values
    T = world_from_cam_from_attitude((x, y, z), np.radians([roll, pitch, yaw]))
    source = "--prior" + (", user sigmas" if sigmas else "")
    return PhotoPrior(invert(T), sigmas or _sigmas(*CONSUMER_M), source)
