"""Write rollouts of the parallel env to MP4 (OpenCV) or GIF (Pillow).

Example::

    env = uav_struct_env.parallel_env("train", render_mode="rgb_array")
    record_rollout(env, "rollout.mp4", n_steps=40, seed=0)
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["record_rollout", "write_video"]

Policy = Callable[[str, dict[str, Any]], Any]


def write_video(frames: Iterable[NDArray[np.uint8]], path: str | Path, fps: float = 2.0) -> Path:
    """Write RGB uint8 frames (all the same shape) to ``path``: ``.mp4``/``.avi`` or ``.gif``.

    Raises:
        ValueError: for an unsupported suffix, no frames, or frames of different shapes.
        RuntimeError: if OpenCV cannot open a video writer for ``path``.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".mp4", ".avi", ".gif"):
        raise ValueError(f"video path must end in .mp4, .avi or .gif, got {str(path)!r}")
    frames = [np.asarray(f) for f in frames]
    if not frames:
        raise ValueError("write_video needs at least one frame, got none")
    shape = frames[0].shape
    for k, f in enumerate(frames):
        if f.shape != shape or f.dtype != np.uint8 or f.ndim != 3 or f.shape[2] != 3:
            raise ValueError(
                f"frame {k} must be uint8 (H, W, 3) like frame 0 {shape}, got {f.dtype} {f.shape}"
            )
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".gif":
        from PIL import Image

        images = [Image.fromarray(f) for f in frames]
        images[0].save(
            path, save_all=True, append_images=images[1:], duration=int(round(1000.0 / fps)), loop=0
        )
        return path
    h, w = shape[:2]
    fourcc = cv2.VideoWriter_fourcc(*("mp4v" if suffix == ".mp4" else "MJPG"))
    writer = cv2.VideoWriter(str(path), fourcc, float(fps), (w, h))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV could not open a video writer for {str(path)!r}")
    try:
        for f in frames:
            writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    finally:
        writer.release()
    return path


def record_rollout(
    env: Any,
    path: str | Path,
    *,
    n_steps: int = 20,
    seed: int | None = 0,
    options: dict | None = None,
    policy: Policy | None = None,
    fps: float | None = None,
) -> Path:
    """Reset ``env`` (a parallel env with ``render_mode="rgb_array"``), step it and save a video.

    Args:
        env: the parallel env.
        path: output file (``.mp4``, ``.avi`` or ``.gif``).
        n_steps: steps after the reset (stops early when every agent is done).
        seed: passed to ``reset``.
        options: passed to ``reset`` (e.g. ``{"viewpoint": 0}``).
        policy: ``policy(agent, observation) -> action``; default samples the action space.
        fps: frame rate (default ``env.metadata["render_fps"]``).

    Returns:
        The path written. One frame per reset/step.
    """
    if getattr(env, "render_mode", None) != "rgb_array":
        raise ValueError(
            f"record_rollout needs an env made with render_mode='rgb_array', got "
            f"{getattr(env, 'render_mode', None)!r}"
        )
    obs, _ = env.reset(seed=seed, options=options)
    frames = [env.render()]
    for _ in range(n_steps):
        if not env.agents:
            break
        actions = {
            a: (policy(a, obs[a]) if policy is not None else env.action_space(a).sample())
            for a in env.agents
        }
        obs, *_ = env.step(actions)
        frames.append(env.render())
    return write_video(frames, path, fps if fps is not None else env.metadata.get("render_fps", 2))
