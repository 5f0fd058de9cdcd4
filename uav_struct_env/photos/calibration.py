"""A real camera's intrinsics: a calibration file, else the photo's EXIF (with a warning).

Calibration files read by :func:`load_calibration`:

* **OpenCV** ``FileStorage`` YAML/XML/JSON (``cv2.calibrateCamera`` results as written by OpenCV's
  samples): ``camera_matrix`` (or ``K``, ``cameraMatrix``) and ``distortion_coefficients`` (or
  ``D``, ``dist_coeffs``, ``distCoeffs``), optional ``image_width``/``image_height``. Plain JSON
  or ROS-style YAML with the same keys (a 3 x 3 list, or ``{rows, cols, data}``) is read too.
* **OpenDroneMap / OpenSfM** ``cameras.json``: ``{"<camera id>": {"projection_type": "brown" |
  "perspective", "width", "height", "focal_x", "focal_y", "c_x", "c_y", "k1", "k2", "p1",
  "p2", "k3"}}`` with focal lengths and principal-point offsets normalized by ``max(width,
  height)`` and measured from the image centre; OpenSfM puts pixel centres at ``+0.5``, the
  project at integers, so ``cx = width / 2 - 0.5 + c_x * max(width, height)``. With several
  cameras in the file, the one whose size matches the photo is taken (else refused).

Distortion is OpenCV's ``(k1, k2, p1, p2, k3)`` (:mod:`localization.geometry.distortion`); 4
coefficients mean ``k3 = 0``; more than 5 are refused unless the extra ones are 0. A calibration
made at another resolution of the same aspect ratio is scaled to the photo.

Without a file, :func:`camera_from_exif` takes, in order: DJI's ``CalibratedFocalLength`` and
``CalibratedOpticalCenterX/Y`` (px, written by some models), EXIF ``FocalLength`` with the
sensor width of a known DJI camera (:data:`SENSOR_WIDTH_MM`), or ``FocalLengthIn35mmFilm``
(35 mm equivalent over the 43.27 mm diagonal); principal point at the image centre, no
distortion. It warns: uncalibrated intrinsics limit the accuracy.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localization.geometry.distortion import check_distortion
from localization.geometry.transforms import check_intrinsics, scaled_intrinsics
from uav_struct_env.photos.errors import PhotoError
from uav_struct_env.photos.metadata import PhotoMetadata
from uav_struct_env.photos.orientation import turn_camera, upright_turns

__all__ = ["SENSOR_WIDTH_MM", "CameraModel", "camera_from_exif", "load_calibration", "resolve_camera"]

#: Sensor widths of DJI cameras by EXIF Model, mm (from DJI's published specifications).
SENSOR_WIDTH_MM = {
    "FC6310": 13.2, "FC6310S": 13.2, "FC6310R": 13.2, "L1D-20c": 13.2,  # 1" sensors
    "FC220": 6.17, "FC330": 6.17, "FC300X": 6.17,  # 1/2.3" sensors
    "FC6520": 17.3, "FC6540": 23.5,  # Zenmuse X5S (4/3"), X7 (APS-C)
}
#: The 35 mm film frame's diagonal, mm (EXIF FocalLengthIn35mmFilm refers to it).
DIAGONAL_35MM = math.hypot(36.0, 24.0)

_K_KEYS = ("camera_matrix", "K", "cameraMatrix", "intrinsic_matrix")
_D_KEYS = ("distortion_coefficients", "D", "dist_coeffs", "distCoeffs", "distortion")


@dataclass(frozen=True, eq=False)
class CameraModel:
    """A photo's camera: intrinsics, distortion, the image size they hold for, where they came from.

    Attributes:
        K: (3, 3) intrinsics, px (pixel centres at integers).
        distortion: (5,) OpenCV ``(k1, k2, p1, p2, k3)``.
        image_size: (W, H), px.
        source: where the numbers came from (a file, ``"EXIF ..."``).
        calibrated: False for intrinsics guessed from EXIF.
    """

    K: NDArray[np.float64]
    distortion: NDArray[np.float64]
    image_size: tuple[int, int]
    source: str
    calibrated: bool = True


def _matrix(value: Any) -> NDArray[np.float64] | None:
    if value is None:
        return None
    if isinstance(value, dict) and "data" in value:
        value = np.asarray(value["data"], dtype=np.float64).reshape(int(value.get("rows", 3)), -1)
    return np.asarray(value, dtype=np.float64)


def _first(d: dict, keys: tuple[str, ...]) -> Any:
    return next((d[k] for k in keys if k in d), None)


def _coefficients(name: str, d: Any) -> NDArray[np.float64]:
    c = np.zeros(5) if d is None else np.asarray(d, dtype=np.float64).reshape(-1)
    if c.size == 4:
        c = np.append(c, 0.0)
    if c.size > 5 and np.any(c[5:] != 0):
        raise PhotoError(f"{name}: {c.size} distortion coefficients with non-zero rational/prism terms; "
                         "expected OpenCV's 4 or 5 (k1, k2, p1, p2[, k3])")
    return check_distortion(name, c[:5])


def _size(d: dict) -> tuple[int, int] | None:
    w, h = d.get("image_width", d.get("width")), d.get("image_height", d.get("height"))
    if w is None or h is None:
        size = d.get("image_size")
        return None if size is None else (int(size[0]), int(size[1]))
    return int(w), int(h)


def _from_mapping(name: str, d: dict) -> tuple[NDArray, NDArray, tuple[int, int] | None]:
    K = _matrix(_first(d, _K_KEYS))
    if K is None:
        raise PhotoError(f"{name}: no camera matrix (expected one of the keys {_K_KEYS})")
    try:
        K = check_intrinsics(f"{name} camera matrix", K)
    except (TypeError, ValueError) as err:
        raise PhotoError(str(err)) from None
    return K, _coefficients(name, _matrix(_first(d, _D_KEYS))), _size(d)


def _odm(name: str, cameras: dict, photo_size: tuple[int, int]) -> tuple[NDArray, NDArray, tuple[int, int]]:
    """One camera of an OpenDroneMap/OpenSfM cameras.json (module docstring)."""
    fitting = [c for c in cameras.values() if (int(c.get("width", 0)), int(c.get("height", 0))) == photo_size]
    if len(cameras) > 1 and len(fitting) != 1:
        raise PhotoError(f"{name}: {len(cameras)} cameras and {len(fitting)} of size {photo_size}; "
                         "expected exactly one camera of the photo's size")
    c = fitting[0] if fitting else next(iter(cameras.values()))
    kind = c.get("projection_type")
    if kind not in ("brown", "perspective"):
        raise PhotoError(f"{name}: projection_type {kind!r} is not supported; expected 'brown' or "
                         "'perspective'")
    try:
        w, h = int(c["width"]), int(c["height"])
        size = max(w, h)
        fx = float(c.get("focal_x", c.get("focal"))) * size
        fy = float(c.get("focal_y", c.get("focal"))) * size
        cx = w / 2 - 0.5 + float(c.get("c_x", 0.0)) * size
        cy = h / 2 - 0.5 + float(c.get("c_y", 0.0)) * size
        d = [float(c.get(k, 0.0)) for k in ("k1", "k2", "p1", "p2", "k3")]
    except (KeyError, TypeError, ValueError) as err:
        raise PhotoError(f"{name}: an OpenDroneMap camera needs width, height and focal: {err}") from None
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return check_intrinsics(f"{name} camera matrix", K), _coefficients(name, d), (w, h)


def _read_opencv(path: Path) -> dict:
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error:
        return {}
    try:
        if not fs.isOpened():
            return {}
        out: dict[str, Any] = {}
        for key in (*_K_KEYS, *_D_KEYS, "image_width", "image_height"):
            node = fs.getNode(key)
            if not node.empty():
                out[key] = node.real() if key.startswith("image_") else node.mat()
        return out
    finally:
        fs.release()


def _read_file(path: Path) -> Any:
    text = path.read_text(errors="replace")
    if path.suffix.lower() == ".json":
        return json.loads(text)
    found = _read_opencv(path)
    if found:
        return found
    try:
        import yaml
    except ImportError:
        raise PhotoError(f"{str(path)!r} is not OpenCV FileStorage; plain YAML needs PyYAML") from None
    return yaml.safe_load(text)


def load_calibration(path: str | Path, photo_size: tuple[int, int], turns: int = 0) -> CameraModel:
    """The camera of a calibration file (module docstring), scaled to photos of ``photo_size``.

    ``turns``: the quarter turns the photo's EXIF orientation tag asks for
    (:func:`uav_struct_env.photos.orientation.upright_turns`). With an odd number, a calibration
    whose size has the upright image's aspect ratio (width and height swapped: made on images
    turned upright by their tag, as OpenCV's ``imread`` turns them) is turned back to the stored
    pixels' layout; a half turn keeps the size, so such a calibration is taken as stored.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        PhotoError: a file that does not parse, holds no camera matrix, bad numbers, or a size
            of another aspect ratio than the photo's.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"calibration file {str(path)!r} does not exist")
    name = f"calibration file {str(path)!r}"
    try:
        data = _read_file(path)
    except Exception as err:  # json, yaml and OpenCV each raise their own parse errors
        detail = " ".join(str(err).split())
        raise PhotoError(f"{name} does not parse ({type(err).__name__}: {detail})") from None
    if not isinstance(data, dict) or not data:
        raise PhotoError(f"{name} holds no camera (expected OpenCV, JSON or OpenDroneMap cameras.json)")
    if all(isinstance(v, dict) and "projection_type" in v for v in data.values()):
        K, dist, size = _odm(name, data, photo_size)
    else:
        K, dist, size = _from_mapping(name, data)
    upright_size = (photo_size[1], photo_size[0])
    turned = size is not None and not _same_aspect(size, photo_size) and _same_aspect(size, upright_size)
    if turns % 2 and turned:
        upright = _scaled(name, K, dist, size, upright_size, str(path))
        K, dist, _ = turn_camera(upright.K, upright.distortion, upright.image_size, -turns)
        return CameraModel(K, dist, tuple(photo_size), f"{upright.source} (upright layout, turned back by "
                           "the photo's EXIF orientation)")
    return _scaled(name, K, dist, size, photo_size, str(path))


def _same_aspect(size: tuple[int, int], other: tuple[int, int]) -> bool:
    """Whether images of ``size`` scale to ``other`` by one factor (to 1e-3)."""
    sx, sy = other[0] / size[0], other[1] / size[1]
    return abs(sx - sy) <= 1e-3 * max(sx, sy)


def _scaled(name: str, K: NDArray, dist: NDArray, size: tuple[int, int] | None,
            photo_size: tuple[int, int], source: str) -> CameraModel:
    """The camera at ``photo_size`` (a calibration at another size of the same aspect is scaled)."""
    if size is None or tuple(size) == tuple(photo_size):
        return CameraModel(K, dist, tuple(photo_size), source)
    sx, sy = photo_size[0] / size[0], photo_size[1] / size[1]
    if not _same_aspect(size, photo_size):
        raise PhotoError(f"{name} is for {size[0]} x {size[1]} images, the photo is {photo_size[0]} x "
                         f"{photo_size[1]}: another aspect ratio (crop or rotation); calibrate at the "
                         "photo's size")
    return CameraModel(scaled_intrinsics(K, sx, sy), dist, tuple(photo_size), f"{source} (scaled x{sx:g})")


def camera_from_exif(meta: PhotoMetadata) -> CameraModel:
    """Intrinsics from the photo's own metadata (module docstring); warns that they are uncalibrated.

    Raises:
        PhotoError: the photo states no focal length usable for intrinsics.
    """
    w, h = meta.image_size
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    if "CalibratedFocalLength" in meta.dji:
        f = meta.dji["CalibratedFocalLength"]
        cx = meta.dji.get("CalibratedOpticalCenterX", cx)
        cy = meta.dji.get("CalibratedOpticalCenterY", cy)
        how = "DJI CalibratedFocalLength"
    elif meta.focal_length_mm and meta.model in SENSOR_WIDTH_MM:
        f = meta.focal_length_mm / SENSOR_WIDTH_MM[meta.model] * w
        how = (f"EXIF FocalLength {meta.focal_length_mm:g} mm, {meta.model} sensor "
               f"{SENSOR_WIDTH_MM[meta.model]} mm")
    elif meta.focal_length_35mm:
        f = meta.focal_length_35mm * math.hypot(w, h) / DIAGONAL_35MM
        how = f"EXIF FocalLengthIn35mmFilm {meta.focal_length_35mm:g} mm"
    else:
        raise PhotoError(f"{meta.path}: no calibration file given (--camera) and the photo states no focal "
                         "length (EXIF FocalLength with a known DJI model, FocalLengthIn35mmFilm or DJI "
                         "CalibratedFocalLength)")
    warnings.warn(f"{meta.path.name}: intrinsics from {how} without distortion; uncalibrated intrinsics "
                  "limit the accuracy (give --camera with a calibration file)", stacklevel=2)
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    return CameraModel(check_intrinsics("EXIF intrinsics", K), np.zeros(5), (w, h), f"EXIF: {how}", False)


def resolve_camera(calibration: str | Path | CameraModel | None, meta: PhotoMetadata) -> CameraModel:
    """A :class:`CameraModel` as given, from a calibration file, or from EXIF (None)."""
    if isinstance(calibration, CameraModel):
        if tuple(calibration.image_size) != tuple(meta.image_size):
            return _scaled("camera", calibration.K, calibration.distortion, calibration.image_size,
                           meta.image_size, calibration.source)
        return calibration
    if calibration is None:
        return camera_from_exif(meta)
    return load_calibration(calibration, meta.image_size, upright_turns(meta.orientation, str(meta.path)))
