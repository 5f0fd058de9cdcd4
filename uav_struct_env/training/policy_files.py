"""A trained viewpoint policy's files, read back without unpickling anything from them.

``examples/train_viewpoint_ppo.py`` saves SB3's ``model.zip`` and ``vecnormalize.pkl`` (what SB3
itself reloads to resume training) and, beside them, ``normalization.npz``: the observation
statistics of ``VecNormalize`` as plain arrays (:func:`save_normalization`). Unpickling a file
runs whatever code it names, so a model folder from someone else must not be unpickled silently:

* :func:`load_normalization` reads ``normalization.npz`` with ``allow_pickle=False``;
* :func:`load_ppo` loads ``model.zip`` with every cloudpickled entry of its ``data`` replaced
  by an object built here (SB3's ``custom_objects``); the weights are read by ``torch.load``
  with ``weights_only=True`` (SB3's own default). An entry this module does not know is refused.

``vecnormalize.pkl`` is read only when the caller asks for it by name
(``examples/evaluate_policy.py --trust-pickle``, for folders written before ``normalization.npz``).

A checkpoint the trainer can resume from also holds ``resume.npz`` (:func:`save_rng_state`): the
random-number generators' states (torch, NumPy, Python) at the rollout boundary it was taken at.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uav_struct_env.outputs import atomic_path

__all__ = [
    "NORMALIZATION_FILE",
    "RESUME_FILE",
    "ObsNormalizer",
    "RngState",
    "capture_rng_state",
    "load_normalization",
    "load_ppo",
    "load_rng_state",
    "recorded_config",
    "restore_rng_state",
    "save_normalization",
    "save_rng_state",
    "train_json",
]

#: File name of the observation statistics beside ``model.zip``.
NORMALIZATION_FILE = "normalization.npz"

#: File name of a resumable checkpoint's random-number generator states.
RESUME_FILE = "resume.npz"


@dataclass(frozen=True)
class RngState:
    """The global random-number generators training draws from: torch, NumPy and Python's."""

    torch: np.ndarray
    numpy: tuple
    python: tuple


def capture_rng_state() -> RngState:
    """The current states of torch's, NumPy's and Python's global generators."""
    import random

    import torch

    return RngState(torch.get_rng_state().numpy().copy(), np.random.get_state(), random.getstate())


def restore_rng_state(state: RngState) -> None:
    """Set torch's, NumPy's and Python's global generators to ``state``."""
    import random

    import torch

    torch.set_rng_state(torch.from_numpy(state.torch.copy()))
    np.random.set_state(state.numpy)
    random.setstate(state.python)


def save_rng_state(state: RngState, path: str | Path) -> Path:
    """Write ``state`` as plain arrays (no pickle), atomically."""
    name, keys, pos, has_gauss, gauss = state.numpy
    version, internal, gauss_next = state.python
    path = Path(path)
    with atomic_path(path) as tmp:
        np.savez(tmp, torch=state.torch, numpy_name=np.str_(name), numpy_keys=keys,
                 numpy_rest=np.array([pos, has_gauss], dtype=np.int64), numpy_gauss=np.float64(gauss),
                 python_version=np.int64(version), python_internal=np.array(internal, dtype=np.int64),
                 python_gauss=np.float64(np.nan if gauss_next is None else gauss_next))
    return path


def load_rng_state(path: str | Path) -> RngState:
    """Read :func:`save_rng_state`'s file (no pickle).

    Raises:
        ValueError: the file is not such a file.
    """
    try:
        with np.load(path, allow_pickle=False) as z:
            pos, has_gauss = (int(v) for v in z["numpy_rest"])
            numpy_state = (str(z["numpy_name"]), z["numpy_keys"], pos, has_gauss, float(z["numpy_gauss"]))
            gauss = float(z["python_gauss"])
            python_state = (int(z["python_version"]), tuple(int(v) for v in z["python_internal"]),
                            None if np.isnan(gauss) else gauss)
            return RngState(z["torch"].astype(np.uint8), numpy_state, python_state)
    except (KeyError, ValueError, OSError) as err:
        raise ValueError(f"{str(path)!r} is not a resume file of train_viewpoint_ppo.py: {err}") from None


@dataclass(frozen=True, eq=False)
class ObsNormalizer:
    """``VecNormalize.normalize_obs`` from its statistics: ``clip((x - mean) / sqrt(var + eps))``.

    Attributes:
        mean: per observation key, the running mean (the key's shape).
        var: per observation key, the running variance.
        clip_obs: normalized values are clipped to ``[-clip_obs, clip_obs]``.
        epsilon: added to the variance.
    """

    mean: dict[str, np.ndarray]
    var: dict[str, np.ndarray]
    clip_obs: float
    epsilon: float

    def __call__(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The normalized copy of a batch of dict observations (other keys unchanged)."""
        out = dict(obs)
        for key, mean in self.mean.items():
            z = (np.asarray(obs[key]) - mean) / np.sqrt(self.var[key] + self.epsilon)
            out[key] = np.clip(z, -self.clip_obs, self.clip_obs).astype(np.float32)
        return out


def save_normalization(vec_normalize: Any, path: str | Path) -> Path:
    """Write the observation statistics of an SB3 ``VecNormalize`` (dict observations) as npz."""
    rms = vec_normalize.obs_rms
    if not isinstance(rms, dict):
        raise TypeError(f"expected VecNormalize over dict observations, got obs_rms {type(rms).__name__}")
    arrays: dict[str, np.ndarray] = {
        "clip_obs": np.float64(vec_normalize.clip_obs),
        "epsilon": np.float64(vec_normalize.epsilon),
    }
    for key, stats in rms.items():
        arrays[f"mean/{key}"] = np.asarray(stats.mean, dtype=np.float64)
        arrays[f"var/{key}"] = np.asarray(stats.var, dtype=np.float64)
    path = Path(path)
    with atomic_path(path) as tmp:
        np.savez(tmp, **arrays)
    return path


def load_normalization(path: str | Path) -> ObsNormalizer:
    """Read :func:`save_normalization`'s file (no pickle).

    Raises:
        ValueError: the file is not such a file (names what is missing or malformed).
    """
    with np.load(path, allow_pickle=False) as z:
        names = set(z.files)
        missing = {"clip_obs", "epsilon"} - names
        if missing:
            raise ValueError(f"{str(path)!r} is not a normalization file: it lacks {sorted(missing)}")
        mean = {n.split("/", 1)[1]: z[n] for n in names if n.startswith("mean/")}
        var = {n.split("/", 1)[1]: z[n] for n in names if n.startswith("var/")}
        if set(mean) != set(var) or any(mean[k].shape != var[k].shape for k in mean):
            raise ValueError(f"{str(path)!r}: the mean and var entries do not match per key")
        if any(not np.all(np.isfinite(v)) or np.any(v < 0) for v in var.values()):
            raise ValueError(f"{str(path)!r}: variances must be finite and >= 0")
        return ObsNormalizer(mean, var, float(z["clip_obs"]), float(z["epsilon"]))


def recorded_config(model_dir: str | Path) -> Any:
    """The training configuration a run recorded (``train.json``'s ``train_config``), or None.

    ``model_dir`` is a run folder or one of its ``checkpoints/step_<N>`` folders (the run's
    ``train.json`` then lies two levels up). None when there is no ``train.json`` or it predates
    the recorded configuration (then only the configuration's name is known, and what the name
    means may have changed since).

    Returns:
        A :class:`uav_struct_env.wrappers.TrainConfig`, or None.

    Raises:
        ValueError: if ``train.json`` is not JSON or its ``train_config`` is malformed.
    """
    from uav_struct_env.errors import ConfigError
    from uav_struct_env.wrappers.configs import TrainConfig

    path = train_json(model_dir)
    if path is None:
        return None
    try:
        recorded = json.loads(path.read_text()).get("train_config")
    except (json.JSONDecodeError, AttributeError) as err:
        raise ValueError(
            f"{str(path)!r} is not a train.json written by train_viewpoint_ppo.py: {err}"
        ) from None
    if recorded is None:
        return None
    try:
        return TrainConfig.from_dict(recorded)
    except ConfigError as err:
        raise ValueError(f"{str(path)!r}: {err}") from None


def train_json(model_dir: str | Path) -> Path | None:
    """The ``train.json`` of a run folder or of one of its checkpoint folders, or None.

    A ``checkpoints/step_<N>`` folder's run holds it two levels up.
    """
    d = Path(model_dir)
    candidates = [d / "train.json"]
    if d.parent.name == "checkpoints":
        candidates.append(d.parent.parent / "train.json")
    return next((path for path in candidates if path.is_file()), None)


def load_ppo(path: str | Path, observation_space: Any, action_space: Any, *, device: str = "cpu"):
    """SB3 ``PPO.load`` of ``model.zip`` without unpickling its cloudpickled entries.

    ``observation_space`` and ``action_space`` are the env's (one agent's); the policy class is
    ``MultiInputPolicy`` for dict observations (the asymmetric actor-critic,
    :class:`~uav_struct_env.training.asymmetric.AsymmetricActorCriticPolicy`, where the model's
    ``policy_kwargs`` name ``actor_keys``), else ``MlpPolicy``. An image key is given to the
    model channel-first, as SB3 trained it (``VecTransposeImage``); its ``predict`` transposes
    the env's channel-last images itself. Training-only state (the last observations, episode
    buffers, schedules) is replaced by empty values: the model predicts.

    Raises:
        ValueError: ``path`` is not an SB3 model file, or holds a pickled entry this function
            cannot replace.
    """
    from gymnasium import spaces
    from stable_baselines3 import PPO
    from stable_baselines3.common.policies import ActorCriticPolicy, MultiInputActorCriticPolicy
    from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
    from stable_baselines3.common.vec_env import VecTransposeImage

    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
    except (zipfile.BadZipFile, KeyError, ValueError) as err:
        raise ValueError(f"{str(path)!r} is not a stable-baselines3 model file: {err}") from None
    pickled = sorted(k for k, v in data.items() if isinstance(v, dict) and ":serialized:" in v)
    policy = MultiInputActorCriticPolicy if isinstance(observation_space, spaces.Dict) else ActorCriticPolicy
    if isinstance(data.get("policy_kwargs"), dict) and "actor_keys" in data["policy_kwargs"]:
        from uav_struct_env.training.asymmetric import AsymmetricActorCriticPolicy

        policy = AsymmetricActorCriticPolicy  # its actor reads actor_keys, its critic critic_keys
    if isinstance(observation_space, spaces.Dict):
        channel_last = {k for k, s in observation_space.spaces.items()
                        if is_image_space(s) and not is_image_space_channels_first(s)}
        observation_space = spaces.Dict({
            k: VecTransposeImage.transpose_space(s, k) if k in channel_last else s
            for k, s in observation_space.spaces.items()})
    replacements: dict[str, Any] = {
        "policy_class": policy,
        "observation_space": observation_space,
        "action_space": action_space,
        "lr_schedule": 0.0,  # rebuilt from the stored float learning_rate
        "clip_range": 0.2,  # a training setting; prediction does not read it
        "clip_range_vf": None,
        "rollout_buffer_class": None,  # chosen from the observation space
        "_last_obs": None,
        "_last_episode_starts": None,
        "_last_original_obs": None,
        "ep_info_buffer": None,
        "ep_success_buffer": None,
    }
    unknown = [k for k in pickled if k not in replacements]
    if unknown:
        raise ValueError(
            f"{str(path)!r} holds pickled entries {unknown} that cannot be read safely; "
            "load it with stable_baselines3.PPO.load only if you trust its source"
        )
    try:
        return PPO.load(path, device=device, custom_objects={k: replacements[k] for k in pickled})
    except Exception as err:  # a tampered or truncated weights file: torch's or SB3's own error
        first = " ".join(str(err).split())[:200]
        raise ValueError(f"{str(path)!r} is not a readable stable-baselines3 model: {type(err).__name__}: "
                         f"{first}") from None
