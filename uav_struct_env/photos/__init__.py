"""Real drone photos localized against an IFC model (``uav-struct localize``), pure of pybullet.

inputs (:mod:`.metadata`, :mod:`.calibration`, :mod:`.georef`, :mod:`.orientation`) -> prior
(:mod:`.attitude`, :mod:`.prior`) -> :mod:`.localize` -> outputs (:mod:`.overlay`, :mod:`.command`);
:mod:`.dji_jpeg` writes DJI-style JPEGs for validation. pyproj is the ``photo`` extra.

from uav_struct_env.photos import localize_photos
poses = localize_photos(["DJI_0001.JPG"], "building.ifc", camera="calib.yaml")
poses[0].success, poses[0].cam_from_world, poses[0].covariance, poses[0].failure_reason
"""

from uav_struct_env.photos.calibration import CameraModel, camera_from_exif, load_calibration
from uav_struct_env.photos.errors import PhotoError
from uav_struct_env.photos.georef import Georeference, read_ifc_georeference
from uav_struct_env.photos.localize import PhotoPose, localize_photos, plan_photos, run_plan
from uav_struct_env.photos.metadata import PhotoMetadata, parse_dji_xmp, read_metadata
from uav_struct_env.photos.prior import PhotoPrior, prior_from_metadata

__all__ = [
    "CameraModel",
    "Georeference",
    "PhotoError",
    "PhotoMetadata",
    "PhotoPose",
    "PhotoPrior",
    "camera_from_exif",
    "load_calibration",
    "localize_photos",
    "parse_dji_xmp",
    "plan_photos",
    "prior_from_metadata",
    "read_ifc_georeference",
    "read_metadata",
    "run_plan",
]
