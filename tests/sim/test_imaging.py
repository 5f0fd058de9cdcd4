import numpy as np
import pytest

import uav_struct_env
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.imaging import ImagingModel, make_imaging


def _square(size=(72, 128)):
    img = np.full((*size, 3), 40, np.uint8)
    img[30:42, 50:70] = 220
    return img


def test_ideal_is_a_pass_through():
    img = _square()
    assert make_imaging("ideal").apply(img, np.random.default_rng(0)) is img


def test_camera_effects_are_seeded_and_keep_geometry():
    img = _square((360, 640))
    cam = make_imaging("camera")
    a = cam.apply(img, np.random.default_rng(1))
    b = cam.apply(img, np.random.default_rng(1))
    np.testing.assert_array_equal(a, b)
    assert a.dtype == np.uint8 and a.shape == img.shape
    assert np.abs(a.astype(int) - img).mean() > 0.5  # it did something
    # the bright square's intensity centroid does not move (symmetric blur, zero-mean noise)
    def centroid(x):
        w = np.clip(x.mean(axis=2) - 100, 0, None)
        rows, cols = np.indices(w.shape)
        return np.array([(cols * w).sum(), (rows * w).sum()]) / w.sum()
    np.testing.assert_allclose(centroid(a), centroid(img), atol=0.1)


def test_blur_scales_with_image_width():
    model = ImagingModel("blur", blur_sigma_px=3.0, read_noise_dn=0, shot_noise_gain=0, jpeg_quality=None)

    def edge_width(width):
        img = np.full((16, width, 3), 20, np.uint8)
        img[:, width // 2 :] = 220
        row = model.apply(img, np.random.default_rng(0))[8, :, 0].astype(float)
        return np.count_nonzero((row > 40) & (row < 200))  # 10 %-90 % rise, px

    small, large = edge_width(256), edge_width(1280)
    assert large > 2 and 4 <= large / max(small, 1) <= 6


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(blur_sigma_px=-1.0), r"imaging blur_sigma_px must be finite and >= 0, got -1\.0"),
        (dict(jpeg_quality=0), r"imaging jpeg_quality \(or None\) must be an int in \[1, 100\], got 0"),
        (dict(read_noise_dn=float("nan")), r"imaging read_noise_dn must be finite and >= 0, got nan"),
    ],
)
def test_bad_imaging_parameters_raise(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        ImagingModel(**kwargs)


def test_env_applies_imaging_only_to_the_image():
    kw = dict(image_size=(128, 72), renderer="tiny", stage="columns")
    ideal = uav_struct_env.parallel_env(**kw)
    cam = uav_struct_env.parallel_env(imaging="camera", **kw)
    try:
        o1, i1 = ideal.reset(seed=0, options={"viewpoint": 0})
        o2, i2 = cam.reset(seed=0, options={"viewpoint": 0})
        assert not np.array_equal(o1["uav_0"]["image"], o2["uav_0"]["image"])
        np.testing.assert_array_equal(o1["uav_0"]["gnss"], o2["uav_0"]["gnss"])
        np.testing.assert_array_equal(
            i1["uav_0"]["landmarks"]["column_tops"]["uv"], i2["uav_0"]["landmarks"]["column_tops"]["uv"]
        )
    finally:
        ideal.close()
        cam.close()
    with pytest.raises(ConfigError, match=r"imaging must be one of \['camera', 'ideal'\].*got 'film'"):
        uav_struct_env.parallel_env(imaging="film")
