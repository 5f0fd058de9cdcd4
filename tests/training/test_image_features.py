"""The keypoint image network: where a channel's activation peaks, read out as coordinates."""

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import torch  # noqa: E402
from gymnasium import spaces  # noqa: E402

from uav_struct_env.errors import ConfigError  # noqa: E402
from uav_struct_env.training.asymmetric import AsymmetricActorCriticPolicy  # noqa: E402
from uav_struct_env.training.image_features import KeypointCNN, KeypointExtractor, SpatialSoftmax  # noqa: E402
from uav_struct_env.wrappers.configs import TRAIN_CONFIGS, TrainConfig  # noqa: E402

IMAGE = spaces.Box(0, 255, (3, 36, 64), np.uint8)  # channel-first, as SB3 hands images on


@pytest.mark.parametrize("row, col", [(0, 0), (8, 15), (4, 11), (2, 3)])
def test_the_spatial_softmax_finds_each_channels_peak_in_normalized_coordinates(row, col):
    maps = torch.zeros(2, 3, 9, 16)
    maps[0, 1, row, col] = 40.0  # one sharp peak in channel 1 of the first map
    out = SpatialSoftmax(9, 16)(maps)
    assert out.shape == (2, 6)
    x, y = out[0, 2:4].tolist()
    assert x == pytest.approx(-1 + 2 * col / 15, abs=1e-6) and y == pytest.approx(-1 + 2 * row / 8, abs=1e-6)
    torch.testing.assert_close(out[1], torch.zeros(6), atol=1e-6, rtol=0)  # a flat map: the centre


def test_the_keypoint_cnn_keeps_a_map_and_refuses_what_is_no_channel_first_image():
    net = KeypointCNN(IMAGE, features_dim=40)
    assert net.keypoints.grid.shape == (9 * 16, 2)  # a 9 x 16 map, not NatureCNN's 1 x 4
    assert net(torch.rand(5, 3, 36, 64)).shape == (5, 40)
    with pytest.raises(ValueError, match=r"channel-first image space .* got shape \(36, 64, 3\)"):
        KeypointCNN(spaces.Box(0, 255, (36, 64, 3), np.uint8))
    extractor = KeypointExtractor(spaces.Dict({"image": IMAGE, "gnss": spaces.Box(-1, 1, (3,), np.float32)}))
    assert extractor.features_dim == 256 + 3


def test_the_policy_moves_with_the_images_content_and_names_a_bad_network():
    space = spaces.Dict({"image": IMAGE, "gnss": spaces.Box(-1, 1, (3,), np.float32),
                         "pose": spaces.Box(-1, 1, (6,), np.float32)})
    actions = spaces.Box(-1.0, 1.0, (5,), np.float32)
    torch.manual_seed(0)
    policy = AsymmetricActorCriticPolicy(space, actions, lambda _: 3e-4, actor_keys=("image", "gnss"),
                                         image_net="keypoints", net_arch=[16, 16])
    assert not any(isinstance(m, torch.nn.Conv2d) and m.kernel_size == (8, 8) for m in policy.modules())
    rng = np.random.default_rng(3)
    obs = {k: rng.uniform(0, 255 if k == "image" else 1, (2, *s.shape)).astype(s.dtype)
           for k, s in space.spaces.items()}
    a, _ = policy.predict(obs, deterministic=True)
    b, _ = policy.predict({**obs, "pose": -obs["pose"]}, deterministic=True)
    c, _ = policy.predict({**obs, "image": np.roll(obs["image"], 20, axis=3)}, deterministic=True)
    np.testing.assert_array_equal(a, b)  # the critic's key does not reach the actions
    assert not np.array_equal(a, c)  # the image's content moved: the actions do
    with pytest.raises(ValueError, match=r"image_net must be one of \['nature', 'keypoints'\], got 'resnet'"):
        AsymmetricActorCriticPolicy(space, actions, lambda _: 3e-4, actor_keys=("image",), image_net="resnet")


def test_the_configuration_records_its_image_network():
    config = TRAIN_CONFIGS["pixels_keypoints"]
    assert config.as_dict()["image_net"] == "keypoints"
    assert TrainConfig.from_dict(config.as_dict()) == config
    assert "image_net" not in TRAIN_CONFIGS["pixels_critic"].as_dict()  # as recorded before
    with pytest.raises(ConfigError, match=r"image_net must be one of .* 'keypoints' with actor_keys \[\]"):
        TrainConfig("x", image_net="keypoints")
    with pytest.raises(ConfigError, match="image_net"):
        TrainConfig.from_dict({**config.as_dict(), "image_net": 3})
