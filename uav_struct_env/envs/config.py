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

from localization.checks import check_choice, check_number
from localization.geometry.camera import PAPER_IMAGE_SIZE
from uav_struct_env.errors import ConfigError, SiteGeometryError
from uav_struct_env.sim.batch import MAX_BATCH_SIZE
from uav_struct_env.sim.imaging import ImagingModel, make_imaging
from uav_struct_env.sim.lens import CameraModel, make_camera_model
from uav_struct_env.sim.schedule import ScheduleSpec
from uav_struct_env.sim.sensors import SensorModel, make_noise
from uav_struct_env.sim.uav import FlightLimits, Geofence
from uav_struct_env.site import LANDMARK_SETS, Site, paper_site
from uav_struct_env.site.activity import Activity, make_activity
from uav_struct_env.site.as_built import AsBuilt, make_as_built

__all__ = ["PRESETS", "RENDER_MODES", "RENDERERS", "EnvConfig", "check_image_size", "make_config"]


#: Upper bounds where memory or physics follows from a value: an image side and its pixels (a
#: Mavic 2 Pro still is 5472 x 3648), agents, seconds an action is held, a UAV's radius (m), a
#: marker's side (m).
MAX_IMAGE_SIDE = 8192
MAX_IMAGE_PIXELS = 5472 * 3648
MAX_AGENTS = 64
MAX_CONTROL_PERIOD = 60.0
MAX_UAV_RADIUS = 10.0
MAX_MARKER_SIDE = 10.0


def _number(name: str, value: Any, lo: float | None, hi: float | None, **kwargs: Any) -> Any:
    return check_number(name, value, lo, hi, error=ConfigError, type_error=ConfigError, **kwargs)


def check_image_size(size: Any) -> tuple[int, int]:
    """``(width, height)`` of an image the env renders, checked.

    Two integers, each side 16 to :data:`MAX_IMAGE_SIDE` px, at most :data:`MAX_IMAGE_PIXELS` in all.

    Raises:
        ConfigError: naming the value and the limit it breaks.
    """
    if isinstance(size, (str, bytes)) or not isinstance(size, (tuple, list)) or len(size) != 2:
        raise ConfigError(f"image_size must be (width, height) in pixels, got {size!r}")
    w = _number("image_size[0] (width)", size[0], 16, MAX_IMAGE_SIDE, integer=True)
    h = _number("image_size[1] (height)", size[1], 16, MAX_IMAGE_SIDE, integer=True)
    if w * h > MAX_IMAGE_PIXELS:
        raise ConfigError(
            f"image_size {w} x {h} has {w * h} pixels, more than the {MAX_IMAGE_PIXELS} supported "
            "(a 20 MP still; every agent renders one per step)"
        )
    return w, h


def _is_site_file(site: object) -> bool:
    return isinstance(site, str) and site.lower().endswith((".json", ".ifc")) and Path(site).is_file()

RENDER_MODES = ("rgb_array",)
RENDERERS = ("auto", "tiny", "egl", "batch")
LIGHTINGS = ("fixed", "random")


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
        image_size: ``(W, H)`` of the observed images. The intrinsics are the ``camera``'s
            scaled to this size (same field of view).
        imaging: camera effects on the observed image (:mod:`uav_struct_env.sim.imaging`):
            ``"ideal"`` (none, the default), ``"camera"`` (blur, noise, JPEG) or an
            ``ImagingModel``. Landmark truth is unaffected.
        noise: onboard sensor model: ``"paper"``, ``"gnss_ins"``, ``"none"`` or a model object
            from :mod:`uav_struct_env.sim.sensors`.
        renderer: ``"auto"`` (EGL for images of about 420 x 240 px and more where EGL starts,
            else TinyRenderer), ``"tiny"``, ``"egl"`` or ``"batch"``: the compiled CPU
            rasterizer of :mod:`uav_struct_env.sim.batch`, which renders every agent's frame of a
            step in one call, for images up to 160 x 120 (larger ones are refused); pybullet
            (TinyRenderer) stays the physics and draws ``render()``'s views.
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
        observe_image: render ``obs["image"]``. False: no image in the observation and no
            render in ``step`` (unless ``observe_depth``): the landmark truth in ``info`` comes
            from ray casting against the same triangles (:mod:`uav_struct_env.sim.raycast`;
            agrees with the depth test on 99.98-100 % of landmark-views), for state-only
            training on simulated detections. ``render()`` still draws the views, on demand.
        observe_depth: add ``obs["depth"]`` (float32 (H, W), metres along the optical axis).
        texture_seed: seed of the per-env concrete textures (and of ``site="random"``).
        on_crash: ``"agent"`` (a crash terminates only that agent, PettingZoo's usual
            semantics) or ``"all"`` (it also terminates every other agent, reason
            ``"teammate_crash"``: the episode ends for everyone, as SuperSuit's vector-env
            conversion and RLlib's PettingZoo wrappers need).
        show_uavs: draw every flying UAV's airframe (a 32 x 24 x 8 cm box) in the other
            UAVs' images.
        render_view_height: height in pixels of each agent's tile in ``render()``.
        render_fps: frame rate stored in ``metadata`` and used by the video helper.
        start_yaw_jitter: random starts (``reset`` without a ``viewpoint`` option) turn each
            UAV's heading by a uniform angle in ``[-start_yaw_jitter, start_yaw_jitter]`` rad
            after the in-view check, so some start views miss part of the structure (a
            viewpoint-planning task); ``0`` (default) keeps the aimed views and draws nothing.
        lighting: ``"fixed"`` (the default sun, :data:`uav_struct_env.sim.world.DEFAULT_LIGHT`)
            or ``"random"``: each ``reset`` draws a sun direction and intensity
            (:func:`uav_struct_env.sim.world.random_light`; EGL uses the direction only) from the
            episode's generator, so a seed fixes it; ``env.world.light`` holds it.
        as_built: None (the building stands as designed) or an as-built deviation model
            (:class:`~uav_struct_env.site.as_built.AsBuilt`, or a tolerance model name such as
            ``"aci117"``): the rendered building, the collision obstacles and the landmark truth
            in ``info`` are the as-built building; ``env.site`` (what a localizer uses) stays
            the design.
        activity: site activity (:mod:`uav_struct_env.site.activity`): ``"none"`` (a bare site,
            the default), ``"light"``, ``"busy"`` or an ``Activity``. Workers walking on the slab
            and the ground, equipment, stored materials, scaffolding and column formwork, laid
            out from the site's elements at each ``reset`` from their own seeded generator (the
            episode's other draws are unchanged): they are rendered, hide landmarks in the
            landmark truth (rendered and ray-cast), and the static ones are collision obstacles.
            ``env.worker_points()`` and ``env.worker_visibility(agent)`` report the workers.
        camera: the camera (:mod:`uav_struct_env.sim.lens`): ``"paper"`` (the paper's ideal
            pinhole, the default), ``"mavic2pro"`` (the Mavic 2 Pro's Hasselblad L1D-20c: its
            intrinsics, lens distortion, 47 ms rolling-shutter readout and 1/500 s exposure with
            the UAV's motion) or a ``CameraModel``. ``info["intrinsics"]`` and
            ``info["distortion"]`` are its K and ``(k1, k2, p1, p2, k3)``; landmark ``uv`` is where
            each landmark appears in the delivered image.
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
    observe_image: bool = True
    observe_depth: bool = False
    texture_seed: int = 0
    on_crash: str = "agent"
    show_uavs: bool = True
    render_view_height: int = 180
    render_fps: int = 2
    start_yaw_jitter: float = 0.0
    lighting: str = "fixed"
    as_built: AsBuilt | str | None = None
    activity: str | Activity = "none"
    camera: str | CameraModel = "paper"

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
            _number("marker_size", self.marker_size, 0, MAX_MARKER_SIDE, lo_open=True)
        w, h = check_image_size(self.image_size)
        object.__setattr__(self, "image_size", (w, h))
        object.__setattr__(self, "noise", make_noise(self.noise))
        object.__setattr__(self, "imaging", make_imaging(self.imaging))
        object.__setattr__(self, "activity", make_activity(self.activity))
        object.__setattr__(self, "camera", make_camera_model(self.camera))
        check_choice("renderer", self.renderer, RENDERERS, error=ConfigError)
        if self.renderer == "batch" and (w > MAX_BATCH_SIZE[0] or h > MAX_BATCH_SIZE[1]):
            raise ConfigError(
                f"renderer='batch' draws images up to {MAX_BATCH_SIZE[0]} x {MAX_BATCH_SIZE[1]} px "
                f"(training resolution), got image_size {w} x {h}; use renderer='auto', 'tiny' or 'egl'"
            )
        for name, lo, hi in (("max_cycles", 1, None), ("n_agents", 1, MAX_AGENTS),
                             ("render_view_height", 16, MAX_IMAGE_SIDE), ("render_fps", 1, 1000),
                             ("texture_seed", 0, None)):
            _number(name, getattr(self, name), lo, hi, integer=True)
        for name in ("observe_image", "observe_depth", "show_uavs"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ConfigError(f"{name} must be True or False, got {getattr(self, name)!r}")
            object.__setattr__(self, name, bool(getattr(self, name)))
        if self.render_mode is not None and self.render_mode not in (*RENDER_MODES, "human"):
            raise ConfigError(
                f"render_mode must be None or one of {list(RENDER_MODES)}, got {self.render_mode!r}"
            )
        _number("control_period", self.control_period, 0, MAX_CONTROL_PERIOD, lo_open=True)
        _number("uav_radius", self.uav_radius, 0, MAX_UAV_RADIUS, lo_open=True)
        _number("start_yaw_jitter", self.start_yaw_jitter, 0, math.pi)
        check_choice("on_crash", self.on_crash, ("agent", "all"), error=ConfigError)
        if isinstance(self.landmark_sets, str):
            raise ConfigError(f"landmark_sets must be a tuple of set names, got {self.landmark_sets!r}")
        sets = tuple(self.landmark_sets)
        unknown = [s for s in sets if s not in LANDMARK_SETS]
        if unknown:
            raise ConfigError(
                f"landmark_sets must be drawn from {LANDMARK_SETS}, got unknown {unknown}"
            )
        object.__setattr__(self, "landmark_sets", sets)
        check_choice("lighting", self.lighting, LIGHTINGS, error=ConfigError)
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
