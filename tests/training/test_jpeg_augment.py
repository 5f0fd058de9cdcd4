"""JPEG augmentation of the refiner's training windows: real libjpeg artefacts, off by default."""

from __future__ import annotations

import numpy as np
import pytest

from uav_struct_env.errors import ConfigError
from uav_struct_env.training.jpeg_augment import JpegAugment, encode_jpeg


def _edges(h: int = 48, w: int = 48) -> np.ndarray:
    """A red square on grey with a blue bar: colour edges that chroma subsampling smears."""
    img = np.full((h, w, 3), 128, np.uint8)
    img[10:30, 13:33] = (200, 30, 30)
    img[35:40, 5:40] = (20, 40, 210)
    return img


def test_quality_and_chroma_change_the_pixels_as_libjpeg_does():
    img = _edges()
    e444 = np.abs(encode_jpeg(img, 100, "4:4:4").astype(int) - img).mean()
    e420 = np.abs(encode_jpeg(img, 100, "4:2:0").astype(int) - img).mean()
    e80 = np.abs(encode_jpeg(img, 80, "4:2:0").astype(int) - img).mean()
    assert e444 < 0.5 < e420 < e80, (e444, e420, e80)


@pytest.mark.parametrize("chroma", ["4:4:4", "4:2:2", "4:2:0"])
@pytest.mark.parametrize("quality", [80, 95, 100])
def test_opencv_gives_pillows_pixels(quality, chroma):
    """The augmentation (OpenCV) makes the JPEG Pillow would make and decodes it as Pillow does."""
    import io

    from PIL import Image

    from uav_struct_env.training.jpeg_augment import CHROMA_SUBSAMPLING

    img = np.random.default_rng(quality).integers(0, 256, (53, 61, 3), dtype=np.uint8)
    img[10:30, 13:33] = (200, 30, 30)
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, "JPEG", quality=quality, subsampling=CHROMA_SUBSAMPLING[chroma])
    with Image.open(io.BytesIO(buf.getvalue())) as im:
        pillow = np.asarray(im.convert("RGB"))
    out = encode_jpeg(img, quality, chroma)
    assert out.dtype == np.uint8 and out.flags.c_contiguous
    np.testing.assert_array_equal(out, pillow)


def test_the_grid_phase_moves_the_artefacts_and_keeps_the_size():
    img = _edges()
    a = encode_jpeg(img, 85, "4:2:0", (0, 0))
    b = encode_jpeg(img, 85, "4:2:0", (5, 11))
    assert a.shape == b.shape == img.shape
    assert not np.array_equal(a, b)


def test_probability_zero_returns_the_image_and_one_always_compresses():
    img = _edges()
    rng = np.random.default_rng(0)
    assert JpegAugment(probability=0.0)(img, rng) is img
    out = JpegAugment(probability=1.0, quality=(90, 90), chroma=("4:2:2",))(img, rng)
    assert out.shape == img.shape and not np.array_equal(out, img)


@pytest.mark.parametrize("kwargs, match", [
    ({"probability": 1.5}, "probability"),
    ({"quality": (90, 80)}, "low <= high"),
    ({"quality": (0, 80)}, "quality"),
    ({"chroma": ("4:1:1",)}, "chroma"),
])
def test_bad_settings_are_refused(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        JpegAugment(**kwargs)


def test_refiner_samples_unchanged_without_jpeg_and_compressed_with_it():
    torch = pytest.importorskip("torch")
    from uav_struct_env.training.train_refiner import WINDOW, PatchSamples, parse_jpeg

    rng = np.random.default_rng(3)
    windows = np.repeat(_edges(WINDOW, WINDOW)[None], 4, axis=0)
    windows = np.clip(windows.astype(int) + rng.integers(-3, 4, windows.shape), 0, 255).astype(np.uint8)
    arrays = {"windows": windows, "offsets": np.zeros((4, 3, 2), np.float32),
              "kind": np.zeros(4, np.int8)}
    plain = [PatchSamples(arrays, seed=1)[k][0] for k in range(4)]
    again = [PatchSamples(arrays, seed=1, jpeg=None)[k][0] for k in range(4)]
    assert all(torch.equal(a, b) for a, b in zip(plain, again, strict=True))
    jpeg = [PatchSamples(arrays, seed=1, jpeg=parse_jpeg("1,80,80"))[k][0] for k in range(4)]
    assert all(a.shape == b.shape and not torch.equal(a, b) for a, b in zip(plain, jpeg, strict=True))
    assert parse_jpeg("0.75,80,100") == JpegAugment(0.75, (80, 100))
    from uav_struct_env.errors import UsageError

    for bad in ("0.5,80", "x,80,100", "0.5,90,80"):
        with pytest.raises(UsageError, match="--jpeg must be P,QLO,QHI"):
            parse_jpeg(bad)
