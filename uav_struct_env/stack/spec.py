"""The localization stack as data: a :class:`StackSpec` and the one builder, :func:`build_stack`.

A stack is what turns one camera frame into a pose: a detector (a name, or any object that
follows :class:`localization.Detector`), an association method, the localizer's noise model and
gates, model weights and prior sigmas. The study (:mod:`uav_struct_env.study.run`), the
:class:`~uav_struct_env.wrappers.LocalizationWrapper` and the benchmarks all build theirs here,
so a new option is added in one place, and the choice lists (:data:`DETECTORS`,
:data:`ASSOCIATIONS`) are spelled once.

Two policies differed between the study and the wrapper; they are fields with each caller's
value as that caller's default, so neither's numbers change:

* ``min_localizer_sigma_px``: the localizer's noise model is ``max(pixel_sigma, this)``. The
  study uses 0.5 px (a noise-free projection detector must not make the gates collapse), the
  wrapper 0 (its 128 x 72 default noise is 0.1 px).
* ``scale_gates``: the robust association's gates are given in px of the paper's 1280-px-wide
  camera (inlier-gate floor 3 px, coarse gate 40 px) and scaled by ``W / 1280`` (the wrapper's
  policy); ``False`` keeps them in px of the image (the study's). At 1280 px they agree.

Layers: this package imports :mod:`localization` and :mod:`uav_struct_env.site` only (never
``wrappers`` or ``study``).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization import ASSOCIATION_METHODS, Detector, Localizer, PriorSigmas, ProjectionDetector
from localization.checks import check_choice, check_number
from localization.detect.weights import WEIGHT_NAMES, weight_set
from localization.geometry.camera import PAPER_IMAGE_SIZE
from uav_struct_env.errors import ConfigError
from uav_struct_env.site import LANDMARK_SETS
from uav_struct_env.stack.frame import FrameLocalization, localize_aruco_frame, localize_frame

__all__ = [
    "ASSOCIATIONS",
    "DETECTORS",
    "PAPER_WIDTH_PX",
    "STRUCTURAL_DETECTORS",
    "LocalizationStack",
    "StackSpec",
    "build_stack",
    "check_weights",
    "resolve_learned",
]

#: Detectors of structural landmarks, by name (any :class:`localization.Detector` object works too).
STRUCTURAL_DETECTORS: tuple[str, ...] = ("projection", "learned", "guided")
#: Every detector name: the structural ones and the ArUco markers' own (``landmarks="aruco"``).
DETECTORS: tuple[str, ...] = (*STRUCTURAL_DETECTORS, "aruco")
#: Association methods of :class:`localization.Localizer`.
ASSOCIATIONS: tuple[str, ...] = tuple(ASSOCIATION_METHODS)
#: Width of the paper's camera; pixel quantities "at the paper's resolution" scale by W / this.
PAPER_WIDTH_PX: int = PAPER_IMAGE_SIZE[0]
#: ArUco pose modes of :class:`localization.aruco.ArucoLocalizer`.
_ARUCO_MODES = ("average", "joint")
#: Detectors that run the learned detector's networks (and take its weight files).
_LEARNED_DETECTORS = ("learned", "guided")


def resolve_learned(detector: Any, detector_model: Any, refiner_model: Any) -> tuple[Any, Any, Any]:
    """``(detector, detector_model, refiner_model)`` with a ``"learned:NAME"`` or ``"guided:NAME"`` resolved.

    ``"learned:NAME"`` names a weight set of :mod:`localization.detect.weights`
    (``learned:landmarks_v1``, ``learned:landmarks_active_v4`` or ``learned:active``): it becomes
    ``"learned"`` with that set's keypoint network and refiner files, each unless given explicitly;
    ``"guided:NAME"`` likewise becomes ``"guided"`` (the BIM-guided detector, whose first pass runs
    the learned networks) with the set's files. Any other detector is returned unchanged with the
    two files.

    Raises:
        ConfigError: for an unknown weight-set name, listing the known ones.
    """
    kind, sep, name = detector.partition(":") if isinstance(detector, str) else ("", "", "")
    if not sep or kind not in _LEARNED_DETECTORS:
        return detector, detector_model, refiner_model
    if name not in WEIGHT_NAMES:
        raise ConfigError(
            f"detector {detector!r} names unknown weights {name!r}; '{kind}:NAME' takes NAME one of "
            f"{WEIGHT_NAMES}"
        )
    named = weight_set(name)
    return (
        kind,
        named.model if detector_model is None else detector_model,
        named.refiner if refiner_model is None else refiner_model,
    )


def check_weights(name: str, path: Any, detector: Any) -> str | Path | None:
    """Return ``path`` (None allowed) if it is an existing file and ``detector`` runs the learned networks.

    Raises:
        ConfigError: naming ``name``, for weights given to another detector or a missing file.
    """
    if path is None:
        return None
    if detector not in _LEARNED_DETECTORS:
        raise ConfigError(f"{name} applies to detector='learned' or 'guided' only, got detector={detector!r}")
    if not isinstance(path, (str, Path)) or not Path(path).is_file():
        raise ConfigError(f"{name} must be an existing ONNX file, got {path!r}")
    stat = Path(path).stat()
    why = _onnx_load_error(str(Path(path).resolve()), stat.st_mtime_ns, stat.st_size)
    if why is not None:  # a corrupt file is refused with the options, not mid-run with a traceback
        raise ConfigError(f"{name}: {why}")
    return path


@functools.lru_cache(maxsize=16)
def _onnx_load_error(path: str, mtime_ns: int, size: int) -> str | None:
    """Why ONNX Runtime cannot load ``path`` (as it stands: ``mtime_ns``, ``size``), or None."""
    from localization.detect.onnx_net import OnnxNet

    try:
        OnnxNet(path)
    except ValueError as err:
        return str(err)
    return None


@dataclass(frozen=True)
class StackSpec:
    """Everything that decides how a frame is localized (but not the scene or the camera).

    Attributes:
        landmarks: landmark set: ``slab_corners``, ``opening_corners``, ``column_tops``,
            ``aruco`` or ``all``.
        detector: ``"projection"`` (true projections + noise, misses, clutter),
            ``"learned"`` (:class:`localization.detect.learned.LearnedDetector` on the image, with
            the default weights), ``"learned:NAME"`` (the same with the weight set ``NAME`` of
            :mod:`localization.detect.weights`, e.g. ``"learned:active"``; stored as
            ``"learned"`` with that set's two files in ``detector_model`` and ``refiner_model``),
            ``"guided"`` (:class:`uav_struct_env.stack.guided.GuidedDetector`: the learned
            detector, a first pose, then the building model's templates matched at that pose;
            needs the site: ``build_stack(..., site=)``), ``"guided:NAME"`` (the same with the
            weight set ``NAME``, e.g. ``"guided:active"``; stored as ``"guided"`` with its files),
            ``"aruco"`` (OpenCV markers; needs ``landmarks="aruco"``), or any object with
            ``detect(image, context) -> Detections`` (used as given).
        association: ``"robust"`` or ``"paper"``.
        pixel_sigma: the projection detector's noise, px of the images; None: 1 px at the
            paper's 1280-px-wide camera scaled to the image width.
        min_localizer_sigma_px: floor of the localizer's noise model (module docstring).
        scale_gates: scale the robust gates with the image width (module docstring).
        miss_rate: projection detector: probability of missing a visible landmark.
        false_positives: projection detector: mean clutter detections per image.
        detector_model: learned (or guided) detector: keypoint-network ONNX file (None: the
            default weights').
        refiner_model: learned (or guided) detector: patch-refiner ONNX file (None: the default
            weights').
        prior_sigmas: the onboard prior's sigmas for the localizer (None: 3 m, 2/2/5 deg).
        aruco_mode: ``"joint"`` (one PnP over all corners) or ``"average"`` (the paper's).
        aruco_prior: the prior chooses each marker's IPPE solution (False: the lowest
            reprojection error does).
        aruco_pixel_sigma: ArUco corner noise, px (floored by ``min_localizer_sigma_px``).
        localizer_kwargs: further :class:`localization.Localizer` arguments (override the
            gates derived here).
        confirm: hold a final pose on few pairs to the building's structure matched in the image
            (:mod:`uav_struct_env.stack.confirm`) when the stack is built with a site and a
            detector that reads the image (every structural one but ``"projection"``); False:
            report the localizer's pose as it is.

    Raises:
        ConfigError: for an unknown name, a bad number or an option that does not apply.
    """

    landmarks: str = "column_tops"
    detector: str | Detector = "projection"
    association: str = "robust"
    pixel_sigma: float | None = None
    min_localizer_sigma_px: float = 0.0
    scale_gates: bool = True
    miss_rate: float = 0.0
    false_positives: float = 0.0
    detector_model: str | Path | None = None
    refiner_model: str | Path | None = None
    prior_sigmas: PriorSigmas | tuple | None = None
    aruco_mode: str = "joint"
    aruco_prior: bool = True
    aruco_pixel_sigma: float = 1.0
    localizer_kwargs: Mapping[str, Any] = field(default_factory=dict)
    confirm: bool = True

    def __post_init__(self) -> None:
        check_choice("landmarks", self.landmarks, LANDMARK_SETS, error=ConfigError)
        resolved = resolve_learned(self.detector, self.detector_model, self.refiner_model)
        for name, value in zip(("detector", "detector_model", "refiner_model"), resolved, strict=True):
            object.__setattr__(self, name, value)
        if isinstance(self.detector, str):
            check_choice("detector", self.detector, DETECTORS, error=ConfigError)
        elif not isinstance(self.detector, Detector):
            raise ConfigError(
                f"detector must be one of {DETECTORS} or an object with detect(image, context), "
                f"got {self.detector!r}"
            )
        if self.detector in _LEARNED_DETECTORS and self.landmarks == "aruco":
            raise ConfigError(f"detector={self.detector!r} detects structural landmarks, not 'aruco'")
        if self.detector == "aruco" and self.landmarks != "aruco":
            raise ConfigError(f"detector='aruco' needs landmarks='aruco', got {self.landmarks!r}")
        check_choice("association", self.association, ASSOCIATIONS, error=ConfigError)
        check_choice("aruco_mode", self.aruco_mode, _ARUCO_MODES, error=ConfigError)
        for name in ("detector_model", "refiner_model"):
            check_weights(name, getattr(self, name), self.detector)
        if self.pixel_sigma is not None:
            check_number("pixel_sigma", self.pixel_sigma, 0.0, error=ConfigError, type_error=ConfigError)
        for name, hi in (
            ("min_localizer_sigma_px", None),
            ("miss_rate", 1.0),
            ("false_positives", None),
            ("aruco_pixel_sigma", None),
        ):
            check_number(name, getattr(self, name), 0.0, hi, error=ConfigError, type_error=ConfigError)
        object.__setattr__(self, "localizer_kwargs", dict(self.localizer_kwargs))
        if not isinstance(self.confirm, (bool, np.bool_)):
            raise ConfigError(f"confirm must be True or False, got {self.confirm!r}")

    @property
    def structural(self) -> bool:
        """True unless the stack localizes from ArUco markers."""
        return self.landmarks != "aruco"

    def detector_sigma(self, image_width: int) -> float:
        """The projection detector's pixel noise at images ``image_width`` px wide."""
        scale = image_width / PAPER_WIDTH_PX
        return scale if self.pixel_sigma is None else float(self.pixel_sigma)

    def localizer_arguments(self, image_size: tuple[int, int]) -> dict[str, Any]:
        """The keyword arguments of :class:`localization.Localizer` for images of ``image_size``."""
        sigma = max(self.detector_sigma(image_size[0]), self.min_localizer_sigma_px)
        out: dict[str, Any] = {"pixel_sigma": sigma, "image_size": tuple(image_size)}
        if self.scale_gates:
            scale = image_size[0] / PAPER_WIDTH_PX
            out["gate_px"] = max(5.0 * sigma, 3.0 * scale)
            out["coarse_gate_px"] = 40.0 * scale
        if self.prior_sigmas is not None:
            out["prior_sigmas"] = self.prior_sigmas
        return {**out, **self.localizer_kwargs}


@dataclass(eq=False)
class LocalizationStack:
    """A built stack: detector + localizer (or the ArUco localizer) for one landmark set.

    Attributes:
        spec: what it was built from.
        image_size: (W, H) of the frames it localizes.
        model_ids: (M,) landmark id of each model index.
        detector: the structural detector (None for ArUco).
        localizer: the :class:`localization.Localizer` (None for ArUco).
        aruco: the :class:`localization.aruco.ArucoLocalizer` (None for structural sets).
        confirmation: the :class:`~uav_struct_env.stack.confirm.PoseConfirmation` its final
            poses are held to (None: none).
    """

    spec: StackSpec
    image_size: tuple[int, int]
    model_ids: NDArray[np.int64]
    detector: Any = None
    localizer: Localizer | None = None
    aruco: Any = None
    confirmation: Any = None

    @property
    def prior_std(self) -> NDArray[np.float64]:
        """(6,) the prior's standard deviations (position m, rotation rad) in the localizer's terms."""
        sigmas = self.localizer.prior_sigmas if self.localizer is not None else PriorSigmas()
        return sigmas.as_array()

    def seed(self, rng: np.random.Generator) -> None:
        """Let a simulated (projection) detector draw from ``rng`` from now on."""
        if isinstance(self.detector, ProjectionDetector):
            self.detector.rng = rng

    def localize(
        self,
        image: Any,
        landmark_truth: Mapping[str, Any] | None,
        prior_cam_from_world: NDArray[np.float64],
        gt_cam_from_world: NDArray[np.float64] | None = None,
        prior_sigmas: PriorSigmas | None = None,
        warm_start: NDArray[np.float64] | None = None,
    ) -> FrameLocalization:
        """Detect, localize and score one frame.

        Args:
            image: the (H, W, 3) uint8 frame (ignored by the projection detector).
            landmark_truth: per-set landmark truth (``info["landmarks"]``: set name -> dict of
                ``ids``, ``xyz``, ``uv``, ``in_frame``, ``visible``); the projection detector
                needs it, the others use it for scoring only. None or {} without truth.
            prior_cam_from_world: (4, 4) onboard prior.
            gt_cam_from_world: (4, 4) ground truth, or None (errors are then NaN).
            prior_sigmas: this frame's prior sigmas for structural association (a filter's
                prediction); None: the localizer's. ArUco poses take the prior as a tie-break only.
            warm_start: a (4, 4) ``cam_from_world`` predicted for this frame, tried before the
                robust association's search (:meth:`localization.Localizer.localize`); None:
                the full search. ArUco ignores it.
        """
        if self.aruco is not None:
            return localize_aruco_frame(
                self.aruco,
                image,
                prior_cam_from_world,
                gt_cam_from_world,
                use_prior=self.spec.aruco_prior,
            )
        context = {"landmarks": dict(landmark_truth or {}), "image_size": self.image_size,
                   "prior_cam_from_world": prior_cam_from_world}
        return localize_frame(
            self.detector,
            self.localizer,
            image,
            context,
            prior_cam_from_world,
            gt_cam_from_world,
            self.model_ids,
            prior_sigmas=prior_sigmas,
            warm_start=warm_start,
            confirmation=self.confirmation,
        )


_LEARNED: dict[tuple, Any] = {}


def _learned(spec: StackSpec, width: int) -> Any:
    """One learned detector per process and (set, width, association, weights): they are large."""
    from localization.detect.learned import LearnedDetector

    key = (
        spec.landmarks,
        int(width),
        spec.association,
        None if spec.detector_model is None else str(spec.detector_model),
        True if spec.refiner_model is None else str(spec.refiner_model),
    )
    if key not in _LEARNED:
        _LEARNED[key] = LearnedDetector.for_localizer(*key)
    return _LEARNED[key]


_SEEDS: dict[int, Any] = {}  # id of a shared learned detector -> its SharedSeed
_TEMPLATES: list[tuple[Any, Any]] = []  # (site, its SiteTemplates): the last site's only
_STARTS: list[tuple[Any, Any, Any]] = []  # (site, wide landmarks, their PriorStarts): the last site's


def _templates(site: Any) -> Any:
    """The :class:`~uav_struct_env.sim.templates.SiteTemplates` of ``site`` (the last site's are kept)."""
    from uav_struct_env.sim.templates import SiteTemplates

    if not _TEMPLATES or _TEMPLATES[0][0] is not site:
        _TEMPLATES[:] = [(site, SiteTemplates(site))]
    return _TEMPLATES[0][1]


def _shared_seed(detector: Any) -> Any:
    """The :class:`~uav_struct_env.stack.frame_memo.SharedSeed` of a (shared) learned detector."""
    from uav_struct_env.stack.frame_memo import SharedSeed

    if id(detector) not in _SEEDS or _SEEDS[id(detector)].detector is not detector:
        _SEEDS[id(detector)] = SharedSeed(detector)
    return _SEEDS[id(detector)]


def _prior_starts(site: Any, wide_xyz: NDArray[np.float64], localizer: Localizer) -> Any:
    """The :class:`~uav_struct_env.stack.prior_starts.PriorStarts` of ``site``, its landmarks and camera.

    One per site (the last site's kept), landmarks and camera: every set's guided detector of a
    frame asks it for the same starts.
    """
    from localization.detect.guided import TemplateMatcher
    from localization.detect.prior_align import PriorAligner
    from uav_struct_env.stack.prior_starts import PriorStarts

    if _STARTS and _STARTS[0][0] is not site:
        _STARTS.clear()
    for _, xyz, starts in _STARTS:
        if np.array_equal(xyz, wide_xyz) and starts.same_camera(localizer.K, localizer.distortion):
            return starts
    templates = _templates(site)
    starts = PriorStarts(PriorAligner(templates), TemplateMatcher(wide_xyz, templates), localizer.K,
                         localizer.distortion)
    _STARTS[:] = [*_STARTS[-3:], (site, np.array(wide_xyz, copy=True), starts)]
    return starts


def _guided(spec: StackSpec, size: tuple[int, int], localizer: Localizer, xyz: NDArray[np.float64],
            site: Any) -> Any:
    """The guided detector of ``spec``'s set: the learned one (all types) as its seed, templates of ``site``.

    Its anchors are every structural landmark of the site's stage, localized like the set (the
    same arguments), unless the stage has no landmark besides the set's.
    """
    from localization.detect.guided import TemplateMatcher
    from localization.detect.learned import LANDMARK_TYPES
    from uav_struct_env.site import Site
    from uav_struct_env.stack.guided import GuidedDetector

    if not isinstance(site, Site):
        raise ConfigError(
            f"detector='guided' renders the building model: build_stack needs site=, got {site!r}"
        )
    matcher = TemplateMatcher(xyz, _templates(site))
    seed = _shared_seed(_learned(replace(spec, landmarks="all"), size[0]))
    types = range(len(LANDMARK_TYPES)) if spec.landmarks == "all" else [LANDMARK_TYPES.index(spec.landmarks)]
    every = site.landmarks("all").xyz
    anchors = None
    if spec.landmarks != "all" and len(every) > len(xyz):
        anchors = Localizer(every, localizer.K, association=spec.association, distortion=localizer.distortion,
                            **spec.localizer_arguments(size))
    starts = _prior_starts(site, xyz if anchors is None else every, localizer)
    return GuidedDetector(seed, types, localizer, matcher, spec.landmarks, anchors=anchors,
                          prior_starts=starts)


def build_stack(
    spec: StackSpec,
    K: ArrayLike,
    image_size: Sequence[int],
    *,
    model_xyz: ArrayLike | None = None,
    model_ids: ArrayLike | None = None,
    markers: Sequence[Any] = (),
    rng: np.random.Generator | None = None,
    distortion: ArrayLike | None = None,
    site: Any = None,
) -> LocalizationStack:
    """Build the stack of ``spec`` for a camera ``K`` with images of ``image_size`` (W, H).

    Args:
        spec: the :class:`StackSpec`.
        K: (3, 3) intrinsics of the frames.
        image_size: (W, H) of the frames.
        model_xyz: (M, 3) the landmark set's BIM points (structural sets).
        model_ids: (M,) their ids (default ``0 .. M-1``).
        markers: the site's ArUco markers (``landmarks="aruco"``).
        rng: the projection detector's generator (see :meth:`LocalizationStack.seed`).
        distortion: the frames' OpenCV distortion coefficients (``info["distortion"]``), or
            None for a pinhole; the localizer (or the ArUco localizer) undistorts detections
            with them at its entry.
        site: the site as designed (a :class:`~uav_struct_env.site.Site`): the building model
            that ``detector="guided"`` renders its templates from, and that the final poses of
            every detector reading the image are confirmed against (``spec.confirm``); None: no
            confirmation.

    Raises:
        ConfigError: with fewer than 4 landmarks, no markers for ArUco, or no site for
            ``detector="guided"``.
    """
    w, h = (int(v) for v in image_size)
    K = np.asarray(K, dtype=np.float64)
    if not spec.structural:
        try:
            from localization.aruco import ArucoLocalizer
        except ImportError as e:  # OpenCV's aruco module missing
            raise ConfigError(f"detector='aruco' is not available: {e}") from None
        if not markers:
            raise ConfigError("detector='aruco' needs markers: build the env with marker_size set")
        sigma = max(spec.aruco_pixel_sigma, spec.min_localizer_sigma_px)
        aruco = ArucoLocalizer(
            markers, K, mode=spec.aruco_mode, pixel_sigma=sigma, dist_coeffs=distortion
        )
        ids = np.repeat(np.array([m.id for m in aruco.markers], dtype=np.int64), 4)
        return LocalizationStack(spec, (w, h), ids, aruco=aruco)
    xyz = np.asarray(model_xyz, dtype=np.float64).reshape(-1, 3)
    if len(xyz) < 4:
        raise ConfigError(
            f"landmark set {spec.landmarks!r} has {len(xyz)} landmarks; at least 4 are needed to "
            "localize"
        )
    ids = np.arange(len(xyz)) if model_ids is None else np.asarray(model_ids)
    localizer = Localizer(
        xyz, K, association=spec.association, distortion=distortion,
        **spec.localizer_arguments((w, h)),
    )
    if not isinstance(spec.detector, str):
        detector = spec.detector
    elif spec.detector == "learned":
        detector = _learned(spec, w)
    elif spec.detector == "guided":
        detector = _guided(spec, (w, h), localizer, xyz, site)
    else:
        detector = ProjectionDetector(
            spec.landmarks, spec.detector_sigma(w), spec.miss_rate, spec.false_positives, rng=rng
        )
    return LocalizationStack(spec, (w, h), ids.astype(np.int64), detector, localizer,
                             confirmation=_confirmation(spec, localizer, site))


def _confirmation(spec: StackSpec, localizer: Localizer, site: Any) -> Any:
    """The stack's :class:`~uav_struct_env.stack.confirm.PoseConfirmation`, or None.

    None without a site, with ``spec.confirm`` off, or for the projection detector (simulated
    detections, not the image's).
    """
    from uav_struct_env.site import Site

    if not spec.confirm or spec.detector == "projection" or not isinstance(site, Site):
        return None
    from localization.verify import CONFIRM_TOLERANCE_M
    from uav_struct_env.stack.confirm import confirmation_for

    return confirmation_for(_templates(site), site.landmarks("all").xyz, localizer, CONFIRM_TOLERANCE_M)
