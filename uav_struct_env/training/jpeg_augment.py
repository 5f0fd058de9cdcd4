"""JPEG compression as a training augmentation: the artefacts of a camera's JPEG on a rendered image.

Drone cameras store JPEGs: 8 x 8 block quantization of the luma and chroma, and chroma subsampled
2:1 horizontally (4:2:2, DJI's Phantom 4 camera, ``tests/data/photos/README.md``) or in both
directions (4:2:0, most encoders' default). The learned detector's patch refiner places corners to
a fraction of a pixel from colour and luma edges, and both are what a JPEG degrades
(``benchmarks/photo_jpeg_gap.py``). :class:`JpegAugment` encodes an image with libjpeg
at a random quality and chroma subsampling and decodes it again, with the block grid at a random
phase: a landmark lies anywhere relative to a real photo's 8 x 8 (16 x 16 with 4:2:0) grid, while
a training window's centre is always at the same offset from its corner.

Off by default everywhere (no committed weights were trained with it: the refiners tried with it
for photos are in ``localization/detect/models/MODEL_CARD.md``, none adopted); the refiner's
trainer takes it as ``--jpeg`` (:mod:`uav_struct_env.training.train_refiner`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.checks import check_number
from uav_struct_env.errors import ConfigError

__all__ = ["CHROMA_SUBSAMPLING", "JpegAugment", "encode_jpeg"]

#: Pillow's ``subsampling`` code of each chroma layout.
CHROMA_SUBSAMPLING = {"4:4:4": 0, "4:2:2": 1, "4:2:0": 2}
#: OpenCV's ``IMWRITE_JPEG_SAMPLING_FACTOR`` of each chroma layout (luma sampling per component).
_SAMPLING_FACTOR = {"4:4:4": 0x111111, "4:2:2": 0x211111, "4:2:0": 0x221111}
#: The largest JPEG grid period (a 4:2:0 minimum coded unit), px.
_MCU = 16


@dataclass(frozen=True)
class JpegAugment:
    """JPEG-compress a fraction of the training images (module docstring).

    Attributes:
        probability: the fraction of images compressed (the rest stay lossless).
        quality: ``(low, high)`` JPEG quality, drawn uniformly (integers, both included).
        chroma: the chroma layouts drawn from, uniformly (keys of :data:`CHROMA_SUBSAMPLING`).
    """

    probability: float = 0.75
    quality: tuple[int, int] = (80, 100)
    chroma: tuple[str, ...] = ("4:4:4", "4:2:2", "4:2:0")

    def __post_init__(self) -> None:
        check_number("JpegAugment.probability", self.probability, 0.0, 1.0, error=ConfigError,
                     type_error=ConfigError)
        lo, hi = self.quality
        for q in (lo, hi):
            check_number("JpegAugment.quality", q, 1, 100, integer=True, error=ConfigError,
                         type_error=ConfigError)
        if lo > hi:
            raise ConfigError(f"JpegAugment.quality must be (low, high) with low <= high, got "
                              f"{self.quality!r}")
        unknown = [c for c in self.chroma if c not in CHROMA_SUBSAMPLING]
        if unknown or not self.chroma:
            raise ConfigError(f"JpegAugment.chroma must be among {tuple(CHROMA_SUBSAMPLING)}, got "
                              f"{self.chroma!r}")

    def __call__(self, image: NDArray[np.uint8], rng: np.random.Generator) -> NDArray[np.uint8]:
        """The (H, W, 3) uint8 image JPEG-compressed with probability :attr:`probability`, else itself.

        The image is padded at its top and left by a random 0-15 px (edge pixels repeated) before
        encoding and the padding cut off after decoding, so the block grid falls at a random phase.
        """
        if rng.random() >= self.probability:
            return image
        quality = int(rng.integers(self.quality[0], self.quality[1] + 1))
        chroma = self.chroma[int(rng.integers(len(self.chroma)))]
        top, left = (int(v) for v in rng.integers(0, _MCU, 2))
        return encode_jpeg(image, quality, chroma, (top, left))


def encode_jpeg(image: NDArray[np.uint8], quality: int, chroma: str = "4:2:0",
                phase: tuple[int, int] = (0, 0)) -> NDArray[np.uint8]:
    """``image`` (H, W, 3) uint8 RGB after a JPEG round trip at ``quality`` with ``chroma`` subsampling.

    ``phase = (top, left)``: the block grid starts that many pixels above and left of the image.
    Encoded and decoded by OpenCV's libjpeg: the same pixels as Pillow's encoder and decoder at
    the same settings (Pillow reads the photos in :mod:`uav_struct_env.photos`;
    tests/training/test_jpeg_augment.py checks the two agree), four times faster on a training
    window.
    """
    import cv2

    top, left = phase
    padded = np.pad(image, ((top, 0), (left, 0), (0, 0)), mode="edge") if top or left else image
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(padded[..., ::-1]),
                           [cv2.IMWRITE_JPEG_QUALITY, int(quality),
                            cv2.IMWRITE_JPEG_SAMPLING_FACTOR, _SAMPLING_FACTOR[chroma]])
    if not ok:
        raise ValueError(f"OpenCV could not JPEG-encode an image of shape {image.shape}")
    out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1]
    return np.ascontiguousarray(out[top:, left:])
