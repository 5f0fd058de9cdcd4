"""Run the study: render every scene from every scripted viewpoint and evaluate every method.

The unit of work is one (scene, viewpoint): one ``reset(options={"viewpoint": k})`` of the
four-UAV environment, which renders the four UAV views with the paper's prior perturbation, and
then every method of that scene on the four frames. Workers (``workers > 1``) are spawned
processes that keep one environment per scene alive across the viewpoints they are given, so
each site is loaded at most once per process. Every random draw is seeded from
``(seed, method, uav, viewpoint)``, so the numbers do not depend on how the work is split.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from localization import cramer_rao_bound
from localization.geometry.transforms import camera_center, invert, project
from localization.warmup import warm_up
from uav_struct_env.processes import run_chunks
from uav_struct_env.stack import FrameLocalization, StackSpec, build_stack
from uav_struct_env.study.detections import DetectionRow, detection_rows
from uav_struct_env.study.protocol import METHODS, Method, Scene, StudyConfig
from uav_struct_env.study.tracking import ViewpointTracking, track_viewpoint

__all__ = [
    "ImageResult",
    "Overlay",
    "StudyInterrupted",
    "bound_pixel_sigma",
    "bound_source",
    "iter_study",
    "run_unit",
    "run_unit_tracked",
    "run_units",
    "run_units_tracked",
    "stack_spec",
]


@dataclass(frozen=True)
class ImageResult:
    """One method on one image (a row of ``per_image.csv``)."""

    method: str
    uav: int
    viewpoint: int
    success: bool
    failure_reason: str
    failure_code: str  # a localization.FailureCode value, "" on success
    translation_error_m: float
    rotation_error_deg: float
    prior_translation_error_m: float
    prior_rotation_error_deg: float
    n_visible: int
    n_detections: int
    n_true_detections: int
    n_assigned: int
    n_correct: int
    n_inliers: int
    reprojection_rmse_px: float
    crb_translation_m: float  # Cramér-Rao bound (RMS) at crb_pixel_sigma_px; NaN for markers
    crb_rotation_deg: float
    latency_s: float
    gt_x: float
    gt_y: float
    gt_z: float
    prior_x: float
    prior_y: float
    prior_z: float
    est_x: float
    est_y: float
    est_z: float
    #: RMS distance (px) of this image's true detections from their landmarks' true
    #: projections (NaN without any; markers: NaN).
    pixel_error_rms_px: float = float("nan")
    #: the per-axis pixel noise the bound columns assume (see :func:`bound_pixel_sigma`).
    crb_pixel_sigma_px: float = float("nan")


@dataclass(frozen=True, eq=False)
class Overlay:
    """What Fig. 2 draws for one structural method on one image."""

    method: str
    uav: int
    viewpoint: int
    image: NDArray[np.uint8]
    detections_uv: NDArray[np.float64]
    assignment: NDArray[np.int64]
    correct: NDArray[np.bool_]
    model_uv_prior: NDArray[np.float64]
    model_uv_final: NDArray[np.float64]
    success: bool


# ------------------------------------------------------------------------------- per process
_ENVS: dict[Scene, object] = {}


def _env_for(config: StudyConfig, scene: Scene):
    """The environment of ``scene``, kept for the next viewpoints of the same scene.

    One lives per process at a time: switching scenes closes the previous one (memory; a site
    is loaded once per contiguous run of viewpoints).
    """
    env = _ENVS.get(scene)
    if env is None:
        _close_envs()
        import uav_struct_env

        env = uav_struct_env.parallel_env(
            stage=config.scene_stage(scene),
            marker_size=scene.marker_size,
            site=config.site,
            image_size=config.image_size,
            noise=config.noise,
            renderer=config.renderer,
            imaging=config.imaging,
            n_agents=config.n_agents,
            texture_seed=config.seed,
            as_built=config.as_built_model,
            lighting=config.lighting,
            activity=config.activity,
            camera=config.camera,
        )
        _ENVS[scene] = env
    return env


def _close_envs() -> None:
    for env in _ENVS.values():
        env.close()
    _ENVS.clear()


def _rng(config: StudyConfig, method: Method, uav: int, viewpoint: int) -> np.random.Generator:
    index = next(i for i, m in enumerate(METHODS) if m.key == method.key)
    return np.random.default_rng([config.seed, index, uav, viewpoint])


def stack_spec(config: StudyConfig, method: Method) -> StackSpec:
    """The localization stack the study runs ``method`` with.

    The study's own policies: the localizer's noise model is floored at 0.5 px (a noise-free
    projection detector must not collapse the gates) and the gates stay in px of the image; with
    the learned detector the verification's fit tests assume its declared noise for the study's
    weights and imaging (:func:`localization.detect.learned.fit_pixel_sigma`), with the guided one
    :data:`localization.detect.guided.GUIDED_FIT_SIGMA_PX`, and a pose must be confirmed within
    :data:`localization.verify.CONFIRM_TOLERANCE_M`.
    """
    kwargs = {}
    if method.structural and config.detector in ("learned", "guided"):
        from localization.detect.guided import GUIDED_FIT_SIGMA_PX
        from localization.detect.learned import fit_pixel_sigma  # onnxruntime only when it is used
        from localization.verify import CONFIRM_TOLERANCE_M

        kwargs["fit_sigma_px"] = GUIDED_FIT_SIGMA_PX if config.detector == "guided" else fit_pixel_sigma(
            config.image_size[0], config.imaging, config.detector_model, config.refiner_model
        )
        kwargs["tolerance_m"] = CONFIRM_TOLERANCE_M
    return StackSpec(
        landmarks=method.landmarks,
        detector=config.detector if method.structural else "aruco",
        association=config.association,
        pixel_sigma=config.pixel_sigma,
        min_localizer_sigma_px=0.5,
        scale_gates=False,
        miss_rate=config.miss_rate,
        false_positives=config.false_positives,
        detector_model=config.detector_model if method.structural else None,
        refiner_model=config.refiner_model if method.structural else None,
        aruco_mode=method.aruco_mode or "joint",
        aruco_prior=method.aruco_prior,
        aruco_pixel_sigma=config.pixel_sigma,
        localizer_kwargs=kwargs,
    )


def run_unit(config: StudyConfig, scene: Scene, viewpoint: int, overlay_viewpoint: int = 0):
    """Render ``scene`` at ``viewpoint`` and evaluate its methods: ``(results, overlays)``."""
    results, overlays, _, _ = run_unit_tracked(config, scene, viewpoint, overlay_viewpoint)
    return results, overlays


def run_unit_tracked(config: StudyConfig, scene: Scene, viewpoint: int, overlay_viewpoint: int = 0):
    """:func:`run_unit` and, with ``config.track_workers``, the viewpoint's worker tracking.

    Returns ``(results, overlays, tracking, detections)``; ``tracking`` is a list with one
    :class:`~uav_struct_env.study.tracking.ViewpointTracking` for a scene with structural
    methods when workers are tracked, else empty; ``detections`` one
    :class:`~uav_struct_env.study.detections.DetectionRow` per detection of every structural
    localization.
    """
    env = _env_for(config, scene)
    obs, infos = env.reset(seed=config.seed * 1000 + viewpoint, options={"viewpoint": viewpoint})
    site = env.site
    methods = [m for m in config.selected_methods if m.scene == scene]
    results: list[ImageResult] = []
    overlays: list[Overlay] = []
    detections: list[DetectionRow] = []
    estimates: dict[str, dict] = {}
    prior_sigmas = None
    for uav, agent in enumerate(env.possible_agents):
        info = infos[agent]
        image = obs[agent]["image"]
        K = info["intrinsics"]
        gt = invert(info["world_from_cam"])
        prior = invert(info["prior_world_from_cam"])
        for method in methods:
            truth = info["landmarks"][method.landmarks]
            # The localizer's model is the design (env.site); the truth is what stands
            # (env.built_site, which as built may expose other landmarks).
            model = site.landmarks(method.landmarks) if method.structural else None
            model_xyz = None if model is None else model.xyz
            model_ids = np.asarray(truth["ids"]) if model is None else model.ids
            stack = build_stack(
                stack_spec(config, method),
                K,
                config.image_size,
                model_xyz=model_xyz,
                model_ids=model_ids,
                markers=site.markers,
                rng=_rng(config, method, uav, viewpoint),
                distortion=info["distortion"],
                site=site,
            )
            frame = stack.localize(image, {method.landmarks: truth}, prior, gt)
            est = frame.estimate
            if method.structural:
                estimates.setdefault(method.key, {})[agent] = est
                prior_sigmas = stack.localizer.prior_sigmas
                counts = _structural_counts(frame)
                det = frame.detections
                detections += detection_rows(method.key, uav, viewpoint, det.uv, det.scores, det.true_ids,
                                             est.assignment, model_ids, truth)
                if viewpoint == overlay_viewpoint and uav == 0:
                    overlays.append(
                        _overlay(method, uav, viewpoint, image, K, prior, est, frame.detections,
                                 model_ids, model_xyz)
                    )
            else:
                counts = _marker_counts(frame, truth, site.markers)
            if method.structural:
                counts["pixel_error_rms_px"] = _pixel_error_rms(frame.detections, truth)
            results.append(_row(method, uav, viewpoint, frame, gt, prior, truth, K, **counts))
    tracking: list[ViewpointTracking] = []
    if config.track_workers and estimates:
        index = config.scenes.index(scene)
        tracking.append(track_viewpoint(
            env, infos, estimates, stage=scene.stage, viewpoint=viewpoint,
            rng=np.random.default_rng([config.seed, 0x7A4C, index, viewpoint]), prior_sigmas=prior_sigmas,
            pixel_sigma=config.worker_pixel_sigma, upright=config.upright_workers,
        ))
    return results, overlays, tracking, detections


def _row(method, uav, viewpoint, frame: FrameLocalization, gt, prior, truth, K, **counts) -> ImageResult:
    """One row of ``per_image.csv``: the frame's scores (the stack's), its bound and its centres."""
    est = frame.estimate
    visible = np.asarray(truth["visible"], dtype=bool)
    # The bound at 1 px (it scales linearly with the pixel noise): run_units rescales it to the
    # detector's own noise (bound_pixel_sigma). ArUco corners have another noise: no bound.
    if method.structural:
        crb = cramer_rao_bound(np.asarray(truth["xyz"])[visible].reshape(-1, 3), gt, K, 1.0)
        crb_t, crb_r = crb.position_rms_m, crb.rotation_rms_deg
    else:
        crb_t = crb_r = float("nan")
    c_gt, c_prior = camera_center(gt), camera_center(prior)
    c_est = camera_center(est.cam_from_world) if est.success else np.full(3, np.nan)
    return ImageResult(
        method=method.key,
        uav=uav,
        viewpoint=viewpoint,
        success=bool(est.success),
        failure_reason=est.failure_reason or "",
        failure_code=est.failure_code.value if est.failure_code is not None else "",
        translation_error_m=frame.translation_error_m,
        rotation_error_deg=frame.rotation_error_deg,
        prior_translation_error_m=frame.prior_translation_error_m,
        prior_rotation_error_deg=frame.prior_rotation_error_deg,
        n_visible=int(visible.sum()),
        n_inliers=int(est.n_inliers),
        reprojection_rmse_px=float(est.reprojection_rmse_px),
        crb_translation_m=crb_t,
        crb_rotation_deg=crb_r,
        gt_x=c_gt[0],
        gt_y=c_gt[1],
        gt_z=c_gt[2],
        prior_x=c_prior[0],
        prior_y=c_prior[1],
        prior_z=c_prior[2],
        est_x=c_est[0],
        est_y=c_est[1],
        est_z=c_est[2],
        **counts,
    )


def _pixel_error_rms(det, truth: dict) -> float:
    """RMS pixel distance of the true detections (``true_ids`` >= 0) from their true projections."""
    if det.true_ids is None:
        return float("nan")
    index = {int(i): k for k, i in enumerate(np.asarray(truth["ids"]).tolist())}
    true = np.asarray(det.true_ids) >= 0
    if not true.any():
        return float("nan")
    uv_true = np.asarray(truth["uv"], dtype=float)[[index[int(i)] for i in det.true_ids[true]]]
    return float(np.sqrt(np.mean(np.sum((det.uv[true] - uv_true) ** 2, axis=1))))


def bound_pixel_sigma(config: StudyConfig, method: Method, rows: Sequence[ImageResult]) -> float:
    """The per-axis pixel noise (px) of the method's detector, which its Cramér-Rao bound assumes.

    The projection detector's is the configured ``pixel_sigma``. A pixel-reading detector's
    (``learned``) is measured on the run's own images: the RMS over every true detection (matched
    to a visible landmark within the detector's match radius) of its distance from the true
    projection, divided by sqrt(2). ArUco rows have no bound: NaN.
    """
    if not method.structural:
        return float("nan")
    if config.detector == "projection":
        return float(config.pixel_sigma)
    n = np.array([r.n_true_detections for r in rows], dtype=float)
    rms = np.array([r.pixel_error_rms_px for r in rows], dtype=float)
    ok = np.isfinite(rms) & (n > 0)
    if not ok.any():
        return float("nan")
    return float(np.sqrt(np.sum(n[ok] * rms[ok] ** 2) / (2.0 * np.sum(n[ok]))))


def bound_source(config: StudyConfig, method: Method) -> str | None:
    """Where :func:`bound_pixel_sigma` comes from: ``"configured"``, ``"measured"`` or None (no bound)."""
    if not method.structural:
        return None
    return "configured" if config.detector == "projection" else "measured"


def _with_bounds(config: StudyConfig, rows: list[ImageResult]) -> list[ImageResult]:
    """Rows with their 1-px bounds rescaled to each method's :func:`bound_pixel_sigma`."""
    out = []
    for method in METHODS:
        mine = [r for r in rows if r.method == method.key]
        sigma = bound_pixel_sigma(config, method, mine)
        out += [
            replace(r, crb_translation_m=r.crb_translation_m * sigma,
                    crb_rotation_deg=r.crb_rotation_deg * sigma, crb_pixel_sigma_px=sigma)
            for r in mine
        ]
    return out


def _structural_counts(frame: FrameLocalization) -> dict:
    scores = frame.scores
    return {
        "n_detections": len(frame.detections),
        "n_true_detections": scores.true_detections,
        "n_assigned": scores.assigned,
        "n_correct": scores.correct,
        "latency_s": frame.latency_s,
    }


def _overlay(method, uav, viewpoint, image, K, prior, est, det, ids, model_xyz) -> Overlay:
    correct = (est.assignment >= 0) & (ids[np.maximum(est.assignment, 0)] == det.true_ids)
    uv_prior, _ = project(K, prior, model_xyz)
    uv_final, _ = project(K, est.cam_from_world, model_xyz)
    return Overlay(
        method.key,
        uav,
        viewpoint,
        image,
        det.uv,
        est.assignment,
        correct,
        uv_prior,
        uv_final,
        bool(est.success),
    )


def _marker_counts(frame: FrameLocalization, truth: dict, markers) -> dict:
    """The detection / association counts of a marker frame for :func:`_row`.

    "Association" of markers is decoding their ids: a marker counts as visible when all its
    corners are, and a detection is correct when its id is one of the visible markers.
    """
    found = frame.marker_ids
    visible = np.asarray(truth["visible"], dtype=bool).reshape(-1, 4).all(axis=1)
    visible_ids = {int(m.id) for m, v in zip(markers, visible, strict=True) if v}
    correct = sum(1 for i in found.tolist() if i in visible_ids)
    return {
        "n_detections": len(found),
        "n_true_detections": len(visible_ids),
        "n_assigned": len(found),
        "n_correct": correct,
        "latency_s": frame.latency_s,
    }


# ------------------------------------------------------------------------------- scheduling
def _units(config: StudyConfig) -> list[tuple[Scene, int]]:
    return [(scene, k) for scene in config.scenes for k in range(config.n_viewpoints)]


_KERNELS_READY = False


def warm_kernels(announce: Callable[[str], None] | None = None) -> None:
    """Compile or load the localization kernels once per process, before any frame is timed.

    ``latency_s`` then measures localization, never numba's compilation or its cache loading;
    ``announce`` gets one line when the kernels are compiled for the first time
    (:func:`localization.warmup.warm_up`).
    """
    global _KERNELS_READY
    if not _KERNELS_READY:
        warm_up(announce=announce)
        _KERNELS_READY = True


def _worker(args):
    config, scene, k = args
    warm_kernels()
    return run_unit_tracked(config, scene, k)


class StudyInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped the study after ``done`` of ``total`` viewpoints (every worker stopped)."""

    def __init__(self, done: int, total: int) -> None:
        super().__init__(f"stopped after {done} of {total} viewpoints")
        self.done, self.total = done, total


def iter_study(
    config: StudyConfig,
) -> Iterator[tuple[list[ImageResult], list[Overlay], list[ViewpointTracking], list[DetectionRow]]]:
    """Yield the results of every (scene, viewpoint) unit as it completes (:func:`run_unit_tracked`).

    With ``workers > 1`` the units run in spawned processes (:func:`uav_struct_env.processes.
    run_chunks`): Ctrl-C stops and reaps them all, and a worker that dies raises
    :class:`uav_struct_env.processes.WorkerDied` instead of hanging.
    """
    units = _units(config)
    if config.workers == 1:
        warm_kernels()
        try:
            for scene, k in units:
                yield run_unit_tracked(config, scene, k)
        finally:
            _close_envs()
        return
    # Units are ordered by scene; contiguous chunks keep each process on one scene most of the
    # time, so a site is rarely loaded twice in one process.
    chunk = max(1, -(-config.n_viewpoints // config.workers))
    work = [(config, s, k) for s, k in units]
    chunks = [work[i:i + chunk] for i in range(0, len(work), chunk)]
    yield from run_chunks(_worker, chunks, config.workers, name="study-worker")


def run_units(
    config: StudyConfig, progress: Callable[[int, int], None] | None = None
) -> tuple[list[ImageResult], list[Overlay]]:
    """Run the whole study; ``progress(done, total)`` is called after each unit."""
    results, overlays, _, _ = run_units_tracked(config, progress)
    return results, overlays


def run_units_tracked(
    config: StudyConfig, progress: Callable[[int, int], None] | None = None
) -> tuple[list[ImageResult], list[Overlay], list[ViewpointTracking], list[DetectionRow]]:
    """:func:`run_units`, the viewpoints' worker tracking and the structural detections' records.

    The tracking is empty unless workers are tracked.
    """
    total = len(_units(config))
    results: list[ImageResult] = []
    overlays: list[Overlay] = []
    tracking: list[ViewpointTracking] = []
    detections: list[DetectionRow] = []
    done = 0
    try:
        for res, ovs, trk, dets in iter_study(config):
            results += res
            overlays += ovs
            tracking += trk
            detections += dets
            done += 1
            if progress is not None:
                progress(done, total)
    except KeyboardInterrupt:
        raise StudyInterrupted(done, total) from None
    order = {m.key: i for i, m in enumerate(METHODS)}
    # Sorted before the bounds: their measured noise sums over the rows, and the workers' rows
    # arrive in whatever order they finish (the sum's last digit followed it).
    results.sort(key=lambda r: (order[r.method], r.uav, r.viewpoint))
    results = _with_bounds(config, results)
    tracking.sort(key=lambda t: (t.stage, t.viewpoint))
    detections.sort(key=lambda d: (order[d.method], d.uav, d.viewpoint, d.detection))
    return results, overlays, tracking, detections
