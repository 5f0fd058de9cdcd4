"""Camera imaging effects applied to rendered frames: optics blur, sensor noise, compression.

The renderers produce ideal images: every texel sharp, no noise, no compression. A real UAV
camera frame is not: lens and demosaicing blur, photon and read noise, and the video encoder's
compression all hide fine detail — the cells of a small ArUco marker 40 m away are 2–3 px wide.
:class:`ImagingModel` adds those effects, seeded from the environment's generator, so that
pixel-reading detectors (ArUco, the learned detector) can be evaluated on less flattering
images. Geometry is unchanged (the blur is symmetric, so no feature moves).

Presets (``make_imaging``): ``"ideal"`` — no effects (the default of every env preset);
``"camera"`` — the defaults below. They are plausible values for a 1280×720 frame taken from a
1-inch-sensor camera's compressed video stream (DJI Mavic 2 Pro class), chosen by us, not
measured on that camera: Gaussian optics + demosaicing blur of 0.7 px, read noise of 2 DN and
shot noise of variance 0.05 DN per DN (8-bit), JPEG quality 80 standing in for H.264/H.265
compression. Blur is specified at 1280 px width and scaled with the image width.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from localization.checks import check_number
from uav_struct_env.errors import ConfigError
from uav_struct_env.named import resolve_named

__all__ = ["FORMER_IMAGING_NAMES", "IMAGING_PRESETS", "ImagingModel", "imaging_argument", "make_imaging"]

_REFERENCE_WIDTH = 1280


@dataclass(frozen=True)
class ImagingModel:
    """Blur, noise and compression applied to an RGB uint8 frame.

    Attributes:
        name: preset name, for reports.
        blur_sigma_px: Gaussian blur sigma at 1280 px image width (scaled with the width); 0 off.
        read_noise_dn: standard deviation of signal-independent noise, 8-bit DN; 0 off.
        shot_noise_gain: signal-dependent noise variance per DN of signal; 0 off.
        jpeg_quality: JPEG quality 1–100 for a compression round trip, or None for none.
    """

    name: str = "camera"
    blur_sigma_px: float = 0.7
    read_noise_dn: float = 2.0
    shot_noise_gain: float = 0.05
    jpeg_quality: int | None = 80

    def __post_init__(self) -> None:
        for field in ("blur_sigma_px", "read_noise_dn", "shot_noise_gain"):
            check_number(f"imaging {field}", getattr(self, field), 0,
                         error=ConfigError, type_error=ConfigError)
        if self.jpeg_quality is not None:
            check_number("imaging jpeg_quality (or None)", self.jpeg_quality, 1, 100, integer=True,
                         error=ConfigError, type_error=ConfigError)

    @property
    def is_ideal(self) -> bool:
        """True when the model changes nothing."""
        return (
            self.blur_sigma_px == 0
            and self.read_noise_dn == 0
            and self.shot_noise_gain == 0
            and self.jpeg_quality is None
        )

    def apply(self, rgb: NDArray[np.uint8], rng: np.random.Generator) -> NDArray[np.uint8]:
        """The degraded frame (a new array); ``rgb`` is (H, W, 3) uint8 and is not modified."""
        if self.is_ideal:
            return rgb
        img = rgb.astype(np.float32)
        sigma = self.blur_sigma_px * rgb.shape[1] / _REFERENCE_WIDTH
        if sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), sigma)
        if self.read_noise_dn > 0 or self.shot_noise_gain > 0:
            std = np.sqrt(self.read_noise_dn**2 + self.shot_noise_gain * img)
            img += std * rng.standard_normal(img.shape, dtype=np.float32)
        out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        if self.jpeg_quality is not None:
            ok, buf = cv2.imencode(".jpg", out[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
            if not ok:  # pragma: no cover - OpenCV always encodes a valid uint8 image
                raise RuntimeError("JPEG encoding failed")
            out = np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1])
        return out


IMAGING_PRESETS: dict[str, ImagingModel] = {
    "ideal": ImagingModel("ideal", 0.0, 0.0, 0.0, None),
    "camera": ImagingModel(),
}


#: Imaging names the docs once used, and the settings they meant (refused, naming these).
FORMER_IMAGING_NAMES = {
    "realistic": "camera mavic2pro with imaging camera (--camera mavic2pro --imaging camera)",
}


def _former(name: object) -> str | None:
    if isinstance(name, str) and name in FORMER_IMAGING_NAMES:
        return (f"imaging {name!r} is not a setting: it was the docs' name for "
                f"{FORMER_IMAGING_NAMES[name]}; imaging is one of {sorted(IMAGING_PRESETS)}")
    return None


def imaging_argument(text: str) -> str:
    """The ``--imaging`` value of a command line (an ``argparse`` ``type``).

    A former name is refused with a line naming the settings it meant.
    """
    import argparse

    why = _former(text)
    if why is not None:
        raise argparse.ArgumentTypeError(why)
    return text


def make_imaging(imaging: str | ImagingModel) -> ImagingModel:
    """Resolve a preset name or pass an :class:`ImagingModel` through.

    Raises:
        ConfigError: for an unknown name (a former one: naming what it meant) or another type.
    """
    why = _former(imaging)
    if why is not None:
        raise ConfigError(why)
    return resolve_named("imaging", imaging, IMAGING_PRESETS, ImagingModel, "an ImagingModel")
