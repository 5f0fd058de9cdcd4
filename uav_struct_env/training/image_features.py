"""Image features for a policy from small camera frames: where things are, not only what is there.

SB3 gives a dict observation's image to NatureCNN, made for 84 x 84 Atari frames: on the 64 x 36
frames the pixel configurations train on, its 8 x 8 / 4 x 4 / 3 x 3 convolutions with strides 4
and 2 leave a 1 x 4 map, so the place of the building in the frame (what a viewpoint policy has
to act on: the ``state`` policies' layout features say where the landmarks lie in the image)
survives only as far as the channels happen to encode it. :class:`KeypointCNN` keeps a 9 x 16 map
(a 5 x 5 convolution with stride 2, a 3 x 3 with stride 2, a 3 x 3 with stride 1) and reads it with
a *spatial softmax* (Levine, Finn, Darrell and Abbeel, "End-to-End Training of Deep Visuomotor
Policies", JMLR 2016): each channel's expected image position under a softmax over its map, a
learned keypoint in normalized coordinates, beside each channel's mean activation (how much of
it is in view).

:class:`KeypointExtractor` is the dict-observation extractor SB3's ``CombinedExtractor`` would
be with :class:`KeypointCNN` in place of NatureCNN: image keys through it, other keys flattened,
all concatenated. The asymmetric actor-critic builds it for its actor and critic
(``image_net="keypoints"``, :class:`~uav_struct_env.training.asymmetric.AsymmetricActorCriticPolicy`).
"""

from __future__ import annotations

import torch
from gymnasium import spaces
from stable_baselines3.common.preprocessing import get_flattened_obs_dim, is_image_space
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

__all__ = ["KeypointCNN", "KeypointExtractor", "SpatialSoftmax"]


class SpatialSoftmax(nn.Module):
    """(B, C, H, W) feature maps -> (B, 2 C) expected ``(x, y)`` of each channel, in [-1, 1].

    A softmax over each channel's H x W activations (divided by a learned temperature, started at
    1) weights the pixel centres' normalized coordinates (-1 the left / top edge's first centre,
    +1 the last); the output is ``[x_0, y_0, x_1, y_1, ...]``.
    """

    def __init__(self, height: int, width: int) -> None:
        super().__init__()
        ys, xs = torch.meshgrid(torch.linspace(-1.0, 1.0, height), torch.linspace(-1.0, 1.0, width),
                                indexing="ij")
        self.register_buffer("grid", torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=1))  # (H W, 2)
        self.log_temperature = nn.Parameter(torch.zeros(()))

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        """The keypoints of ``maps``."""
        b, c, h, w = maps.shape
        weights = torch.softmax(maps.reshape(b, c, h * w) / self.log_temperature.exp(), dim=-1)
        return (weights @ self.grid).reshape(b, 2 * c)


class KeypointCNN(nn.Module):
    """A small-frame CNN read out as keypoints and mean activations (module docstring).

    Args:
        observation_space: a channel-first image space (C, H, W), as SB3 hands images on.
        features_dim: width of the output.
        channels: channels of the convolutions (the keypoints are as many).

    Raises:
        ValueError: for a space that is not a channel-first image at least 8 px each way.
    """

    def __init__(self, observation_space: spaces.Box, features_dim: int = 256, channels: int = 32) -> None:
        shape = getattr(observation_space, "shape", ())
        if len(shape) != 3 or min(shape[1:]) < 8 or shape[0] > 4:
            raise ValueError(f"KeypointCNN needs a channel-first image space (C <= 4, H and W >= 8 px), "
                             f"got shape {shape}")
        super().__init__()
        self.conv = nn.Sequential(
            nn.Conv2d(shape[0], channels, 5, stride=2, padding=2), nn.ReLU(),
            nn.Conv2d(channels, channels, 3, stride=2, padding=1), nn.ReLU(),
            nn.Conv2d(channels, channels, 3, stride=1, padding=1),
        )
        with torch.no_grad():
            _, _, h, w = self.conv(torch.zeros(1, *shape)).shape
        self.keypoints = SpatialSoftmax(h, w)
        self.head = nn.Sequential(nn.Linear(3 * channels, features_dim), nn.ReLU())
        self.features_dim = features_dim

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """Features of (B, C, H, W) images scaled to [0, 1] (SB3's preprocessing does that)."""
        maps = self.conv(images)
        pooled = torch.relu(maps).mean(dim=(2, 3))
        return self.head(torch.cat([self.keypoints(maps), pooled], dim=1))


class KeypointExtractor(BaseFeaturesExtractor):
    """SB3's ``CombinedExtractor`` with :class:`KeypointCNN` for image keys (module docstring).

    Args:
        observation_space: a ``spaces.Dict``.
        cnn_output_dim: each image's features width.
    """

    def __init__(self, observation_space: spaces.Dict, cnn_output_dim: int = 256) -> None:
        super().__init__(observation_space, features_dim=1)
        extractors: dict[str, nn.Module] = {}
        width = 0
        for key, space in observation_space.spaces.items():
            if is_image_space(space, normalized_image=False):
                extractors[key] = KeypointCNN(space, cnn_output_dim)
                width += cnn_output_dim
            else:
                extractors[key] = nn.Flatten()
                width += get_flattened_obs_dim(space)
        self.extractors = nn.ModuleDict(extractors)
        self._features_dim = width

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        """The concatenated features of every key."""
        return torch.cat([net(observations[key]) for key, net in self.extractors.items()], dim=1)
