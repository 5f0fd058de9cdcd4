"""The study command: run the protocol, write results, tables, CSV and figures, print Table II."""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from localization.detect.weights import WEIGHT_NAMES, WeightSet, adapted_weights
from localization.geometry.camera import PAPER_IMAGE_SIZE
from uav_struct_env.envs.config import LIGHTINGS
from uav_struct_env.outputs import OutputExistsError, StagedOutput
from uav_struct_env.processes import WorkerDied
from uav_struct_env.sim.imaging import imaging_argument
from uav_struct_env.sim.lens import CAMERA_MODELS
from uav_struct_env.site import make_site
from uav_struct_env.site.activity import ACTIVITY_PRESETS
from uav_struct_env.site.as_built import TOLERANCE_MODELS
from uav_struct_env.study.cells import json_ready
from uav_struct_env.study.detections import write_detections_csv
from uav_struct_env.study.figures import (
    plot_error_cdfs,
    plot_fig2,
    plot_viewpoint_map,
    plot_worker_tracking,
)
from uav_struct_env.study.protocol import ASSOCIATIONS, DETECTORS, METHODS, NOISES, StudyConfig
from uav_struct_env.study.report import (
    results_dict,
    settings_line,
    table1_markdown,
    table2_markdown,
    write_csv,
    write_results_json,
)
from uav_struct_env.study.run import StudyInterrupted, run_units_tracked, warm_kernels
from uav_struct_env.study.tracking import tracking_markdown, tracking_summary
from uav_struct_env.tracking_sim import DEFAULT_WORKER_SIGMA_PX
from uav_struct_env.validate import (
    INPUT_ERRORS,
    CommandParser,
    check_output_dir,
    check_site,
    image_size_argument,
    refuse,
)

__all__ = ["main", "run_study"]

QUICK_VIEWPOINTS = 2


#: What the study writes; ``results.json`` (written last) says that a set is complete.
STUDY_FILES = ("results.json", "table1.md", "table2.md", "per_image.csv", "detections.csv",
               "fig2_associations.png",
               "error_cdf.png", "viewpoint_map.png", "worker_tracking.md", "worker_tracking_cdf.png")


def run_study(
    config: StudyConfig,
    out: str | Path,
    *,
    progress: bool = True,
    figures: bool = True,
    overwrite: bool = False,
) -> dict:
    """Run the study into ``out`` and return the ``results.json`` document.

    Writes ``results.json``, ``table1.md``, ``table2.md``, ``per_image.csv``, ``detections.csv``
    (one row per detection of the structural methods: :mod:`uav_struct_env.study.detections`), with
    ``config.track_workers`` ``worker_tracking.md`` (and ``worker_tracking`` in the JSON), and
    (with ``figures``) ``fig2_associations.png``, ``error_cdf.png`` and ``viewpoint_map.png`` (and
    ``worker_tracking_cdf.png`` when tracking workers), all at once when the study has finished
    (:class:`uav_struct_env.outputs.StagedOutput`): an interrupted run leaves ``out`` as it was.

    Raises:
        uav_struct_env.outputs.OutputExistsError: ``out`` already holds files and ``overwrite``
            is false (checked before anything runs). With ``overwrite``, the files of an
            earlier study there are replaced and those this run does not write are removed.
    """
    staged = StagedOutput(out, overwrite=overwrite, owned=STUDY_FILES)
    with staged:
        # Compiled before the bar starts (one line when it is the first time), never in a latency.
        warm_kernels(announce=lambda line: print(line, file=sys.stderr, flush=True))
        t0 = time.perf_counter()
        bar = tqdm(
            total=len(config.scenes) * config.n_viewpoints,
            unit="viewpoint",
            desc="study",
            disable=not progress,
            file=sys.stderr,
        )

        def tick(done: int, total: int) -> None:
            bar.update(done - bar.n)

        try:
            rows, overlays, tracking, detections = run_units_tracked(config, progress=tick)
        finally:
            bar.close()
        elapsed = time.perf_counter() - t0
        results = results_dict(config, rows, {"elapsed_s": round(elapsed, 1)})
        stage = staged.stage
        if config.track_workers:
            summary = tracking_summary(tracking, config.worker_pixel_sigma, config.activity,
                                       config.upright_workers)
            results["worker_tracking"] = json_ready(summary)
            (stage / "worker_tracking.md").write_text(tracking_markdown(results, settings_line(results)))
        write_results_json(stage / "results.json", results)
        (stage / "table1.md").write_text(table1_markdown(results))
        (stage / "table2.md").write_text(table2_markdown(results))
        made = f"Settings: {settings_line(results)}"
        write_csv(stage / "per_image.csv", rows, comment=made)
        write_detections_csv(stage / "detections.csv", detections, comment=made)
        if figures:
            settings = settings_line(results)
            plot_fig2(overlays, stage / "fig2_associations.png", settings)
            plot_error_cdfs(rows, stage / "error_cdf.png", settings)
            if config.track_workers:
                plot_worker_tracking(tracking, stage / "worker_tracking_cdf.png", settings)
            structural = [m for m in config.selected_methods if m.structural]
            if structural:
                site = make_site(config.site, stage=config.scene_stage(structural[0].scene),
                                 marker_size=1.0, rng=np.random.default_rng(config.seed))
                plot_viewpoint_map(site, rows, structural[0].key, stage / "viewpoint_map.png", settings)
    return results


def _parser() -> CommandParser:
    p = CommandParser(
        prog="uav-struct study",
        description="Reproduce the paper's four-UAV study (Tables I and II, Fig. 2).",
    )
    p.add_argument("--out", default="results", help="output folder (default: results)")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the results of an earlier run in --out (otherwise such a folder is refused)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of textures, detector noise and priors")
    p.add_argument(
        "--detector",
        default=None,
        help=f"landmark detector: {', '.join(DETECTORS)}, learned:NAME or guided:NAME (NAME a weight set: "
        f"{', '.join(WEIGHT_NAMES)}; "
        "default: guided for an IFC --site, learned otherwise; learned: the method from the rendered "
        "pixels with the default weights, or with those "
        "`uav-struct adapt` made for an IFC --site when they exist; guided: the learned detector, a "
        "first pose, then the building model rendered at that pose and matched around each "
        "landmark; projection: ground truth + noise, an ablation isolating association and pose)",
    )
    p.add_argument("--association", default="robust", choices=ASSOCIATIONS)
    p.add_argument("--noise", default="paper", choices=NOISES, help="onboard prior model")
    p.add_argument(
        "--quick",
        action="store_true",
        help=f"{QUICK_VIEWPOINTS} viewpoints per UAV instead of 10 (for tests)",
    )
    p.add_argument(
        "--methods",
        default=None,
        help="comma-separated rows to evaluate, of: " + ", ".join(m.key for m in METHODS)
        + " (default: every row; the slab-stage rows share one scene per viewpoint, column tops and "
        "'all' another, so one row of each costs about what the whole stage does)",
    )
    p.add_argument(
        "--site",
        default="paper",
        help="site: paper, random (drawn from --seed), a site file (*.json) or an IFC file (*.ifc)",
    )
    p.add_argument(
        "--stage",
        default=None,
        help="the floor to evaluate, by one of its stage names (e.g. 'Level 2/slab'; list them with "
        "python -c \"from uav_struct_env.site import ifc_stages; print(ifc_stages('b.ifc'))\"); "
        "default: the paper's first floor, or an IFC file's last floor",
    )
    p.add_argument(
        "--as-built",
        default=None,
        choices=sorted(TOLERANCE_MODELS),
        help="render the building as built: every element moved within this tolerance model "
        "(aci117: columns 25 mm lateral, slab tops 19 mm, opening edges 13 mm) while the "
        "localizer keeps the design (default: the building stands as designed)",
    )
    p.add_argument(
        "--as-built-scale",
        type=float,
        default=1.0,
        help="factor on every --as-built tolerance (default 1; 0 is the design)",
    )
    p.add_argument("--workers", type=int, default=1, help="parallel processes (default 1)")
    p.add_argument(
        "--image-size",
        type=image_size_argument,
        default=PAPER_IMAGE_SIZE,
        metavar="WxH",
        help="the rendered images' size, the paper's camera scaled to it (default: the paper's 1280x720, "
        "at which the learned detectors were trained; smaller for quick smoke runs)",
    )
    p.add_argument("--pixel-sigma", type=float, default=1.0, help="projection detector noise, px")
    p.add_argument("--miss-rate", type=float, default=0.0, help="projection detector miss rate")
    p.add_argument("--false-positives", type=float, default=0.0, help="mean false detections per image")
    p.add_argument("--renderer", default="auto", choices=("auto", "tiny", "egl"))
    p.add_argument(
        "--imaging",
        default="ideal",
        type=imaging_argument,
        choices=("ideal", "camera"),
        help="camera effects on the rendered images: ideal (none) or camera (blur, noise, JPEG)",
    )
    p.add_argument(
        "--camera",
        default="paper",
        choices=tuple(CAMERA_MODELS),
        help="the camera: paper (ideal pinhole) or mavic2pro (lens distortion, rolling shutter, "
        "motion blur; the localizers undistort with its coefficients)",
    )
    p.add_argument(
        "--lighting",
        default="fixed",
        choices=LIGHTINGS,
        help="the sun: fixed, or random (direction and intensity drawn per viewpoint from --seed)",
    )
    p.add_argument(
        "--activity",
        default="none",
        choices=tuple(ACTIVITY_PRESETS),
        help="site activity: none (a bare site), light or busy (workers, equipment, materials, "
        "scaffolding, laid out per viewpoint from --seed; they hide landmarks)",
    )
    p.add_argument(
        "--detector-model",
        default=None,
        metavar="ONNX",
        help="with --detector learned[:NAME]: keypoint-network weights (default: those of NAME)",
    )
    p.add_argument(
        "--refiner-model",
        default=None,
        metavar="ONNX",
        help="with --detector learned[:NAME]: patch-refiner weights (default: those of NAME)",
    )
    p.add_argument(
        "--track-workers",
        action="store_true",
        help="also track the site's workers (with --activity, light if none) from the four cameras at true, "
        "estimated and prior poses: results.json gains worker_tracking, worker_tracking.md",
    )
    p.add_argument(
        "--worker-pixel-sigma",
        type=float,
        default=DEFAULT_WORKER_SIGMA_PX,
        help="with --track-workers: the worker detector's feet / head-top noise, px (default "
        f"{DEFAULT_WORKER_SIGMA_PX:g})",
    )
    p.add_argument(
        "--upright-workers",
        action="store_true",
        help="with --track-workers: triangulate workers standing (head top above the feet)",
    )
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def study_config(args, **overrides) -> StudyConfig:
    """The :class:`StudyConfig` of parsed ``uav-struct study`` options; ``overrides`` replace fields.

    ``uav-struct sweep`` takes the same options and builds its runs' settings here too.
    """
    # The command's default is the full method from pixels (StudyConfig keeps "projection").
    fields = dict(
        seed=args.seed,
        detector=args.detector,
        association=args.association,
        noise=args.noise,
        site=args.site,
        n_viewpoints=QUICK_VIEWPOINTS if args.quick else 10,
        pixel_sigma=args.pixel_sigma,
        miss_rate=args.miss_rate,
        false_positives=args.false_positives,
        renderer=args.renderer,
        imaging=args.imaging,
        detector_model=args.detector_model,
        refiner_model=args.refiner_model,
        workers=args.workers,
        image_size=args.image_size,
        stage=args.stage,
        as_built=args.as_built,
        as_built_scale=args.as_built_scale,
        lighting=args.lighting,
        camera=args.camera,
        activity=args.activity,
        track_workers=args.track_workers,
        worker_pixel_sigma=args.worker_pixel_sigma,
        upright_workers=args.upright_workers,
    )
    if args.methods is not None:
        fields["methods"] = tuple(k.strip() for k in args.methods.split(","))
    fields.update(overrides)
    if fields["detector"] is None:
        fields["detector"] = default_detector(fields["site"])
    adapted = adapted_for(*(fields[k] for k in ("site", "detector", "detector_model", "refiner_model")))
    if adapted is not None:
        fields.update(detector_model=str(adapted.model), refiner_model=str(adapted.refiner))
    return StudyConfig(**fields)


def default_detector(site: str) -> str:
    """The detector a study runs unless told: ``guided`` on an IFC building, else ``learned``.

    On an IFC building the guided detector beat the learned one on the train buildings
    (docs/study.md, "The BIM-guided detector"); it needs the building model, which the IFC is.
    """
    return "guided" if isinstance(site, str) and site.lower().endswith(".ifc") else "learned"


def adapted_for(site: str, detector: str, detector_model: str | None,
                refiner_model: str | None) -> WeightSet | None:
    """The weights ``uav-struct adapt`` made for ``site``, if the default learned networks run there.

    None unless ``detector`` is ``"learned"`` or ``"guided"`` (not ``learned:NAME``) with no weight
    files given and ``site`` is an IFC file with an adapted set
    (:func:`localization.detect.weights.adapted_weights`).
    """
    if detector not in ("learned", "guided") or detector_model is not None or refiner_model is not None:
        return None
    if not (isinstance(site, str) and site.lower().endswith(".ifc") and Path(site).is_file()):
        return None
    return adapted_weights(site)


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args = _parser().parse_args(argv)
    try:
        config = study_config(args)
        check_site(args.site, args.stage, seed=args.seed)
        check_output_dir(args.out, overwrite=args.overwrite)
    except INPUT_ERRORS as err:
        return refuse("uav-struct study", err)
    if args.detector is None and config.detector == "guided":
        print("uav-struct study: note: an IFC building: detecting with the BIM-guided detector (--detector "
              "guided, the default here); --detector learned runs the learned detector alone",
              file=sys.stderr)
    adapted = adapted_for(args.site, config.detector, args.detector_model, args.refiner_model)
    if adapted is not None:
        print(f"uav-struct study: note: running the detector weights adapted to this building by uav-struct "
              f"adapt ({adapted.model.parent}); --detector learned:landmarks_v1 runs the default ones",
              file=sys.stderr)
    for key, why in config.skip_reasons.items():
        print(f"uav-struct study: note: {key} left out: {why}", file=sys.stderr)
    if not config.selected_methods:
        return refuse("uav-struct study", "nothing to evaluate: every requested method is left out "
                      "(above); choose another --stage or --site")
    try:
        results = run_study(config, args.out, progress=not args.no_progress,
                            figures=not args.no_figures, overwrite=args.overwrite)
    except (OutputExistsError, NotADirectoryError) as err:
        return refuse("uav-struct study", err)
    except OSError as err:  # e.g. the disk filled up while the results were written
        return refuse("uav-struct study", f"{err}; nothing written to {args.out}", status=1)
    except StudyInterrupted as stop:
        print(f"uav-struct study: interrupted: {stop}; nothing written to {args.out}",
              file=sys.stderr)
        return 130
    except WorkerDied as err:
        print(f"uav-struct study: error: {err}; nothing written to {args.out}", file=sys.stderr)
        return 1
    out = Path(args.out)
    print("\nTable II — camera-pose accuracy:\n")
    print((out / "table2.md").read_text())
    print("Table I — detection and association (same settings):\n")
    print((out / "table1.md").read_text().split("\n\n", 1)[1])  # its settings line printed above
    if config.track_workers:
        print("Worker tracking — 3D worker error by camera poses:\n")
        print((out / "worker_tracking.md").read_text().split("\n\n", 1)[1])
    written = "results.json, table1.md, table2.md, per_image.csv, detections.csv"
    written += "" if args.no_figures else ", figures"
    print(f"Wrote {out.resolve()}/ ({written}) in {results['config']['elapsed_s']} s")
    return 0
