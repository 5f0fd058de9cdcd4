"""The four-UAV PettingZoo parallel environment (``uav_struct_v0``).

A thin adapter over :mod:`uav_struct_env.sim`: the site (:mod:`uav_struct_env.site`), one
pybullet :class:`~uav_struct_env.sim.world.SiteWorld` per env (built at the first ``reset`` and
reused; a reset only moves the UAVs), kinematic UAVs (:mod:`uav_struct_env.sim.uav`), onboard
sensor models (:mod:`uav_struct_env.sim.sensors`) and the scripted viewpoint schedule
(:mod:`uav_struct_env.sim.schedule`).

Per agent and step:

* observation ``{"image": uint8 (H, W, 3), "gnss": float32 (3,), "attitude": float32 (3,)}``
  (+ ``"depth"`` float32 (H, W) with ``observe_depth``; no ``"image"`` with
  ``observe_image=False``, whose landmark truth is ray-cast instead of rendered); attitude is
  (roll, pitch, yaw) rad in the convention of :mod:`uav_struct_env.sim.attitude` (ZYX, body
  FLU, positive pitch looks down), each wrapped to [-pi, pi);
* info ``world_from_cam`` (ground truth), ``prior_world_from_cam`` (exactly
  ``world_from_cam_from_attitude(obs["gnss"], obs["attitude"])`` in float64), ``intrinsics``
  (3x3 K of the observed image), ``distortion`` ((5,) its OpenCV ``k1, k2, p1, p2, k3``; zeros
  for the paper's pinhole), ``landmarks`` (per configured set: ids, xyz, uv, in_frame,
  visible; ``uv`` is where the landmark appears in the delivered image, distortion and rolling
  shutter included, see :mod:`uav_struct_env.sim.lens`), ``viewpoint`` (k right after
  ``reset(options={"viewpoint": k})``, else -1),
  ``noise_index`` (the viewpoint counter the paper noise's sign uses), ``gnss_fix`` (False in a
  GNSS outage of the sensor model, when ``gnss`` repeats the last fix) and
  ``termination_reason`` (None, ``"collision_structure"``, ``"collision_uav"``,
  ``"below_min_altitude"``, ``"above_max_altitude"``, ``"beyond_max_distance"``,
  ``"teammate_crash"``) and ``truncation_reason`` (None, ``"max_cycles"``);
* reward ``0.0``: the base env has no localization and no task; the LocalizationWrapper adds
  the reward. ``info["reward_terms"]`` is an empty dict that sums to it.

With ``as_built`` (:mod:`uav_struct_env.site.as_built`) the rendered building, the obstacles and
the landmark truth in ``info`` are ``env.built_site``, the design moved within tolerances;
``env.site`` stays the design (the BIM a localizer knows). Landmark ids are the same in both.

Episode: a crash (structure within ``uav_radius``, another UAV within ``2 * uav_radius``) or
leaving the geofence terminates that agent (it leaves ``env.agents``); after ``max_cycles``
steps every remaining agent is truncated. With ``on_crash="all"`` (the ``train`` preset) a crash
also terminates every other agent (``"teammate_crash"``), ending the episode: SuperSuit's
``pettingzoo_env_to_vec_env_v1`` cannot handle agents leaving mid-episode and its
``black_death_v3`` wrapper does not support Dict observations; RLlib's PettingZoo wrappers end
an episode only when all agents are terminated or all are truncated (one terminated and three
truncated kept the finished env stepping), and the end is terminal for the team, not a time limit.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray
from pettingzoo import ParallelEnv

from localization.checks import check_number
from localization.geometry.transforms import invert, quat_wxyz_from_matrix
from uav_struct_env.envs.config import EnvConfig, make_config
from uav_struct_env.envs.render import MapView, UavMarker, compose_frame, draw_site_map
from uav_struct_env.errors import ClosedError, ConfigError, ResetNeededError
from uav_struct_env.sim.activity import ActivityBodies
from uav_struct_env.sim.airframes import Airframes
from uav_struct_env.sim.attitude import world_from_cam_from_attitude
from uav_struct_env.sim.lens import LensView, Motion
from uav_struct_env.sim.schedule import (
    ViewpointSchedule,
    _ViewTargets,
    fit_schedule,
    sample_viewpoint,
)
from uav_struct_env.sim.sensors import Reading
from uav_struct_env.sim.uav import ACTION_COMPONENTS, Obstacles, UavState, step_uav
from uav_struct_env.site import Site, make_site
from uav_struct_env.site.activity import SiteActivity

__all__ = ["ACTION_COMPONENTS", "RESET_OPTIONS", "TEAMMATE_CRASH", "UavStructParallelEnv"]

#: The keys ``reset(options=...)`` accepts.
RESET_OPTIONS = ("viewpoint",)

#: ``termination_reason`` of the agents that did not crash when, with ``on_crash="all"``, a
#: teammate's crash ended the episode (they are terminated, not truncated).
TEAMMATE_CRASH = "teammate_crash"

#: Bound on the gnss observation box (m); far outside any reachable geofence.
GNSS_BOUND = 1.0e4


class UavStructParallelEnv(ParallelEnv):
    """Four camera UAVs around a construction site; see the module docstring.

    Args:
        config: an :class:`EnvConfig` or a preset name (``"paper"``, ``"train"``); default
            ``"paper"``.
        **overrides: :class:`EnvConfig` fields to override.
    """

    metadata = {
        "name": "uav_struct_v0",
        "render_modes": ["rgb_array"],
        "render_fps": 2,
        "is_parallelizable": True,
    }

    def __init__(self, config: EnvConfig | str | None = None, **overrides: Any) -> None:
        self.config: EnvConfig = make_config("paper" if config is None else config, **overrides)
        cfg = self.config
        if cfg.render_mode == "human":
            warnings.warn(
                "render_mode='human' is not supported (no window); render() will return None. "
                "Use render_mode='rgb_array' and the video helper instead.",
                stacklevel=2,
            )
        self.render_mode = cfg.render_mode
        self.metadata = {**type(self).metadata, "render_fps": cfg.render_fps}
        self.max_cycles = cfg.max_cycles
        self.possible_agents = [f"uav_{i}" for i in range(cfg.n_agents)]
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}

        self.site: Site = make_site(
            cfg.site, cfg.stage, cfg.marker_size, rng=np.random.default_rng(cfg.texture_seed)
        )
        # What stands: the design moved within the as-built tolerances (rendered, collided with,
        # and the landmark truth); the localizer's BIM is ``self.site``.
        self.built_site: Site = self.site if cfg.as_built is None else cfg.as_built.apply(self.site)
        w, h = cfg.image_size
        self.camera = cfg.camera.camera(w, h)
        # A real camera renders wide and remaps (sim.lens); the paper's pinhole renders directly.
        self._lens: LensView | None = None if cfg.camera.is_ideal else LensView(cfg.camera, w, h)
        self._distortion = np.array(cfg.camera.distortion)
        self._motions: dict[str, Motion] = {}
        self.obstacles = Obstacles.from_site(self.built_site)
        self._site_obstacles = self.obstacles  # the building; reset adds the activity's boxes
        # The schedule's ranges and the geofence fitted to the building (sim.schedule.fit_schedule).
        self.viewpoint_schedule: ViewpointSchedule
        self.viewpoint_schedule, scale = fit_schedule(self.site, cfg.n_agents, cfg.schedule)
        self.schedule_spec = self.viewpoint_schedule.spec
        self.geofence = cfg.geofence.scaled(scale)
        self._targets = _ViewTargets.from_site(self.site)
        self._world = None
        self._batch_scene = None  # renderer="batch": the world's geometry for sim.batch
        self._closed = False
        self._was_reset = False

        obs = {
            "image": spaces.Box(0, 255, (h, w, 3), np.uint8),
            "gnss": spaces.Box(-GNSS_BOUND, GNSS_BOUND, (3,), np.float32),
            "attitude": spaces.Box(-np.pi, np.pi, (3,), np.float32),
        }
        if not cfg.observe_image:
            del obs["image"]
        if cfg.observe_depth:
            obs["depth"] = spaces.Box(0.0, np.float32(self.camera.far), (h, w), np.float32)
        self._observation_space = spaces.Dict(obs)
        self._action_space = spaces.Box(-1.0, 1.0, (len(ACTION_COMPONENTS),), np.float32)

        self._rng = np.random.default_rng()
        self._states: dict[str, UavState] = {}
        self._sensor_state: Any = None
        self._viewpoint_base = 0
        self._scripted_viewpoint = -1
        self.num_cycles = 0
        self._last_images: dict[str, NDArray[np.uint8]] = {}
        self._priors: dict[str, NDArray[np.float64]] = {}
        self._alive: dict[str, bool] = {}
        self._map_view: MapView | None = None
        self._airframes: Airframes | None = None
        #: Site activity: this episode's layout and its bodies (None with activity "none").
        self.activity_layout: SiteActivity | None = None
        self._activity_bodies: ActivityBodies | None = None
        self._activity_seed: list[int] = []
        self._activity_episode = 0

    # ------------------------------------------------------------------ spaces
    def _check_agent(self, agent: str) -> None:
        if agent not in self._index:
            raise ValueError(f"unknown agent {agent!r}; agents are {self.possible_agents}")

    def observation_space(self, agent: str) -> spaces.Dict:
        """The (cached, shared) observation space; the same object for every agent."""
        self._check_agent(agent)
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Box:
        """The (cached, shared) action space: Box(-1, 1, (5,), float32); see ACTION_COMPONENTS."""
        self._check_agent(agent)
        return self._action_space

    @property
    def observation_spaces(self) -> dict[str, spaces.Dict]:
        """``{agent: observation_space(agent)}`` (the dict RLlib, TorchRL and skrl read)."""
        return dict.fromkeys(self.possible_agents, self._observation_space)

    @property
    def action_spaces(self) -> dict[str, spaces.Box]:
        """``{agent: action_space(agent)}``."""
        return dict.fromkeys(self.possible_agents, self._action_space)

    @property
    def state_space(self) -> spaces.Box:
        """The space of :meth:`state`: 8 float32 per possible agent."""
        n = len(self.possible_agents)
        return spaces.Box(-GNSS_BOUND, GNSS_BOUND, (8 * n,), np.float32)

    def state(self) -> NDArray[np.float32]:
        """The global true state, for centralized critics (privileged: not an observation).

        Per possible agent, in order: the true camera position (x, y, z, m), its orientation
        as a unit quaternion (w, x, y, z; ``world_from_cam``) and 1.0 if the agent is alive,
        else 0.0 (a finished agent keeps its last pose).

        Raises:
            ResetNeededError: before the first :meth:`reset`.
        """
        self._check_open()
        if not self._was_reset:
            raise ResetNeededError("state() before reset(): call env.reset(seed=...) first")
        out = np.zeros((len(self.possible_agents), 8), dtype=np.float64)
        for i, a in enumerate(self.possible_agents):
            T = self._states[a].world_from_cam
            out[i, :3] = T[:3, 3]
            out[i, 3:7] = quat_wxyz_from_matrix(T[:3, :3])
            out[i, 7] = float(self._alive.get(a, False))
        return np.clip(out.ravel(), -GNSS_BOUND, GNSS_BOUND).astype(np.float32)

    # ------------------------------------------------------------------ world
    @property
    def world(self):
        """The env's :class:`~uav_struct_env.sim.world.SiteWorld` (built on first use).

        Raises:
            ClosedError: after :meth:`close`.
        """
        self._check_open()
        if self._world is None:
            from uav_struct_env.sim.world import SiteWorld

            batch = self.config.renderer == "batch"
            self._world = SiteWorld(
                self.built_site,
                renderer="tiny" if batch else self.config.renderer,
                image_size=self.config.image_size,
                rng=np.random.default_rng(self.config.texture_seed),
            )
            if self.config.show_uavs:
                self._airframes = Airframes(self._world, self.possible_agents)
            if batch:
                from uav_struct_env.sim.batch import BatchScene

                self._batch_scene = BatchScene(self._world)
        return self._world

    # ------------------------------------------------------------------ reset / step
    def reset(self, seed: int | None = None, options: dict | None = None):
        """Start an episode.

        Args:
            seed: seeds the env's generator (``0`` is a seed); None continues the stream.
            options: ``{"viewpoint": k}`` places every UAV at viewpoint ``k`` of
                ``env.viewpoint_schedule`` (and the paper noise uses ``k`` as its viewpoint
                index). Without it each UAV starts at a random viewpoint on its own side drawn
                from the schedule's ranges. Other keys (:data:`RESET_OPTIONS`) are refused,
                except ``"options"``, which PettingZoo's API tests pass to probe the signature.

        Raises:
            ValueError: if ``seed`` is not None or an int >= 0, ``options`` is not a dict or
                names an unknown key, or ``viewpoint`` is not an int in ``[0, n_viewpoints)``.
        """
        self._check_open()
        if seed is not None:
            check_number("seed", seed, 0, integer=True, type_error=ValueError)
            self._rng = np.random.default_rng(seed)
            self._activity_seed, self._activity_episode = [int(seed)], 0
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"options must be a dict (keys {RESET_OPTIONS}) or None, got {options!r}")
        unknown = sorted(set(options or ()) - set(RESET_OPTIONS) - {"options"}, key=str)
        if unknown:
            raise ValueError(f"unknown reset options {unknown}; valid keys are {list(RESET_OPTIONS)}")
        viewpoint = None if options is None else options.get("viewpoint")
        n = self.config.n_agents
        if viewpoint is not None:
            nv = self.viewpoint_schedule.n_viewpoints
            if (
                isinstance(viewpoint, bool)
                or not isinstance(viewpoint, (int, np.integer))
                or not 0 <= viewpoint < nv
            ):
                raise ValueError(
                    f"options['viewpoint'] must be an int in [0, {nv}), got {viewpoint!r}"
                )
            k = int(viewpoint)
            self._states = {
                a: self.viewpoint_schedule.state(i, k) for i, a in enumerate(self.possible_agents)
            }
            self._viewpoint_base = k
            self._scripted_viewpoint = k
        else:
            self._states = {
                a: sample_viewpoint(self._targets, i, n, self._rng, self.schedule_spec)[0]
                for i, a in enumerate(self.possible_agents)
            }
            jitter = self.config.start_yaw_jitter
            if jitter > 0:
                for a in self.possible_agents:
                    st = self._states[a]
                    turn = self._rng.uniform(-jitter, jitter)
                    self._states[a] = UavState.make(st.xyz, st.yaw + turn, st.pitch)
            self._viewpoint_base = 0
            self._scripted_viewpoint = -1
        self._sensor_state = self.config.noise.start(self._rng, n)
        self._motions = {a: Motion() for a in self.possible_agents}  # hovering at the start
        self._lay_out_activity()
        if self.config.lighting == "random":  # a new sun for the episode
            from uav_struct_env.sim.world import random_light

            self.world.light = random_light(self._rng)
        self._was_reset = True
        self.agents = list(self.possible_agents)
        self._alive = dict.fromkeys(self.agents, True)
        self.num_cycles = 0
        observations, infos = self._observe(self.agents, dt=0.0, reasons=dict.fromkeys(self.agents))
        return observations, infos

    def _lay_out_activity(self) -> None:
        """Lay out this episode's site activity (none: remove the last one's bodies).

        Its seed is (reset seed, episodes since that seed), or fresh entropy before any seed;
        the env's generator is not drawn from, so every other draw of the episode is unchanged.
        """
        if self._activity_bodies is not None:
            self._activity_bodies.remove()
            self._activity_bodies = None
        if self.config.activity.is_none:
            return
        if not self._activity_seed:
            self._activity_seed = [int(np.random.SeedSequence().entropy)]
        self.activity_layout = SiteActivity(
            self.built_site, self.config.activity, [*self._activity_seed, self._activity_episode]
        )
        self._activity_episode += 1
        self._activity_bodies = ActivityBodies(self.world, self.activity_layout)
        self.obstacles = self._site_obstacles.with_boxes(*self.activity_layout.static_aabbs())

    def _activity_time(self) -> float:
        """Seconds since the episode's reset (the workers' clock)."""
        return self.num_cycles * self.config.control_period

    def worker_points(self) -> dict[str, NDArray[np.float64]]:
        """Every worker's ``(2, 3)`` float64 points now, by name (empty without site activity).

        Row 0 is the feet (ground contact, centre), row 1 the head top; project frame.

        Raises:
            ResetNeededError: before the first :meth:`reset`.
        """
        self._check_open()
        if not self._was_reset:
            raise ResetNeededError("worker_points() before reset(): call env.reset(seed=...) first")
        if self.activity_layout is None or self.config.activity.is_none:
            return {}
        return self.activity_layout.worker_points(self._activity_time())

    def worker_visibility(self, agent: str) -> dict[str, float]:
        """Per worker, the fraction (0..1) of its sample points ``agent``'s camera sees now.

        The points are five along the worker's vertical axis (10 %, 30 %, ..., 90 % of its
        height, :data:`~uav_struct_env.site.activity.WORKER_SAMPLE_HEIGHTS`). A point counts
        when it appears inside the delivered image (through the ``camera``'s distortion and
        rolling shutter) in front of the camera and the ray from the camera
        centre to it hits nothing else first (building, other activity bodies, other UAVs'
        airframes; the worker's own body is passed through, the camera's own airframe is
        hidden): ray casting, so it works with ``observe_image=False``.

        Raises:
            ValueError: for an unknown agent.
            ResetNeededError: before the first :meth:`reset`.
        """
        self._check_agent(agent)
        if not self.worker_points():
            return {}
        cam_from_world = invert(self._states[agent].world_from_cam)
        project = None
        if self._lens is not None:  # where the delivered image shows them (distortion, shutter)
            lens, motion = self._lens, self._motions.get(agent)

            def project(xyz):
                uv, _, in_field = lens.project(cam_from_world, xyz, motion)
                return uv, in_field

        # a finished agent's airframe is hidden already
        hidden = self._own_airframe_hidden(agent) if agent in self.agents else nullcontext()
        with hidden:
            return self._activity_bodies.worker_visibility(
                self._activity_time(), cam_from_world, self.camera, project
            )

    def _validate_action(self, agent: Any, action: Any) -> NDArray[np.float64]:
        if agent not in self._index:
            raise ValueError(
                f"action addressed to unknown agent {agent!r}; agents are {self.possible_agents}"
            )
        if agent not in self.agents:
            raise ValueError(
                f"action addressed to finished agent {agent!r} (terminated or truncated); "
                f"live agents are {self.agents}, got action {action!r}"
            )
        arr = np.asarray(action) if action is not None else None
        if arr is None or arr.dtype.kind not in "fiu":
            raise ValueError(
                f"action for {agent!r} must be a real numeric array of shape (5,) "
                f"({', '.join(ACTION_COMPONENTS)}), got {action!r} with dtype "
                f"{None if arr is None else arr.dtype}"
            )
        if arr.shape != self._action_space.shape:
            raise ValueError(
                f"action for {agent!r} must have shape {self._action_space.shape} "
                f"({', '.join(ACTION_COMPONENTS)}), got shape {arr.shape}: {action!r}"
            )
        arr = arr.astype(np.float64)
        if not np.isfinite(arr).all():
            raise ValueError(f"action for {agent!r} must be finite, got {arr.tolist()}")
        return np.minimum(np.maximum(arr, -1.0), 1.0)  # np.clip's result (finite), half its cost

    def step(self, actions: dict[str, Any]):
        """Apply one action per live agent (missing agents hover) for ``control_period`` s.

        Actions are validated before anything moves; values outside [-1, 1] are clipped.

        Raises:
            ResetNeededError: before the first :meth:`reset`.
            ValueError: for an action to an unknown or finished agent, or one that is NaN/inf,
                of the wrong shape or of a non-numeric dtype (message names agent and value).
        """
        self._check_open()
        if not self._was_reset:
            raise ResetNeededError("step() before reset(): call env.reset(seed=...) first")
        if not isinstance(actions, dict):
            raise ValueError(
                "actions must be a dict mapping agent names to actions, "
                f"got {type(actions).__name__}"
            )
        cleaned = {agent: self._validate_action(agent, a) for agent, a in actions.items()}
        live = list(self.agents)
        if not live:
            return {}, {}, {}, {}, {}
        cfg = self.config
        hover = np.zeros(len(ACTION_COMPONENTS))
        for agent in live:
            before = self._states[agent]
            self._states[agent] = step_uav(
                before, cleaned.get(agent, hover), cfg.limits, cfg.control_period
            )
            if self._lens is not None:  # only a real camera's render blurs and skews by motion
                self._motions[agent] = Motion.between(before, self._states[agent], cfg.control_period)
        reasons = self._crashes(live)
        if cfg.on_crash == "all" and any(r is not None for r in reasons.values()):
            # The team's episode ends here, by the dynamics and not by a time limit: everyone is
            # terminated, so that no learner bootstraps past it and RLlib's PettingZoo wrappers
            # (whose episode end needs all agents terminated or all truncated) see the end.
            reasons = {a: TEAMMATE_CRASH if r is None else r for a, r in reasons.items()}
        self.num_cycles += 1
        self._scripted_viewpoint = -1
        observations, infos = self._observe(live, dt=cfg.control_period, reasons=reasons)
        terminations = {a: reasons[a] is not None for a in live}
        truncations = {}
        for a in live:
            why = None
            if not terminations[a] and self.num_cycles >= self.max_cycles:
                why = "max_cycles"
            truncations[a] = why is not None
            infos[a]["truncation_reason"] = why
        rewards = dict.fromkeys(live, 0.0)
        self.agents = [a for a in live if not (terminations[a] or truncations[a])]
        for a in live:
            self._alive[a] = a in self.agents
        return observations, rewards, terminations, truncations, infos

    def _crashes(self, live: list[str]) -> dict[str, str | None]:
        """Termination reason per live agent (None: still flying)."""
        cfg = self.config
        cx, cy = self.site.center[:2].tolist()
        positions = [self._states[a].position for a in live]  # (x, y, z) floats
        reasons: dict[str, str | None] = {}
        clearance = self.obstacles.distances(np.array(positions))
        for k, a in enumerate(live):
            fence = self.geofence.violation(positions[k], (cx, cy))
            reasons[a] = (
                fence
                if fence is not None
                else ("collision_structure" if clearance[k] < cfg.uav_radius else None)
            )
        # the nearest other UAV: the norm np.linalg.norm gives, ((dx^2 + dy^2) + dz^2) ** 0.5
        for k, a in enumerate(live):
            if reasons[a] is None and len(live) > 1:
                xk, yk, zk = positions[k]
                nearest = min(
                    math.sqrt((x - xk) * (x - xk) + (y - yk) * (y - yk) + (z - zk) * (z - zk))
                    for j, (x, y, z) in enumerate(positions) if j != k
                )
                if nearest < 2 * cfg.uav_radius:
                    reasons[a] = "collision_uav"
        return reasons

    def _observe(self, agents: list[str], dt: float, reasons: dict[str, str | None]):
        cfg = self.config
        world = self.world
        # Without an observed image (or depth) nothing is rendered: visibility by ray casting.
        render = cfg.observe_image or cfg.observe_depth
        need_depth = cfg.observe_depth or (render and bool(cfg.landmark_sets))
        K = self.camera.K
        observations: dict[str, dict[str, NDArray]] = {}
        infos: dict[str, dict[str, Any]] = {}
        # The sensors' multipath / sky-blockage model sees the building, not the site activity.
        clearance = self._site_obstacles.distances(np.array([self._states[a].xyz for a in agents]))
        if self._airframes is not None:  # draw the flying UAVs, hide the finished ones
            self._airframes.place({a: self._states[a] for a in agents})
        if self._activity_bodies is not None:
            self._activity_bodies.update(self._activity_time())
        frames = self._batch_frames(agents) if render and self._batch_scene is not None else {}
        for k, agent in enumerate(agents):
            i = self._index[agent]
            state = self._states[agent]
            noise_index = self._viewpoint_base + self.num_cycles
            gnss, attitude = cfg.noise.measure(
                self._sensor_state,
                self._rng,
                Reading(i, noise_index, state.xyz, state.attitude, float(clearance[k]), dt),
            )
            gnss_fix = bool(np.isfinite(gnss).all())
            if not gnss_fix:  # an outage: the onboard position is the last fix, held
                if dt == 0.0 or agent not in self._priors:
                    raise ConfigError(
                        f"sensor model {cfg.noise.name!r} gave no GNSS fix for {agent!r} at reset; "
                        "a model must give a fix when dt == 0 (uav_struct_env.sim.sensors)"
                    )
                gnss = self._priors[agent][:3, 3]
            # np.minimum(np.maximum(...)): np.clip's result at half its cost (every agent-step)
            gnss32 = np.minimum(np.maximum(gnss, -GNSS_BOUND), GNSS_BOUND).astype(np.float32)
            att32 = np.minimum(np.maximum(attitude, -np.pi), np.pi).astype(np.float32)
            world_from_cam = state.world_from_cam
            cam_from_world = invert(world_from_cam)
            obs = {"gnss": gnss32, "attitude": att32}
            if self._lens is None and not render:  # ray cast: the rays pass through its airframe
                own = None if self._airframes is None else self._airframes.bodies[agent]
                landmarks = {
                    name: world.landmark_truth_raycast(name, cam_from_world, self.camera, skip_body=own)
                    for name in cfg.landmark_sets
                }
            else:
                # a batched frame was drawn without the agent's own airframe
                with nullcontext() if frames else self._own_airframe_hidden(agent):
                    if self._lens is not None:
                        obs, landmarks = self._observe_lens(
                            agent, cam_from_world, obs, render, need_depth, frames.get(agent)
                        )
                    else:
                        result = frames.get(agent) or world.render(
                            cam_from_world, self.camera, depth=need_depth
                        )
                        image = cfg.imaging.apply(result.rgb, self._rng)
                        if cfg.observe_image:
                            obs = {"image": image, **obs}
                            self._last_images[agent] = image
                        if cfg.observe_depth:
                            obs["depth"] = np.asarray(result.depth, dtype=np.float32)
                        landmarks = {
                            name: world.landmark_truth(name, cam_from_world, self.camera, result)
                            for name in cfg.landmark_sets
                        }
            prior = world_from_cam_from_attitude(
                gnss32.astype(np.float64), att32.astype(np.float64)
            )
            observations[agent] = obs
            infos[agent] = {
                "world_from_cam": world_from_cam,
                "prior_world_from_cam": prior,
                "intrinsics": K.copy(),
                "distortion": self._distortion.copy(),
                "landmarks": landmarks,
                "viewpoint": self._scripted_viewpoint,
                "noise_index": noise_index,
                "gnss_fix": gnss_fix,
                "termination_reason": reasons.get(agent),
                "truncation_reason": None,
                "reward_terms": {},
            }
            self._priors[agent] = prior
        return observations, infos

    def _batch_frames(self, agents: list[str]) -> dict[str, Any]:
        """Every agent's frame of this step in one call of :mod:`uav_struct_env.sim.batch`.

        Each camera is rendered without its own airframe; a real camera's frame is its wide render
        (:attr:`LensView.render_camera`), remapped by :meth:`_observe_lens`.
        """
        from uav_struct_env.sim.batch import BatchView, render_batch

        camera = self.camera if self._lens is None else self._lens.render_camera
        own = {} if self._airframes is None else self._airframes.bodies
        views = [
            BatchView(self._batch_scene, invert(self._states[a].world_from_cam), camera, own.get(a, -1))
            for a in agents
        ]
        return dict(zip(agents, render_batch(views), strict=True))

    def _observe_lens(
        self, agent: str, cam_from_world: NDArray[np.float64], obs: dict, render: bool, need_depth: bool,
        rendered: Any = None,
    ) -> tuple[dict, dict]:
        """:meth:`_observe`'s render and landmark truth through a real camera (``self._lens``).

        ``rendered``: the agent's wide frame if already drawn (``renderer="batch"``).
        """
        cfg, world, lens = self.config, self.world, self._lens
        motion = self._motions.get(agent)
        if not render:
            wide = {
                name: world.landmark_truth_raycast(name, cam_from_world, lens.render_camera)
                for name in cfg.landmark_sets
            }
        else:
            moving = motion is not None and not motion.is_static
            result = rendered or world.render(cam_from_world, lens.render_camera, depth=need_depth or moving)
            rgb, depth = lens.warp(
                result.rgb, result.depth, cam_from_world, motion, warp_depth=cfg.observe_depth
            )
            image = cfg.imaging.apply(rgb, self._rng)
            if cfg.observe_image:
                obs = {"image": image, **obs}
                self._last_images[agent] = image
            if cfg.observe_depth:
                obs["depth"] = np.asarray(depth, dtype=np.float32)
            wide = {
                name: world.landmark_truth(name, cam_from_world, lens.render_camera, result)
                for name in cfg.landmark_sets
            }
        landmarks = {name: lens.landmark_truth(w, cam_from_world, motion) for name, w in wide.items()}
        return obs, landmarks

    # ------------------------------------------------------------------ render / close
    def render(self) -> NDArray[np.uint8] | None:
        """The ``rgb_array`` frame: views side by side plus the top-down map (None otherwise)."""
        self._check_open()
        if self.render_mode is None:
            warnings.warn(
                "render() called with render_mode=None; pass render_mode='rgb_array'", stacklevel=2
            )
            return None
        if self.render_mode != "rgb_array":
            return None
        cfg = self.config
        if self._map_view is None:
            sched = self.viewpoint_schedule
            reach = float(np.max(sched.horizontal_distances)) + 8.0
            c = self.site.center
            self._map_view = MapView((float(c[0]), float(c[1])), reach, 2 * cfg.render_view_height)
        markers = [
            UavMarker(
                a,
                self._states[a].xyz,
                self._states[a].yaw,
                self._priors[a][:3, 3] if a in self._priors else None,
                self._alive.get(a, False),
            )
            for a in self.possible_agents
            if a in self._states
        ]
        site_map = draw_site_map(self.site, markers, self._map_view)
        if cfg.observe_image:
            views = {a: self._last_images.get(a) for a in self.possible_agents}
        else:  # nothing was rendered in step: render the live agents' views now
            views = {a: self._view(a) if self._alive.get(a, False) else None for a in self.possible_agents}
        w, h = cfg.image_size
        return compose_frame(views, site_map, cfg.render_view_height, w / h)

    def _view(self, agent: str) -> NDArray[np.uint8]:
        """``agent``'s camera image now (its own airframe hidden), for :meth:`render`."""
        cam_from_world = invert(self._states[agent].world_from_cam)
        with self._own_airframe_hidden(agent):
            if self._lens is None:
                return self.world.render(cam_from_world, self.camera).rgb
            wide = self.world.render(cam_from_world, self._lens.render_camera)
            return self._lens.warp(wide.rgb, None, cam_from_world)[0]

    @contextmanager
    def _own_airframe_hidden(self, agent: str) -> Iterator[None]:
        """While ``agent``'s camera looks: its own airframe is hidden (it never sees itself)."""
        if self._airframes is None:
            yield
            return
        self._airframes.set(agent, None)
        try:
            yield
        finally:
            self._airframes.set(agent, self._states[agent])

    def _check_open(self) -> None:
        if self._closed:
            raise ClosedError(
                "this uav_struct_v0 environment is closed (close() released its pybullet "
                "client); create a new one with uav_struct_env.parallel_env(...)"
            )

    def close(self) -> None:
        """Release the pybullet client; later reset/step/render raise :class:`ClosedError`.

        Closing twice is harmless.
        """
        self._closed = True
        self._airframes = None
        self._activity_bodies = None
        self._batch_scene = None
        if self._world is not None:
            self._world.close()
            self._world = None

    # ------------------------------------------------------------------ helpers for scripts
    def uav_state(self, agent: str) -> UavState:
        """The kinematic state of one agent (ground truth)."""
        self._check_agent(agent)
        return self._states[agent]

    def __repr__(self) -> str:
        c = self.config
        return (
            f"UavStructParallelEnv(stage={c.stage!r}, image_size={c.image_size}, "
            f"noise={c.noise.name!r}, "
            f"n_agents={c.n_agents}, max_cycles={self.max_cycles})"
        )
