"""Labelled landmark images rendered from the simulator, with domain randomization.

Used to train and evaluate the learned landmark detector (:mod:`localization.detect.learned`).
Each *layout* is one random site (:func:`uav_struct_env.site.random_site`, both construction
stages, with or without ArUco markers) -- or, with ``site`` a site file or an IFC file, that
building at one of its stages drawn per layout (``python -m uav_struct_env.datasets OUT --site
building.ifc``: a held-out set on a real building; ``stages`` / ``--stages A,B`` draws from those
stages only) -- with its own concrete/ground textures, a random texture
resolution and 3-14 clutter boxes (stacks of building material and equipment-sized boxes on the
ground, a few small stacks on the slab away from its edges). Each layout is seen from
``views_per_layout`` random viewpoints: any azimuth, 10-40 m out from the slab edge, 8-30 m up,
aimed at the building centre with up to +-4 m (horizontal) / +-2 m (vertical) of jitter, so the
building is sometimes cut by the image border. With ``activity`` (``"light"``, ``"busy"``) each
layout also gets the site activity of :mod:`uav_struct_env.site.activity` (workers, equipment,
materials, scaffolding; seeded by ``[seed, layout, 1]``, the workers 3 s further on at each
view), which hides landmarks like everything else; ``"mixed"`` cycles none, light, busy over the
layouts (layout ``i`` gets ``("none", "light", "busy")[i % 3]``, recorded as each image's
``activity``). Every view draws a new sun direction
(elevation 25-85 deg, any azimuth) and TinyRenderer ambient/diffuse coefficients (the EGL
backend only uses the direction: that limitation is pybullet's).

**Camera** (``camera``, :data:`CAMERAS`). ``"paper"`` (the default) is the paper's ideal pinhole,
rendered directly. ``"mavic2pro"`` renders every view through
:class:`uav_struct_env.sim.lens.LensView` with the :data:`~uav_struct_env.sim.lens.MAVIC2PRO`
preset: lens distortion, rolling shutter and motion blur, exactly as the env delivers its
images. ``"mixed"`` alternates the two over the dataset's images (image ``n = layout * views +
view`` is ``mavic2pro`` when ``n`` is odd): half of each. A ``mavic2pro`` view's camera moves
while the frame is read: a velocity drawn uniformly in the UAV's flight limits
(:class:`~uav_struct_env.sim.uav.FlightLimits` defaults: horizontal speed 0-10 m/s in any
direction, vertical -3..+4 m/s) and an angular velocity of a yaw rate (+-100 deg/s, about the
vertical) plus a gimbal pitch rate (+-90 deg/s, about the camera's x axis), all drawn from
``numpy.random.default_rng([seed, layout, 2])`` -- its own stream, so the views, sites and
lights are those of the ``paper`` dataset of the same seed. The pose in ``cam_from_world`` is
the pose at the middle row's exposure (the time convention of :mod:`uav_struct_env.sim.lens`).

**Imaging** (``imaging``, :data:`IMAGINGS`). ``"ideal"`` (the default) saves the render as it is.
``"camera"`` passes every delivered full-resolution image (after the lens, before downscaling)
through :data:`uav_struct_env.sim.imaging.IMAGING_PRESETS` ``["camera"]`` -- optics blur, shot and
read noise, a JPEG round trip: the env's and the study's ``imaging="camera"``, so that a
``camera="mavic2pro", imaging="camera"`` view is the study's ``--camera mavic2pro --imaging
camera``. ``"mixed"`` gives it to image ``n`` when ``n // 2`` is odd: with ``camera="mixed"`` a
quarter of the images each of pinhole / Mavic x ideal / camera imaging. Its noise is drawn from
``numpy.random.default_rng([seed, layout, 3])`` (its own stream again), recorded as each such
image's ``"imaging": "camera"``.

Images are rendered at the paper's 1280 x 720 and downscaled by ``scale`` with
``cv2.INTER_AREA`` -- exactly what the detector does at inference -- so training and inference
images come from the same pipeline.

**Format** (``out_dir``)::

    images/000000.png ...   RGB (saved as PNG; W*scale x H*scale)
    labels.json             {"format": "uav-struct-landmarks-v1",
                             "types": ["column_tops", "slab_corners", "opening_corners"],
                             "image_size": [W', H'], "source_size": [1280, 720], "scale": 0.5,
                             "config": {...generator arguments...},
                             "software": {"package", "version", "git_commit", "git_modified"},
                             "settings": "uav-struct-env 0.1.0 (git ...) · n_layouts 200 · ...",
                             "images": [{"file": "images/000000.png", "layout": 0,
                                         "stage": "columns", "K": 3x3 (of the saved image),
                                         "cam_from_world": 4x4,
                                         "keypoints": [[u, v, type, id], ...],
                                         ...a real camera's view only:
                                         "camera": "mavic2pro", "distortion": [k1, k2, p1, p2, k3],
                                         "velocity": [vx, vy, vz], "angular_velocity": [wx, wy, wz],
                                         ...with activity "mixed" only: "activity": "busy",
                                         ...camera imaging only: "imaging": "camera"},
                                        ...]}

``software`` and ``settings`` say how the dataset was made (:mod:`uav_struct_env.provenance`;
the images are described by the ``labels.json`` beside them). The real-camera keys (world
velocities, m/s and rad/s) appear only on such views, so a ``paper`` dataset's images and
keypoints are what the generator wrote before it had cameras (its ``config`` has no ``camera``
either; likewise ``imaging`` for an ``ideal`` one);
:func:`load_labels` fills in ``"camera": "paper"``, ``"imaging": "ideal"`` and zero distortion and
motion for such views and configs, so readers need no special case.

``keypoints`` are the *visible* landmarks (in frame and not occluded, from
:meth:`SiteWorld.landmark_truth`; through a real camera :meth:`LensView.landmark_truth`, so
``(u, v)`` is where the landmark appears in the delivered, distorted, rolling-shutter image,
:meth:`LensView.project`) in the saved image's pixel coordinates (integer pixel centres,
``u' + 0.5 = (u + 0.5) * scale``); ``type`` indexes ``types``; ``id`` is the site's landmark id.
``K`` and ``distortion`` are the saved image's intrinsics (the distortion coefficients act on
the normalized image plane, so they hold at any ``scale``).
Everything is drawn from ``numpy.random.default_rng([seed, layout])``: one seed, one dataset.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from localization.checks import check_choice, check_number
from localization.geometry.camera import PAPER_IMAGE_SIZE
from localization.geometry.transforms import look_at
from uav_struct_env.errors import ConfigError
from uav_struct_env.provenance import settings_line, software
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.imaging import IMAGING_PRESETS
from uav_struct_env.sim.lens import CAMERA_MODELS, LensView, Motion
from uav_struct_env.sim.uav import FlightLimits
from uav_struct_env.site import Site, make_site, random_site
from uav_struct_env.site.activity import ACTIVITY_PRESETS, SiteActivity

__all__ = ["CAMERAS", "IMAGINGS", "LANDMARK_TYPES", "DatasetConfig", "generate", "load_labels",
           "render_layout"]

#: Heatmap channel order of the learned detector.
LANDMARK_TYPES = ("column_tops", "slab_corners", "opening_corners")
FORMAT = "uav-struct-landmarks-v1"
#: The generator's ``camera`` choices (module docstring, "Camera").
CAMERAS = ("paper", "mavic2pro", "mixed")
#: The generator's ``imaging`` choices (module docstring, "Imaging").
IMAGINGS = ("ideal", "camera", "mixed")
#: The generator's ``activity`` choices: the presets of :mod:`uav_struct_env.site.activity`, or
#: ``"mixed"`` (each layout one of them in turn).
ACTIVITIES = (*ACTIVITY_PRESETS, "mixed")

_MATERIAL_RGB = (
    (0.55, 0.42, 0.28), (0.62, 0.60, 0.57), (0.35, 0.36, 0.38), (0.70, 0.68, 0.62),
    (0.20, 0.35, 0.55), (0.45, 0.20, 0.15), (0.80, 0.78, 0.74),
)
#: Seconds of site activity between two views of a layout (the workers move on).
_ACTIVITY_SECONDS_PER_VIEW = 3.0
_EQUIPMENT_RGB = ((0.90, 0.70, 0.10), (0.85, 0.45, 0.10), (0.25, 0.25, 0.27), (0.90, 0.90, 0.88))


@dataclass(frozen=True)
class DatasetConfig:
    """Generator settings (all lengths in metres)."""

    n_layouts: int = 200
    views_per_layout: int = 15
    seed: int = 0
    scale: float = 0.5
    distance: tuple[float, float] = (10.0, 40.0)
    height: tuple[float, float] = (8.0, 30.0)
    renderer: str = "auto"
    source_size: tuple[int, int] = PAPER_IMAGE_SIZE
    site: str = "random"
    activity: str = "none"
    camera: str = "paper"
    imaging: str = "ideal"
    stages: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.site, str) or not (
            self.site == "random"
            or (self.site.lower().endswith((".json", ".ifc")) and Path(self.site).is_file())
        ):
            raise ConfigError(
                f"DatasetConfig.site must be 'random' or an existing site file (*.json) or IFC file "
                f"(*.ifc), got {self.site!r}"
            )
        if self.site != "random":
            object.__setattr__(self, "site", str(Path(self.site).resolve()))
        if self.stages is not None:
            self._check_stages()
        check_choice("DatasetConfig.activity", self.activity, ACTIVITIES, error=ConfigError)
        check_choice("DatasetConfig.camera", self.camera, CAMERAS, error=ConfigError)
        check_choice("DatasetConfig.imaging", self.imaging, IMAGINGS, error=ConfigError)
        for name in ("n_layouts", "views_per_layout", "seed"):
            v = getattr(self, name)
            check_number(f"DatasetConfig.{name}", v, 0 if name == "seed" else 1, integer=True,
                         error=ConfigError, type_error=ConfigError)
        check_number("DatasetConfig.scale", self.scale, 0, 1, lo_open=True, error=ConfigError,
                     type_error=ConfigError)
        for name in ("distance", "height"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ConfigError(
                    f"DatasetConfig.{name} must be (low, high), 0 < low <= high, got {(lo, hi)!r}"
                )

    def _check_stages(self) -> None:
        """``stages``: a non-empty tuple of the building file's stage names."""
        if self.site == "random":
            raise ConfigError("DatasetConfig.stages applies to a building file (site *.json or *.ifc), "
                              "not to random sites")
        if not isinstance(self.stages, (tuple, list)) or not self.stages:
            raise ConfigError("DatasetConfig.stages must be a non-empty tuple of stage names, got "
                              f"{self.stages!r}")
        names = [st.name for st in make_site(self.site, _first_stage(self.site), None).stages]
        unknown = [s for s in self.stages if s not in names]
        if unknown:
            raise ConfigError(f"DatasetConfig.stages: {unknown} not stages of {Path(self.site).name} "
                              f"(its stages: {names})")
        object.__setattr__(self, "stages", tuple(str(s) for s in self.stages))

    @property
    def image_size(self) -> tuple[int, int]:
        """Size ``(W', H')`` of the saved images."""
        w, h = self.source_size
        return round(w * self.scale), round(h * self.scale)


def _yaw_pose(x: float, y: float, z: float, yaw: float) -> NDArray[np.float64]:
    T = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = (x, y, z)
    return T


def _add_clutter(world, site: Site, rng: np.random.Generator) -> None:
    """Stacks of material and equipment-sized boxes around (and a few on) the building."""
    xmin, ymin, xmax, ymax = site.footprint_bounds
    cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
    reach = max(xmax - xmin, ymax - ymin) / 2
    for _ in range(int(rng.integers(3, 15))):
        ang = rng.uniform(0, 2 * math.pi)
        r = reach + rng.uniform(1.5, 14.0)
        x, y, yaw = cx + r * math.cos(ang), cy + r * math.sin(ang), rng.uniform(0, math.pi)
        if rng.random() < 0.35:  # equipment: container, excavator body, site cabin
            he = (rng.uniform(1.0, 3.5), rng.uniform(0.8, 1.5), rng.uniform(0.8, 1.6))
            rgb = _EQUIPMENT_RGB[int(rng.integers(len(_EQUIPMENT_RGB)))]
            world.add_body(he, (*rgb, 1.0), _yaw_pose(x, y, he[2], yaw))
        else:  # a stack of 1-4 pallets / bundles
            he = (rng.uniform(0.4, 1.5), rng.uniform(0.4, 1.2), rng.uniform(0.1, 0.4))
            z = 0.0
            for _ in range(int(rng.integers(1, 5))):
                rgb = _MATERIAL_RGB[int(rng.integers(len(_MATERIAL_RGB)))]
                shade = rng.uniform(0.8, 1.1)
                world.add_body(he, (*np.clip(np.array(rgb) * shade, 0, 1), 1.0),
                               _yaw_pose(x, y, z + he[2], yaw + rng.uniform(-0.2, 0.2)))
                z += 2 * he[2]
    # Small stacks on the slab, kept 1 m inside its edges (they must not sit on a landmark).
    if not site.floor:  # a stage of columns alone (a steel frame's): no slab to stack on
        return
    top = max(s.z_top for s in site.floor)
    for _ in range(int(rng.integers(0, 3))):
        if xmax - xmin < 3 or ymax - ymin < 3:
            break
        x, y = rng.uniform(xmin + 1.2, xmax - 1.2), rng.uniform(ymin + 1.2, ymax - 1.2)
        he = (rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7), rng.uniform(0.1, 0.4))
        rgb = _MATERIAL_RGB[int(rng.integers(len(_MATERIAL_RGB)))]
        world.add_body(he, (*rgb, 1.0), _yaw_pose(x, y, top + he[2], rng.uniform(0, math.pi)))


def _random_view(
    site: Site, rng: np.random.Generator, config: DatasetConfig
) -> NDArray[np.float64]:
    xmin, ymin, xmax, ymax = site.footprint_bounds
    centre = np.asarray(site.center, dtype=np.float64)
    half = math.hypot(xmax - xmin, ymax - ymin) / 2
    az = rng.uniform(0, 2 * math.pi)
    r = half + rng.uniform(*config.distance)
    eye = np.array([centre[0] + r * math.cos(az), centre[1] + r * math.sin(az),
                    rng.uniform(*config.height)])
    target = centre + rng.uniform([-4, -4, -2], [4, 4, 2])
    return look_at(eye, target)


def layout_activity(config: DatasetConfig, layout: int) -> str:
    """The activity preset of layout ``layout`` (``"mixed"``: none, light, busy in turn)."""
    if config.activity != "mixed":
        return config.activity
    return tuple(ACTIVITY_PRESETS)[layout % len(ACTIVITY_PRESETS)]


def view_camera(config: DatasetConfig, layout: int, view: int) -> str:
    """The camera preset (``"paper"`` or ``"mavic2pro"``) of view ``view`` of layout ``layout``."""
    if config.camera != "mixed":
        return config.camera
    return "mavic2pro" if (layout * config.views_per_layout + view) % 2 else "paper"


def view_imaging(config: DatasetConfig, layout: int, view: int) -> str:
    """The imaging preset (``"ideal"`` or ``"camera"``) of view ``view`` of layout ``layout``."""
    if config.imaging != "mixed":
        return config.imaging
    return "camera" if (layout * config.views_per_layout + view) // 2 % 2 else "ideal"


def random_motion(
    rng: np.random.Generator, cam_from_world: NDArray[np.float64], limits: FlightLimits | None = None
) -> Motion:
    """A camera motion within the UAV's flight ``limits`` (default :class:`FlightLimits`).

    Horizontal velocity of a uniform speed in ``[0, max_horizontal_speed]`` in a uniform direction,
    vertical velocity uniform in ``[-max_descent_speed, max_ascent_speed]``; angular velocity of a
    yaw rate uniform in ``+-max_yaw_rate`` about the world vertical plus a gimbal pitch rate uniform
    in ``+-max_gimbal_rate`` about the camera's x axis (``cam_from_world``'s).
    """
    limits = limits or FlightLimits()
    heading = rng.uniform(0, 2 * math.pi)
    speed = rng.uniform(0, limits.max_horizontal_speed)
    climb = rng.uniform(-limits.max_descent_speed, limits.max_ascent_speed)
    yaw_rate = rng.uniform(-limits.max_yaw_rate, limits.max_yaw_rate)
    pitch_rate = rng.uniform(-limits.max_gimbal_rate, limits.max_gimbal_rate)
    x_axis = np.asarray(cam_from_world, dtype=np.float64)[0, :3]  # camera x in world coordinates
    return Motion(np.array([speed * math.cos(heading), speed * math.sin(heading), climb]),
                  yaw_rate * np.array([0.0, 0.0, 1.0]) + pitch_rate * x_axis)


def deliver_view(
    rgb: NDArray[np.uint8],
    depth: NDArray[np.float32],
    truth: list[dict[str, NDArray]],
    cam_from_world: NDArray[np.float64],
    camera: Camera | LensView,
    out_size: tuple[int, int],
    motion: Motion | None = None,
    imaging: tuple[str, np.random.Generator] | None = None,
) -> tuple[NDArray[np.uint8], list[list], NDArray[np.float64]]:
    """One view's saved image, ``keypoints`` and ``K`` from its render.

    ``rgb``/``depth`` are the render with ``camera`` (a :class:`LensView`: with its
    ``render_camera``, then warped through the lens with ``motion``); ``truth`` is
    ``SiteWorld.landmark_truth`` of that render per :data:`LANDMARK_TYPES`. ``imaging`` (a preset
    name of :data:`~uav_struct_env.sim.imaging.IMAGING_PRESETS` and the generator of its noise)
    then degrades the full-resolution image. The image is downscaled to ``out_size`` with
    ``cv2.INTER_AREA`` and the labels with it.
    """
    if isinstance(camera, LensView):
        rgb, _ = camera.warp(rgb, depth, cam_from_world, motion)
        truth = [camera.landmark_truth(t, cam_from_world, motion) for t in truth]
        camera = camera.camera
    if imaging is not None:
        rgb = IMAGING_PRESETS[imaging[0]].apply(rgb, imaging[1])
    out_w, out_h = out_size
    sx, sy = out_w / camera.width, out_h / camera.height
    keypoints = []
    for t, lm in enumerate(truth):
        for i, uv, vis in zip(lm["ids"], lm["uv"], lm["visible"], strict=True):
            if vis:
                u = (uv[0] + 0.5) * sx - 0.5
                v = (uv[1] + 0.5) * sy - 0.5
                keypoints.append([float(u), float(v), t, int(i)])
    if (out_w, out_h) != (camera.width, camera.height):
        rgb = cv2.resize(rgb, (out_w, out_h), interpolation=cv2.INTER_AREA)
    return rgb, keypoints, camera.scaled(out_w, out_h).K


@functools.lru_cache(maxsize=4)
def _lens_view(name: str, width: int, height: int) -> LensView:
    """One :class:`LensView` per preset and size per process (its maps take a moment to build)."""
    return LensView(CAMERA_MODELS[name], width, height)


def render_layout(config: DatasetConfig, layout: int, out_dir: Path | None = None):
    """Render the views of one layout: a list of ``(rgb (H', W', 3), record)``.

    ``record`` is the layout's entry for ``labels.json`` without ``file``. If ``out_dir`` is
    given nothing is returned in memory (images are written as ``layout_view.png`` there).
    """
    from uav_struct_env.sim.activity import ActivityBodies
    from uav_struct_env.sim.world import SiteWorld, random_light

    rng = np.random.default_rng([config.seed, layout])
    if config.site == "random":
        stage = str(rng.choice(["slab", "columns"]))
        marker_size = [None, 0.5, 1.0][int(rng.integers(3))]
        site = random_site(rng, stage=stage, marker_size=marker_size)
    else:
        stages = config.stages or [st.name for st in
                                   make_site(config.site, _first_stage(config.site), None).stages]
        stage = str(rng.choice(stages))
        marker_size = [None, 0.5, 1.0][int(rng.integers(3))]
        site = make_site(config.site, stage, marker_size)
    texture_size = int(rng.choice([128, 256, 512]))
    camera = Camera().scaled(*config.source_size)
    out_w, out_h = config.image_size
    # The real camera's motion: its own stream (the paper dataset's draws are unchanged).
    motion_rng = None if config.camera == "paper" else np.random.default_rng([config.seed, layout, 2])
    imaging_rng = np.random.default_rng([config.seed, layout, 3])
    out = []
    with SiteWorld(site, renderer=config.renderer, image_size=config.source_size,
                   rng=rng.spawn(1)[0], texture_size=texture_size) as world:
        _add_clutter(world, site, rng)
        activity, level = None, layout_activity(config, layout)
        if level != "none":  # its own seed: the layout's other draws are unchanged
            activity = ActivityBodies(world, SiteActivity(site, level, [config.seed, layout, 1]))
        for view in range(config.views_per_layout):
            if activity is not None:
                activity.update(_ACTIVITY_SECONDS_PER_VIEW * view)
            cam_from_world = _random_view(site, rng, config)
            world.light = random_light(rng)
            motion = None if motion_rng is None else random_motion(motion_rng, cam_from_world)
            name = view_camera(config, layout, view)
            view_cam = camera if name == "paper" else _lens_view(name, *config.source_size)
            render_cam = camera if name == "paper" else view_cam.render_camera
            result = world.render(cam_from_world, render_cam, depth=True)
            truth = [world.landmark_truth(t, cam_from_world, render_cam, result) for t in LANDMARK_TYPES]
            imaging = view_imaging(config, layout, view)
            rgb, keypoints, K_out = deliver_view(result.rgb, result.depth, truth, cam_from_world, view_cam,
                                                 (out_w, out_h), motion, (imaging, imaging_rng))
            extra = {} if name == "paper" else {
                "camera": name, "distortion": view_cam.distortion.tolist(),
                "velocity": motion.velocity.tolist(), "angular_velocity": motion.angular_velocity.tolist(),
            }
            if config.activity == "mixed":
                extra["activity"] = level
            if imaging != "ideal":
                extra["imaging"] = imaging
            record = {"layout": layout, "view": view, "stage": stage,
                      "K": K_out.tolist(),
                      "cam_from_world": cam_from_world.tolist(), "keypoints": keypoints, **extra}
            out.append((rgb, record))
    return out


def _first_stage(path: str) -> str | None:
    """A stage to open ``path`` at (an IFC file needs one; a site file has its own)."""
    if path.lower().endswith(".ifc"):
        from uav_struct_env.site.ifc import ifc_stages

        return ifc_stages(path)[0]
    return None


def _layout_job(args):
    config, layout, out_dir = args
    records = []
    for rgb, record in render_layout(config, layout):
        name = f"images/{layout:05d}_{record['view']:02d}.png"
        if not cv2.imwrite(str(Path(out_dir) / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write {Path(out_dir) / name}")
        records.append({"file": name, **record})
    return records


def generate(config: DatasetConfig, out_dir: str | Path, workers: int = 1,
             progress: bool = True, overwrite: bool = False) -> Path:
    """Render the dataset of ``config`` into ``out_dir`` (see the module docstring).

    ``images/`` and ``labels.json`` appear together when the whole dataset is rendered
    (:class:`uav_struct_env.outputs.StagedOutput`); an interrupted run leaves ``out_dir`` as it
    was. A folder that already holds files is refused unless ``overwrite``.

    Returns:
        The path of ``labels.json``.

    Raises:
        uav_struct_env.outputs.OutputExistsError: ``out_dir`` holds files and not ``overwrite``.
        uav_struct_env.processes.WorkerDied: a worker process died (``workers > 1``).
    """
    from tqdm import tqdm

    from uav_struct_env.outputs import StagedOutput
    from uav_struct_env.processes import run_chunks

    with StagedOutput(out_dir, overwrite=overwrite, owned=("labels.json", "images")) as staged:
        stage = staged.stage
        (stage / "images").mkdir()
        jobs = [(config, k, str(stage)) for k in range(config.n_layouts)]
        records: list[dict] = []
        bar = tqdm(total=config.n_layouts * config.views_per_layout, unit="img",
                   disable=not progress)
        # One EGL client per process: each worker renders its layouts one after another.
        results = (map(_layout_job, jobs) if workers == 1
                   else run_chunks(_layout_job, [[j] for j in jobs], workers, name="dataset-worker"))
        try:
            for recs in results:
                records += recs
                bar.update(len(recs))
        finally:
            bar.close()
        records.sort(key=lambda r: (r["layout"], r["view"]))
        _write_labels(stage / "labels.json", config, records)
    return staged.out / "labels.json"


def _write_labels(path: Path, config: DatasetConfig, records: list[dict]) -> None:
    settings = asdict(config)
    for key, default in (("camera", "paper"), ("imaging", "ideal"), ("stages", None)):
        if settings[key] == default:  # as written before the generator had them (load_labels fills it in)
            del settings[key]
    made_by = software()
    labels = {
        "format": FORMAT, "types": list(LANDMARK_TYPES), "image_size": list(config.image_size),
        "source_size": list(config.source_size), "scale": config.scale,
        "config": settings, "software": made_by,
        "settings": settings_line({k: v for k, v in asdict(config).items() if k != "stages" or v is not None},
                                  made_by),
        "images": records,
    }
    path.write_text(json.dumps(labels))


def load_labels(path: str | Path) -> dict:
    """Read a ``labels.json`` (or its directory) and check its format.

    A ``paper`` view's (and config's) camera keys are filled in: ``"camera": "paper"``, zero
    ``distortion``, ``velocity`` and ``angular_velocity``; an ideal one's ``"imaging": "ideal"``.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "labels.json"
    data = json.loads(path.read_text())
    if data.get("format") != FORMAT:
        raise ValueError(f"{path} is not a {FORMAT} label file (format={data.get('format')!r})")
    data["root"] = str(path.parent)
    data["config"].setdefault("camera", "paper")
    data["config"].setdefault("imaging", "ideal")
    for record in data["images"]:
        record.setdefault("camera", "paper")
        record.setdefault("imaging", "ideal")
        for key, n in (("distortion", 5), ("velocity", 3), ("angular_velocity", 3)):
            record.setdefault(key, [0.0] * n)
    return data
