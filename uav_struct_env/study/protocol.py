"""The paper's study protocol as data: the study configuration and the evaluated methods.

A *method* is one row of the paper's Table II: a landmark source (a structural landmark set, or
ArUco markers of one size), the construction stage it is evaluated in and the paper's reported
figures. Methods that share a stage and marker size share a *scene*: the study renders every
scene once per viewpoint and evaluates all of its methods on the same frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from localization.checks import check_choice, check_number
from localization.geometry.camera import PAPER_IMAGE_SIZE
from uav_struct_env.envs.config import LIGHTINGS
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.lens import CAMERA_MODELS
from uav_struct_env.site import make_site
from uav_struct_env.site.activity import ACTIVITY_PRESETS
from uav_struct_env.site.as_built import MAX_SCALE, TOLERANCE_MODELS, AsBuilt
from uav_struct_env.stack import ASSOCIATIONS, STRUCTURAL_DETECTORS, check_weights
from uav_struct_env.stack.spec import resolve_learned
from uav_struct_env.study.tracking import TRACKING_ACTIVITY
from uav_struct_env.tracking_sim import DEFAULT_WORKER_SIGMA_PX

__all__ = [
    "ASSOCIATIONS",
    "DETECTORS",
    "NOISES",
    "METHODS",
    "Method",
    "PaperFigures",
    "Scene",
    "StudyConfig",
]

#: Detector and association names, from the localization stack (uav_struct_env.stack).
DETECTORS = STRUCTURAL_DETECTORS
NOISES = ("paper", "gnss_ins")


@dataclass(frozen=True)
class PaperFigures:
    """The paper's Table I / II figures for one method (None where the paper gives none)."""

    successful: int
    total: int
    translation_median_m: float
    translation_p90_m: float
    rotation_median_deg: float
    rotation_p90_deg: float
    detection_pct: float | None = None
    association_f1_pct: float | None = None
    latency_s: float | None = None


@dataclass(frozen=True)
class Scene:
    """What gets rendered: a construction stage with markers of one size."""

    stage: str
    marker_size: float


@dataclass(frozen=True)
class Method:
    """One evaluated method (a results.json key and a Table II row)."""

    key: str
    label: str
    scene: Scene
    landmarks: str  # landmark set: a structural set, or "aruco"
    aruco_mode: str | None = None  # "average" (the paper's) or "joint"; None for structural
    #: ArUco: the prior picks each marker's IPPE solution (True) or the lowest reprojection
    #: error does (False: what a plain implementation does; it flips on small markers).
    aruco_prior: bool = True
    paper: PaperFigures | None = None

    @property
    def structural(self) -> bool:
        """True for structural landmarks, False for the ArUco baseline."""
        return self.aruco_mode is None


#: Fewest landmarks of a set at its stage for the study to evaluate it (a PnP pose needs four).
MIN_LANDMARKS = 4

_SLAB = Scene("slab", 1.0)
_COLUMNS = Scene("columns", 1.0)

#: Every method the study evaluates, in table order. The paper's figures: Tables I and II.
METHODS: tuple[Method, ...] = (
    Method(
        "slab_corners",
        "Slab corners",
        _SLAB,
        "slab_corners",
        paper=PaperFigures(39, 40, 0.185, 0.363, 0.615, 1.142, 99.10, 100.00, 13.28),
    ),
    Method(
        "opening_corners",
        "Opening corners",
        _SLAB,
        "opening_corners",
        paper=PaperFigures(39, 40, 1.192, 2.607, 2.664, 6.220, 96.88, 100.00, 13.91),
    ),
    Method(
        "column_tops",
        "Column tops",
        _COLUMNS,
        "column_tops",
        paper=PaperFigures(40, 40, 0.163, 3.323, 0.470, 11.503, 95.65, 94.21, 27.13),
    ),
    Method("all", "All structural (columns stage)", _COLUMNS, "all"),
    Method(
        "aruco_0.5m",
        "ArUco, 0.5 m",
        Scene("slab", 0.5),
        "aruco",
        "average",
        paper=PaperFigures(39, 40, 14.929, 35.958, 35.862, 93.235),
    ),
    Method(
        "aruco_1.0m",
        "ArUco, 1.0 m",
        _SLAB,
        "aruco",
        "average",
        paper=PaperFigures(38, 40, 0.658, 1.533, 0.698, 1.631),
    ),
    Method(
        "aruco_0.5m_no_prior",
        "ArUco, 0.5 m, no prior tie-break",
        Scene("slab", 0.5),
        "aruco",
        "average",
        aruco_prior=False,
    ),
    Method(
        "aruco_1.0m_no_prior",
        "ArUco, 1.0 m, no prior tie-break",
        _SLAB,
        "aruco",
        "average",
        aruco_prior=False,
    ),
    Method("aruco_0.5m_joint", "ArUco, 0.5 m, joint PnP", Scene("slab", 0.5), "aruco", "joint"),
    Method("aruco_1.0m_joint", "ArUco, 1.0 m, joint PnP", _SLAB, "aruco", "joint"),
)


@dataclass(frozen=True)
class StudyConfig:
    """Everything that determines a study's numbers (written to ``results.json``).

    Attributes:
        seed: seeds textures, detector noise and the ``gnss_ins`` prior.
        detector: ``"projection"`` (ground-truth projections + pixel noise, as the paper isolated
            association and pose from its vision model) or ``"learned"`` (the trained keypoint
            network of :mod:`localization.detect.learned` on the rendered image; ``pixel_sigma``,
            ``miss_rate`` and ``false_positives`` then only set the localizer's noise model), or
            ``"learned:NAME"`` with a weight set of :mod:`localization.detect.weights`
            (``"learned:active"``: the active-site set), stored as ``"learned"`` with the set's
            two files in ``detector_model`` and ``refiner_model``, or ``"guided"`` (the BIM-guided
            detector, :mod:`uav_struct_env.stack.guided`) and ``"guided:NAME"`` likewise.
        association: ``"robust"`` or ``"paper"`` (plain linear assignment).
        noise: onboard prior model, ``"paper"`` (3 m, 2/2/5 deg, alternating signs) or
            ``"gnss_ins"``.
        site: ``"paper"``, ``"random"`` (drawn from ``seed``), the path of a site file
            (``*.json``) or of an IFC file (``*.ifc``, needs the ``ifc`` extra).
        n_viewpoints: viewpoints per UAV (10 in the paper; ``--quick`` uses 2).
        n_agents: UAVs, one per side (4 in the paper).
        image_size: (W, H); the paper's camera is scaled to it.
        pixel_sigma: the projection detector's noise, px.
        miss_rate: the projection detector's probability of missing a visible landmark.
        false_positives: mean clutter detections per image.
        renderer: ``"auto"``, ``"tiny"`` or ``"egl"``.
        imaging: camera effects on the rendered images (``"ideal"`` or ``"camera"``, see
            :mod:`uav_struct_env.sim.imaging`); they matter to pixel-reading detectors (ArUco,
            learned), not to the projection detector.
        workers: processes rendering and localizing in parallel.
        methods: keys of :data:`METHODS` to run (default all).
        detector_model: with ``detector="learned"``, the keypoint network's ONNX file (None:
            the default weights' ``localization/detect/models/landmarks_v1.onnx``), e.g. one
            retrained with ``python -m uav_struct_env.training.train_detector``; stored resolved to
            an absolute path. It replaces the keypoint network of a ``"learned:NAME"`` set.
        refiner_model: with ``detector="learned"``, the patch refiner's ONNX file (None: the
            default weights' refiner), e.g. from ``python -m uav_struct_env.training.train_refiner``.
        stage: the floor to evaluate, by any of its stage names (``"Level 2/slab"``): the slab
            methods run at the floor's slab stage, column tops at its columns stage. None: the
            paper's first floor (``"slab"`` / ``"columns"``), or an IFC file's last floor.
            Methods whose stage the building lacks (no columns on that floor) are left out.
        as_built: None (the building stands as designed) or a tolerance model of
            :mod:`uav_struct_env.site.as_built` (``"aci117"``): the rendered building and the
            ground truth deviate from the design, element by element, while the localizer keeps
            the design.
        as_built_scale: factor on every tolerance of ``as_built`` (0: the design).
        lighting: ``"fixed"`` (the default sun) or ``"random"`` (a sun drawn per scene and
            viewpoint from the seed, :func:`uav_struct_env.sim.world.random_light`).
        activity: site activity (:mod:`uav_struct_env.site.activity`): ``"none"``, ``"light"``
            or ``"busy"``: workers, equipment, materials and scaffolding laid out per viewpoint
            from the env's reset seed; they hide landmarks in the images and in the truth.
        track_workers: also track the site's workers from the four cameras at true, estimated
            and prior poses (:mod:`uav_struct_env.study.tracking`). Workers need site activity:
            with ``activity="none"`` it is set to ``"light"`` (whose bodies also hide landmarks).
        worker_pixel_sigma: with ``track_workers``, the simulated worker detector's feet /
            head-top noise, px of the images.
        upright_workers: with ``track_workers``, triangulate workers standing (the head top
            above the feet, :func:`tracking.triangulate.triangulate_upright`).
        camera: the camera (:data:`uav_struct_env.sim.lens.CAMERA_MODELS`): ``"paper"`` (the
            paper's ideal pinhole) or ``"mavic2pro"`` (the Mavic 2 Pro's intrinsics, lens
            distortion, rolling shutter and exposure; the localizers get its distortion
            coefficients). At the scripted viewpoints the UAVs hover, so the rolling shutter and
            blur have no motion to show; the distortion always applies.
    """

    seed: int = 0
    detector: str = "projection"
    association: str = "robust"
    noise: str = "paper"
    site: str = "paper"
    n_viewpoints: int = 10
    n_agents: int = 4
    image_size: tuple[int, int] = PAPER_IMAGE_SIZE
    pixel_sigma: float = 1.0
    miss_rate: float = 0.0
    false_positives: float = 0.0
    renderer: str = "auto"
    imaging: str = "ideal"
    workers: int = 1
    methods: tuple[str, ...] = field(default_factory=lambda: tuple(m.key for m in METHODS))
    detector_model: str | None = None
    refiner_model: str | None = None
    stage: str | None = None
    as_built: str | None = None
    as_built_scale: float = 1.0
    lighting: str = "fixed"
    activity: str = "none"
    track_workers: bool = False
    worker_pixel_sigma: float = DEFAULT_WORKER_SIGMA_PX
    upright_workers: bool = False
    camera: str = "paper"

    def __post_init__(self) -> None:
        resolved = resolve_learned(self.detector, self.detector_model, self.refiner_model)
        for name, value in zip(("detector", "detector_model", "refiner_model"), resolved, strict=True):
            object.__setattr__(self, name, value)
        for name, options in (
            ("detector", DETECTORS),
            ("imaging", ("ideal", "camera")),
            ("association", ASSOCIATIONS),
            ("noise", NOISES),
        ):
            check_choice(name, getattr(self, name), options, error=ConfigError)
        if not isinstance(self.site, str) or not (
            self.site in ("paper", "random") or Path(self.site).is_file()
        ):
            raise ConfigError(
                f"site must be 'paper', 'random' or an existing site file (*.json) or IFC file (*.ifc), "
                f"got {self.site!r}"
            )
        if self.stage is not None and not isinstance(self.stage, str):
            raise ConfigError(f"stage must be a stage name (str) or None, got {self.stage!r}")
        check_number("seed", self.seed, 0, integer=True, error=ConfigError, type_error=ConfigError)
        for name in ("n_viewpoints", "n_agents", "workers"):
            check_number(
                name, getattr(self, name), 1, integer=True, error=ConfigError, type_error=ConfigError
            )
        for name, lo, hi in (
            ("pixel_sigma", 0.0, None),
            ("miss_rate", 0.0, 1.0),
            ("false_positives", 0.0, None),
        ):
            check_number(name, getattr(self, name), lo, hi, error=ConfigError, type_error=ConfigError)
        check_choice("lighting", self.lighting, LIGHTINGS, error=ConfigError)
        check_choice("activity", self.activity, tuple(ACTIVITY_PRESETS), error=ConfigError)
        for name in ("track_workers", "upright_workers"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"{name} must be True or False, got {getattr(self, name)!r}")
        check_number("worker_pixel_sigma", self.worker_pixel_sigma, 0.0, lo_open=True, error=ConfigError,
                     type_error=ConfigError)
        if self.track_workers and self.activity == "none":
            object.__setattr__(self, "activity", TRACKING_ACTIVITY)
        check_choice("camera", self.camera, tuple(CAMERA_MODELS), error=ConfigError)
        if self.as_built is not None:
            check_choice("as_built", self.as_built, tuple(TOLERANCE_MODELS), error=ConfigError)
        check_number("as_built_scale", self.as_built_scale, 0.0, MAX_SCALE, error=ConfigError,
                     type_error=ConfigError)
        for name in ("detector_model", "refiner_model"):
            v = check_weights(name, getattr(self, name), self.detector)
            object.__setattr__(self, name, None if v is None else str(Path(v).resolve()))
        keys = [m.key for m in METHODS]
        unknown = [k for k in self.methods if k not in keys]
        if unknown or not self.methods:
            raise ConfigError(f"methods must be a non-empty subset of {keys}, got {list(self.methods)}")
        object.__setattr__(self, "methods", tuple(self.methods))
        object.__setattr__(self, "image_size", tuple(int(v) for v in self.image_size))
        stages, skips = self._resolve_stages()
        object.__setattr__(self, "_stages", stages)
        object.__setattr__(self, "_skips", skips)

    def _resolve_stages(self) -> tuple[dict[str, str | None], dict[str, str]]:
        """Stage name for each scene role (``"slab"``, ``"columns"``) on this site, and the skips.

        A structural method is skipped (with the reason) when its role has no stage on this
        building's floor or its landmark set has fewer than MIN_LANDMARKS landmarks there.
        """
        if self.stage is None and (self.site in ("paper", "random") or self.site.endswith(".json")):
            return {"slab": "slab", "columns": "columns"}, {}
        try:
            site = make_site(
                self.site, stage=self.stage, marker_size=None, rng=np.random.default_rng(self.seed)
            )
        except ValueError as err:  # SiteGeometryError: an unknown stage, a malformed file
            raise ConfigError(str(err)) from None
        stages = {role: site.floor_stage(role) for role in ("slab", "columns")}
        skips: dict[str, str] = {}
        for m in METHODS:
            stage = stages[m.scene.stage]
            if stage is None and stages["slab"] is None:
                skips[m.key] = f"stage {stages['columns']!r} has no floor (a frame of columns only)"
            elif stage is None:
                skips[m.key] = f"the floor of stage {stages['slab']!r} has no columns stage"
            elif m.structural:
                n = len(site.with_stage(stage).landmarks(m.landmarks))
                if n < MIN_LANDMARKS:
                    skips[m.key] = (f"stage {stage!r} exposes {n} {m.landmarks} (at least "
                                    f"{MIN_LANDMARKS} are needed for a pose)")
        return stages, skips

    @property
    def as_built_model(self) -> AsBuilt | None:
        """The env's as-built model (seeded with ``seed``), or None for the design."""
        if self.as_built is None:
            return None
        return AsBuilt(self.as_built, self.as_built_scale, seed=self.seed)

    def scene_stage(self, scene: Scene) -> str:
        """The site's stage name that ``scene`` is rendered at."""
        return self._stages[scene.stage]

    @property
    def skipped_methods(self) -> tuple[str, ...]:
        """Requested methods this building cannot evaluate (see :attr:`skip_reasons`)."""
        return tuple(m.key for m in METHODS if m.key in self.methods and m.key in self._skips)

    @property
    def skip_reasons(self) -> dict[str, str]:
        """Why each of :attr:`skipped_methods` is left out: no columns stage, or < 4 landmarks."""
        return {k: self._skips[k] for k in self.skipped_methods}

    @property
    def selected_methods(self) -> tuple[Method, ...]:
        """The methods to run, in table order (without :attr:`skipped_methods`)."""
        return tuple(m for m in METHODS if m.key in self.methods and m.key not in self._skips)

    @property
    def scenes(self) -> tuple[Scene, ...]:
        """The distinct scenes the selected methods need, in first-use order."""
        out: list[Scene] = []
        for m in self.selected_methods:
            if m.scene not in out:
                out.append(m.scene)
        return tuple(out)
