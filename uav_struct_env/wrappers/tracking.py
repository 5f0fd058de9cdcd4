"""``WorkerTracking``: multi-view 3D tracking of the site's workers, its numbers and a reward option.

Each reset and step, every live camera detects the workers (:class:`~uav_struct_env.tracking_sim.
SimulatedWorkerDetector` on the env's ``worker_points()`` / ``worker_visibility(agent)``, at the
camera's true pose: what the image shows), and :func:`tracking.track_workers` associates the
detections across cameras and triangulates each worker from the camera poses of ``poses``:
``"estimated"`` (the localizer's, from a :class:`~uav_struct_env.wrappers.localize.LocalizePoses`
below; cameras that failed to localize do not take part), ``"truth"`` or ``"prior"``. It adds to
every agent's info ``worker_tracking`` (:data:`TRACKING_INFO_KEYS`, numbers only, finite;
:data:`~uav_struct_env.wrappers.localize.UNDEFINED` = -1.0 where a quantity has no value):

* ``n_workers``: workers on the site; ``n_detections``: this camera's worker detections;
* ``n_tracked``: workers triangulated from >= 2 cameras; ``n_tracked_with_me``: those this camera
  helped triangulate; ``coverage``: ``n_tracked / n_workers``;
* ``median_error_m``, ``p95_error_m``: 3D error of the tracked workers (the larger of feet and
  head-top errors, :mod:`tracking.metrics`; ground truth, simulation only);
* ``my_error_m``: the mean error of the workers this camera helped triangulate;
* ``my_position_std_m``: their mean predicted feet position std, ``sqrt(trace(cov))``
  (deployable, no ground truth).

The whole result is in :attr:`WorkerTracking.last_result` (a :class:`tracking.TrackingResult`).

Reward option (``reward="tracking"`` or a :class:`TrackingReward`): every live agent's reward
gains :class:`TrackingReward`'s terms (and ``info["reward_terms"]`` with them, so the terms still
sum to the reward): ``tracking_coverage`` (+``coverage_weight`` x the share of the site's workers
this camera helps triangulate with at least one other) and ``tracking_error`` (-``error_weight``
x the mean over those workers of ``min(error, error_cap)``). Composed over a
:class:`~uav_struct_env.wrappers.LocalizationWrapper` with the ``error`` reward, a viewpoint policy
is trained for anchor quality and worker coverage together.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from localization.checks import check_choice, check_number
from localization.geometry.transforms import invert
from tracking import TrackingResult, track_workers, worker_errors
from uav_struct_env.errors import ConfigError
from uav_struct_env.tracking_sim import (
    POSE_SOURCES,
    SimulatedWorkerDetector,
    camera_views,
    check_worker_source,
)
from uav_struct_env.wrappers.base import ParallelWrapper, find_wrapper
from uav_struct_env.wrappers.localize import LocalizePoses, info_number

__all__ = ["TRACKING_INFO_KEYS", "TrackingReward", "WorkerTracking"]

#: The keys of ``info[agent]["worker_tracking"]``, in order.
TRACKING_INFO_KEYS = (
    "n_workers",
    "n_detections",
    "n_tracked",
    "n_tracked_with_me",
    "coverage",
    "median_error_m",
    "p95_error_m",
    "my_error_m",
    "my_position_std_m",
)


class TrackingReward:
    """Reward terms from downstream worker tracking (module docstring); needs ground truth.

    Args:
        coverage_weight: reward for helping triangulate every worker of the site (>= 0).
        error_weight: weight of the mean capped 3D error of those workers, per metre (>= 0).
        error_cap: cap on each worker's error, m (> 0): a wrong triangulation never costs more
            than ``error_weight x error_cap``.
    """

    name = "tracking"

    def __init__(self, *, coverage_weight: float = 1.0, error_weight: float = 1.0, error_cap: float = 1.0):
        kw = {"error": ConfigError, "type_error": ConfigError}
        self.coverage_weight = check_number("coverage_weight", coverage_weight, 0.0, **kw)
        self.error_weight = check_number("error_weight", error_weight, 0.0, **kw)
        self.error_cap = check_number("error_cap", error_cap, 0.0, lo_open=True, **kw)

    def terms(self, n_workers: int, my_errors: np.ndarray) -> dict[str, float]:
        """``tracking_coverage`` and ``tracking_error`` of one agent.

        Args:
            n_workers: workers on the site.
            my_errors: (K,) 3D errors (m) of the workers this agent helped triangulate.
        """
        errors = np.asarray(my_errors, dtype=np.float64)
        coverage = len(errors) / n_workers if n_workers else 0.0
        penalty = float(np.mean(np.minimum(errors, self.error_cap))) if len(errors) else 0.0
        return {
            "tracking_coverage": self.coverage_weight * coverage,
            "tracking_error": -self.error_weight * penalty,
        }


class WorkerTracking(ParallelWrapper):
    """Track the site's workers from all cameras each step; add ``info["worker_tracking"]``.

    Args:
        env: a ``uav_struct_v0`` env with site activity (``activity="light"`` or ``"busy"``), or a
            wrapper chain of one (with a :class:`LocalizePoses` for ``poses="estimated"``).
        poses: camera poses the tracker uses, one of :data:`~uav_struct_env.tracking_sim.
            POSE_SOURCES` (None: ``"estimated"`` when a :class:`LocalizePoses` is below, else
            ``"truth"``).
        pixel_sigma: keypoint noise of the simulated detector, px (None: 2 px at 1280 px wide).
        miss_rate: probability that a detectable worker is missed.
        min_visible: smallest visible fraction of a worker that gets it detected.
        gate_probability: chi-square quantile of the association gate.
        height_range: head-above-feet heights (m) accepted in an association (None: any).
        upright: triangulate workers standing (head top above the feet; :func:`tracking.track_workers`).
        reward: None, ``"tracking"`` (:class:`TrackingReward` defaults) or a :class:`TrackingReward`.

    Raises:
        ConfigError: for an env without workers, ``poses="estimated"`` without a
            :class:`LocalizePoses` below, an unknown option or a value out of range.
    """

    def __init__(
        self,
        env: Any,
        poses: str | None = None,
        *,
        pixel_sigma: float | None = None,
        miss_rate: float = 0.05,
        min_visible: float = 0.5,
        gate_probability: float = 0.999,
        height_range: tuple[float, float] | None = (1.0, 2.3),
        upright: bool = False,
        reward: str | TrackingReward | None = None,
    ) -> None:
        super().__init__(env)
        self._base = check_worker_source(env)
        self._loc = find_wrapper(env, LocalizePoses)
        if poses is None:
            poses = "estimated" if self._loc is not None else "truth"
        check_choice("poses", poses, POSE_SOURCES, error=ConfigError)
        if poses == "estimated" and self._loc is None:
            raise ConfigError("poses='estimated' needs a LocalizePoses (or LocalizationWrapper) below")
        self.poses = poses
        self.detector = SimulatedWorkerDetector(pixel_sigma, miss_rate, min_visible)
        self.gate_probability = check_number(
            "gate_probability", gate_probability, 0.0, 1.0, lo_open=True, hi_open=True, error=ConfigError
        )
        if height_range is not None:
            lo = check_number("height_range[0]", height_range[0], error=ConfigError, type_error=ConfigError)
            hi = check_number("height_range[1]", height_range[1], lo, lo_open=True, error=ConfigError,
                              type_error=ConfigError)
            height_range = (lo, hi)
        self.height_range = height_range
        self.upright = bool(upright)
        if reward is None or isinstance(reward, TrackingReward):
            self.reward = reward
        elif reward == "tracking":
            self.reward = TrackingReward()
        else:
            raise ConfigError(f"reward must be None, 'tracking' or a TrackingReward, got {reward!r}")
        self.image_size = tuple(int(x) for x in self._base.config.image_size)
        self.last_result: TrackingResult | None = None

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset the env and track the workers; ``seed`` also seeds the worker detector."""
        if seed is not None:
            self.detector.seed(np.random.default_rng([int(seed), 0x7A4C]))
        obs, infos = self.env.reset(seed=seed, options=options)
        self._track(infos, list(obs))
        return obs, infos

    def step(self, actions: dict[str, Any]):
        """Step the env, track the workers; with a reward, add its terms to every live agent."""
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        stats = self._track(infos, list(obs))
        if self.reward is not None:
            for agent in obs:
                terms = self.reward.terms(*stats[agent])
                infos[agent].setdefault("reward_terms", {}).update(terms)
                rewards[agent] = float(rewards.get(agent, 0.0)) + float(sum(terms.values()))
        return obs, rewards, terminations, truncations, infos

    def _track(self, infos: Mapping[str, dict], agents: list[str]) -> dict[str, tuple[int, np.ndarray]]:
        points = self._base.worker_points()
        live = {a: infos[a] for a in agents}
        estimates = (
            {a: self._loc.last_frames[a].estimate for a in agents if a in self._loc.last_frames}
            if self._loc is not None else None
        )
        localizer = self._loc.localizer if self._loc is not None else None
        prior_sigmas = localizer.prior_sigmas if localizer is not None else None
        views = camera_views(live, self.poses, estimates, prior_sigmas)
        detections = {}
        for agent in agents:
            info = infos[agent]
            dets = self.detector.detect(
                points, self._base.worker_visibility(agent), info["intrinsics"],
                invert(info["world_from_cam"]), self.image_size, info.get("distortion"),
            )
            detections[agent] = dets
        used = {v.name for v in views}
        result = track_workers(
            views, {a: d for a, d in detections.items() if a in used},
            gate_probability=self.gate_probability, height_range=self.height_range, upright=self.upright,
        )
        self.last_result = result
        errors = worker_errors(result, points)  # in the order of result.tracked, labels all known
        by_worker = dict(zip((id(w) for w in result.tracked), errors, strict=True))
        n_workers = len(points)
        team = errors if len(errors) else np.array([np.nan])
        out = {}
        for agent in agents:
            mine = result.cameras_of(agent)
            my_errors = np.array([by_worker[id(w)] for w in mine])
            stds = [np.sqrt(np.trace(w.feet.covariance)) for w in mine]
            infos[agent]["worker_tracking"] = {
                "n_workers": n_workers,
                "n_detections": len(detections[agent]),
                "n_tracked": len(result.tracked),
                "n_tracked_with_me": len(mine),
                "coverage": info_number(len(result.tracked) / n_workers if n_workers else np.nan),
                "median_error_m": info_number(np.median(team)),
                "p95_error_m": info_number(np.percentile(team, 95)),
                "my_error_m": info_number(np.mean(my_errors) if len(mine) else np.nan),
                "my_position_std_m": info_number(np.mean(stds) if stds else np.nan),
            }
            out[agent] = (n_workers, my_errors)
        return out
