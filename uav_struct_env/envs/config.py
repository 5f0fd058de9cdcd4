"""Environment configuration: one frozen dataclass, named presets and keyword overrides.

``EnvConfig`` holds every knob of :class:`~uav_struct_env.envs.uav_struct.UavStructParallelEnv`.
Build one with :func:`make_config` (``preset`` plus keyword overrides), which is what
``uav_struct_env.parallel_env(**config)`` does. Presets (:data:`PRESETS`):

* ``"paper"`` (default): the paper's camera (1280 x 720, fx = fy = 1108.5 px), the paper's
  noise (3 m, 2 deg roll/pitch, 5 deg yaw, alternating signs), 1.0 m ArUco markers.
* ``"train"``: the same field of view at 128 x 72 px, the ``gnss_ins`` noise model, no
  landmark truth in ``info`` (saves the per-step projections), 200 cycles, and a crash ends the
  episode for everyone (``on_crash="all"``, for SuperSuit/SB3), for RL training.

Keys with a stable meaning (docs/design.md): ``stage``, ``image_size``, ``marker_size``, ``noise``,
``renderer``, ``max_cycles``, ``render_mode``. The rest may grow.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from localization.synthetic import PAPER_IMAGE_SIZE
from uav_struct_env.errors import ConfigError, SiteGeometryError
from uav_struct_env.sim.imaging import ImagingModel, make_imaging
from uav_struct_env.sim.schedule import ScheduleSpec
from uav_struct_env.sim.sensors import SensorModel, make_noise
from uav_struct_env.sim.uav import FlightLimits, Geofence
from uav_struct_env.site import LANDMARK_SETS, Site, paper_site
from uav_struct_env.site.as_built import AsBuilt, make_as_built

__all__ = ["PRESETS", "RENDER_MODES", "RENDERERS", "EnvConfig", "make_config"]


def _is_site_file(site: object) -> bool:
    return isinstance(site, str) and site.lower().endswith((".json", ".ifc")) and Path(site).is_file()

RENDER_MODES = ("rgb_array",)
RENDERERS = ("auto", "tiny", "egl")


@dataclass(frozen=True)
class EnvConfig:
    """Configuration of the four-UAV environment. Units: metres, seconds, radians, pixels.

    Attributes:
        stage: construction stage: one of the site's stage names (``"slab"`` or ``"columns"``
            for the paper's building; ``"Level 2/slab"`` ... for an IFC file, see
            :func:`~uav_struct_env.site.ifc_stages`); None: a given Site's own stage, else
            ``"columns"``.
        site: ``"paper"``, ``"random"`` (drawn once per env from ``texture_seed``), a
            :class:`~uav_struct_env.site.Site`, or the path of a site file (``*.json``) or an
            IFC file (``*.ifc``, needs the ``ifc`` extra).
        marker_size: ArUco marker side (m), or None for no markers.
        image_size: ``(W, H)`` of the observed images. The intrinsics are the paper's camera
            scaled to this size (same field of view).
        imaging: camera effects on the observed image (:mod:`uav_struct_env.sim.imaging`):
            ``"ideal"`` (none, the default), ``"camera"`` (blur, noise, JPEG) or an
            ``ImagingModel``. Landmark truth is unaffected.
        noise: onboard sensor model: ``"paper"``, ``"gnss_ins"``, ``"none"`` or a model object
            from :mod:`uav_struct_env.sim.sensors`.
        renderer: ``"auto"`` (EGL for images of about 420 x 240 px and more where EGL starts,
            else TinyRenderer), ``"tiny"`` or ``"egl"``.
        max_cycles: steps after which every live agent is truncated.
        render_mode: None or ``"rgb_array"``.
        n_agents: number of UAVs (``uav_0`` ... ``uav_{n-1}``), one per side sector.
        control_period: seconds each action is held.
        limits: command limits (:class:`~uav_struct_env.sim.uav.FlightLimits`).
        geofence: flight area (:class:`~uav_struct_env.sim.uav.Geofence`).
        uav_radius: collision radius of a UAV, m (Mavic 2 Pro diagonal 354 mm + margin).
        schedule: the scripted viewpoint schedule's parameters (its ``seed`` fixes it per env).
        landmark_sets: landmark sets whose ground truth goes in ``info["landmarks"]``; ``()``
            skips the projections.
        observe_depth: add ``obs["depth"]`` (float32 (H, W), metres along the optical axis).
        texture_seed: seed of the per-env concrete textures (and of ``site="random"``).
        on_crash: ``"agent"`` (a crash terminates only that agent, PettingZoo's usual
            semantics) or ``"all"`` (it also truncates every other agent: the episode ends, as
            SuperSuit's vector-env conversion needs).
        show_uavs: draw every flying UAV's airframe (a 32 x 24 x 8 cm box) in the other
            UAVs' images.
        render_view_height: height in pixels of each agent's tile in ``render()``.
        render_fps: frame rate stored in ``metadata`` and used by the video helper.
        start_yaw_jitter: random starts (``reset`` without a ``viewpoint`` option) turn each
            UAV's heading by a uniform angle in ``[-start_yaw_jitter, start_yaw_jitter]`` rad
            after the in-view check, so some start views miss part of the structure (a
            viewpoint-planning task); ``0`` (default) keeps the aimed views and draws nothing.
        as_built: None (the building stands as designed) or an as-built deviation model
            (:class:`~uav_struct_env.site.as_built.AsBuilt`, or a tolerance model name such as
            ``"aci117"``): the rendered building, the collision obstacles and the landmark truth
            in ``info`` are the as-built building; ``env.site`` (what a localizer uses) stays
            the design.
    """

    stage: str | None = None
    site: str | Site = "paper"
    marker_size: float | None = 1.0
    image_size: tuple[int, int] = PAPER_IMAGE_SIZE
    noise: str | SensorModel = "paper"
    imaging: str | ImagingModel = "ideal"
    renderer: str = "auto"
    max_cycles: int = 100
    render_mode: str | None = None
    n_agents: int = 4
    control_period: float = 0.5
    limits: FlightLimits = field(default_factory=FlightLimits)
    geofence: Geofence = field(default_factory=Geofence)
    uav_radius: float = 0.5
    schedule: ScheduleSpec = field(default_factory=ScheduleSpec)
    landmark_sets: tuple[str, ...] = LANDMARK_SETS
    observe_depth: bool = False
    texture_seed: int = 0
    on_crash: str = "agent"
    show_uavs: bool = True
    render_view_height: int = 180
    render_fps: int = 2
    start_yaw_jitter: float = 0.0
    as_built: AsBuilt | str | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.site, Site) or self.site in ("paper", "random") or _is_site_file(self.site)):
            raise ConfigError(
                "site must be 'paper', 'random', a Site or an existing *.json / *.ifc file, "
                f"got {self.site!r}"
            )
        if self.stage is not None and not isinstance(self.stage, str):
            raise ConfigError(f"stage must be a stage name (str) or None, got {self.stage!r}")
        names = (self.site.stage_names if isinstance(self.site, Site)
                 else paper_site().stage_names if self.site in ("paper", "random") else None)
        if self.stage is not None and names is not None and self.stage not in names:
            raise ConfigError(f"stage must be one of {names}, got {self.stage!r}")
        if self.marker_size is not None:
            if (
                isinstance(self.marker_size, bool)
                or not isinstance(self.marker_size, (int, float))
                or not math.isfinite(self.marker_size)
                or self.marker_size <= 0
            ):
                raise ConfigError(
                    "marker_size must be a positive side length in metres or None, "
                    f"got {self.marker_size!r}"
                )
        size = self.image_size
        if (
            not isinstance(size, (tuple, list))
            or len(size) != 2
            or any(
                isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 16 for v in size
            )
        ):
            raise ConfigError(f"image_size must be (width, height) ints >= 16, got {size!r}")
        object.__setattr__(self, "image_size", (int(size[0]), int(size[1])))
        object.__setattr__(self, "noise", make_noise(self.noise))
        object.__setattr__(self, "imaging", make_imaging(self.imaging))
        if self.renderer not in RENDERERS:
            raise ConfigError(f"renderer must be one of {RENDERERS}, got {self.renderer!r}")
        for name in ("max_cycles", "n_agents", "render_view_height", "render_fps"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ConfigError(f"{name} must be a positive int, got {v!r}")
        if self.render_mode is not None and self.render_mode not in (*RENDER_MODES, "human"):
            raise ConfigError(
                f"render_mode must be None or one of {list(RENDER_MODES)}, got {self.render_mode!r}"
            )
        for name in ("control_period", "uav_radius"):
            v = getattr(self, name)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not math.isfinite(v)
                or v <= 0
            ):
                raise ConfigError(f"{name} must be a positive number, got {v!r}")
        j = self.start_yaw_jitter
        if isinstance(j, bool) or not isinstance(j, (int, float)) or not 0 <= j <= math.pi:
            raise ConfigError(f"start_yaw_jitter must be a number in [0, pi] rad, got {j!r}")
        if self.on_crash not in ("agent", "all"):
            raise ConfigError(f"on_crash must be 'agent' or 'all', got {self.on_crash!r}")
        sets = tuple(self.landmark_sets)
        unknown = [s for s in sets if s not in LANDMARK_SETS]
        if unknown:
            raise ConfigError(
                f"landmark_sets must be drawn from {LANDMARK_SETS}, got unknown {unknown}"
            )
        object.__setattr__(self, "landmark_sets", sets)
        try:
            object.__setattr__(self, "as_built", make_as_built(self.as_built))
        except SiteGeometryError as exc:
            raise ConfigError(str(exc)) from None
        for name, cls in (
            ("limits", FlightLimits),
            ("geofence", Geofence),
            ("schedule", ScheduleSpec),
        ):
            if not isinstance(getattr(self, name), cls):
                raise ConfigError(f"{name} must be a {cls.__name__}, got {getattr(self, name)!r}")

    def replace(self, **overrides: Any) -> EnvConfig:
        """A copy with some fields replaced (validated again)."""
        return _replace(self, overrides)


def _replace(config: EnvConfig, overrides: dict[str, Any]) -> EnvConfig:
    names = {f.name for f in dataclasses.fields(EnvConfig)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise ConfigError(f"unknown config keys {unknown}; valid keys are {sorted(names)}")
    if "image_size" in overrides and isinstance(overrides["image_size"], list):
        overrides = {**overrides, "image_size": tuple(overrides["image_size"])}
    return dataclasses.replace(config, **overrides)


PRESETS: dict[str, EnvConfig] = {
    "paper": EnvConfig(),
    "train": EnvConfig(
        image_size=(128, 72), noise="gnss_ins", landmark_sets=(), max_cycles=200, on_crash="all"
    ),
}


def make_config(preset: str | EnvConfig = "paper", **overrides: Any) -> EnvConfig:
    """A preset (name or :class:`EnvConfig`) with keyword overrides.

    Raises:
        ConfigError: for an unknown preset, an unknown key or an invalid value.
    """
    if isinstance(preset, EnvConfig):
        base = preset
    elif preset in PRESETS:
        base = PRESETS[preset]
    else:
        raise ConfigError(
            f"preset must be one of {sorted(PRESETS)} or an EnvConfig, got {preset!r}"
        )
    return _replace(base, overrides) if overrides else base
