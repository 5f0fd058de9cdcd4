"""``uav-struct adapt b.ifc``: fine-tune the learned detector on renders of one building.

The building model is known before the flight, so the detector can be prepared for it. The
command renders the building (:mod:`uav_struct_env.datasets.landmarks` with ``site=b.ifc``:
every layout the floor the study evaluates, :func:`floor_stages`, or with ``--all-stages`` one of
every stage drawn at random; activity, camera and imaging all ``mixed``), then
fine-tunes the default weights (:data:`localization.detect.weights.DEFAULT_WEIGHTS`) on them:

1. the keypoint network, from its committed ONNX file, on ``layouts x views`` half-resolution
   renders (dataset seed ``seed``, :func:`uav_struct_env.training.train_detector.train`);
2. the patch refiner, from its committed ONNX file, on windows mined by the *adapted* keypoint
   network from ``refiner_layouts x views`` other full-resolution renders (dataset seed
   ``seed + 1``, :func:`uav_struct_env.training.train_refiner.train`).

The dataset's viewpoints are drawn at random around the building (any azimuth, 10-40 m out,
8-30 m up) from their own seeds; the study's are its four UAVs' scheduled viewpoints, so none of
the study's images is trained on. Both trainings run a fixed number of steps with one seed, so
the weights do not depend on the machine's load (the wall time does). Checkpoints are not chosen
on any validation set: the last weights are kept.

The set is written to ``ROOT/<sha256 of b.ifc>/`` (ROOT: ``--out``, else
:func:`localization.detect.weights.adapted_root`): the two ONNX files
(:func:`localization.detect.weights.adapted_set` names them) and ``provenance.json`` (settings,
software version and commit, the file's SHA-256, steps, minutes per phase), moved there together
when all is done; Ctrl-C or SIGTERM leaves the folder as it was. ``uav-struct study --site b.ifc``
with the default learned detector then runs the adapted set.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from localization.detect.weights import (
    ADAPTED_DIR_ENV,
    ADAPTED_PROVENANCE,
    DEFAULT_WEIGHTS,
    adapted_root,
    adapted_set,
    adapted_weights,
    file_sha256,
    weight_set,
)
from uav_struct_env.errors import ConfigError
from uav_struct_env.training.finetune import (
    Laps,
    add_setting_options,
    check_settings,
    dataset_config,
    finetune,
    render_dataset,
)

__all__ = ["AdaptConfig", "adapt", "main"]


@dataclass(frozen=True)
class AdaptConfig:
    """Settings of one adaptation (chosen on the corpus's training buildings; docs/adapt.md).

    Attributes:
        layouts: layouts of the keypoint network's dataset (each a stage drawn at random).
        refiner_layouts: layouts of the refiner's dataset.
        views: viewpoints per layout.
        keypoint_steps: fine-tuning steps of the keypoint network (batch 16, 256 x 192 crops).
        refiner_steps: fine-tuning steps of the refiner (batch
            :data:`~uav_struct_env.training.finetune.REFINER_BATCH`).
        keypoint_lr: peak learning rate of the keypoint network (warm-up, then cosine).
        refiner_lr: peak learning rate of the refiner.
        seed: dataset seed of the keypoint network's renders (the refiner's: ``seed + 1``) and
            training seed of both networks.
        threads: torch threads.
        render_workers: rendering processes.
    """

    layouts: int = 24
    refiner_layouts: int = 12
    views: int = 10
    keypoint_steps: int = 300
    refiner_steps: int = 300
    keypoint_lr: float = 1e-3
    refiner_lr: float = 5e-4
    seed: int = 4400
    threads: int = 2
    render_workers: int = 2

    def __post_init__(self) -> None:
        check_settings(self)


def floor_stages(ifc: str | Path, stage: str | None = None) -> tuple[str, ...]:
    """The stages of the floor ``uav-struct study --site ifc [--stage stage]`` evaluates.

    Its slab stage and its columns stage (those it has), as the study resolves them
    (:meth:`uav_struct_env.site.Site.floor_stage`); None: the study's default floor.
    """
    from uav_struct_env.site import make_site

    site = make_site(str(ifc), stage=stage, marker_size=None)
    return tuple(s for s in (site.floor_stage("slab"), site.floor_stage("columns")) if s is not None)


def _render(ifc: Path, out: Path, layouts: int, seed: int, scale: float, config: AdaptConfig,
            progress: bool, stages: tuple[str, ...] | None = None) -> Path:
    """Render one labelled dataset of the building (activity, camera and imaging mixed)."""
    return render_dataset(dataset_config(ifc, layouts, config.views, seed, scale, stages), out,
                          config.render_workers, progress)


def _train_networks(ifc: Path, work: Path, final: dict, config: AdaptConfig, progress: bool,
                    stages: tuple[str, ...] | None = None) -> dict:
    """Render both datasets and fine-tune both networks; returns the phases' costs and counts."""
    laps = Laps()
    keypoint_data = _render(ifc, work / "keypoint_data", config.layouts, config.seed, 0.5, config, progress,
                            stages)
    refiner_data = _render(ifc, work / "refiner_data", config.refiner_layouts, config.seed + 1, 1.0, config,
                           progress, stages)
    laps("render")
    counts = finetune(config, weight_set(DEFAULT_WEIGHTS), [keypoint_data], [refiner_data], final, work,
                      progress, laps)
    return {"minutes": {**laps.minutes, "total": round(sum(laps.minutes.values()), 2)}, **counts}


def adapt(ifc: str | Path, root: str | Path | None = None, config: AdaptConfig | None = None,
          progress: bool = True, overwrite: bool = False, stages: tuple[str, ...] | None = None) -> Path:
    """Adapt the default weights to the building file ``ifc``; returns the set's folder.

    Args:
        ifc: the building's IFC file.
        root: the folder of adapted sets (None: :func:`~localization.detect.weights.adapted_root`);
            the set goes to ``root/<sha256 of ifc>/``.
        config: the settings (None: :class:`AdaptConfig`'s defaults).
        progress: show progress bars.
        overwrite: replace a set adapted before (otherwise such a folder is refused).
        stages: the building's stages the renders draw from (:func:`floor_stages` gives a floor's);
            None: every stage.

    Raises:
        uav_struct_env.outputs.OutputExistsError: the building has an adapted set and not ``overwrite``.
    """
    import torch

    from uav_struct_env.outputs import StagedOutput, atomic_write_json
    from uav_struct_env.provenance import software

    config = config or AdaptConfig()
    ifc = Path(ifc).resolve()
    sha = file_sha256(ifc)
    target = adapted_set(sha, root)
    t0 = time.perf_counter()
    with StagedOutput(target.model.parent, overwrite=overwrite,
                      owned=(ADAPTED_PROVENANCE, "adapted_*.onnx")) as staged, \
            tempfile.TemporaryDirectory(prefix="uav-struct-adapt-") as work:
        final = {"model": staged.stage / target.model.name, "refiner": staged.stage / target.refiner.name}
        costs = _train_networks(ifc, Path(work), final, config, progress, stages)
        record = {
            "building": {"file": str(ifc), "name": ifc.name, "sha256": sha},
            "weights": {"name": target.name, "model": target.model.name, "refiner": target.refiner.name,
                        "base": DEFAULT_WEIGHTS,
                        "base_sha256": {k: file_sha256(getattr(weight_set(DEFAULT_WEIGHTS), k))
                                        for k in ("model", "refiner")}},
            "settings": asdict(config),
            "stages": None if stages is None else list(stages),
            "software": {**software(), "torch": torch.__version__},
            **costs,
            "wall_minutes": round((time.perf_counter() - t0) / 60.0, 2),
        }
        atomic_write_json(staged.stage / ADAPTED_PROVENANCE, record, indent=2)
    return target.model.parent


def _parser() -> argparse.ArgumentParser:
    from uav_struct_env.validate import CommandParser

    p = CommandParser(prog="uav-struct adapt",
                      description="Fine-tune the learned detector on renders of one building (IFC), "
                      "for `uav-struct study --site` on that file.")
    p.add_argument("ifc", help="the building's IFC file")
    p.add_argument("--out", default=None,
                   help=f"folder of adapted sets (default {adapted_root()}, or $UAV_STRUCT_ADAPTED_DIR); "
                   "the set goes to OUT/<sha256 of the file>/")
    p.add_argument("--overwrite", action="store_true", help="replace the building's adapted set")
    p.add_argument("--stage", default=None,
                   help="the floor the renders show, by any of its stage names, as uav-struct study --stage "
                   "takes it (default: the floor the study evaluates by default)")
    p.add_argument("--all-stages", action="store_true",
                   help="render every stage of the building, one drawn per layout (the default before "
                   "2026-11-28)")
    add_setting_options(p, AdaptConfig)
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    return p


def main(argv: list[str] | None = None) -> int:
    """``uav-struct adapt``; returns the exit status."""
    from uav_struct_env.outputs import OutputExistsError
    from uav_struct_env.processes import WorkerDied, interrupted_status, stop_on_sigterm
    from uav_struct_env.validate import INPUT_ERRORS, check_input_file, check_site, refuse

    prog = "uav-struct adapt"
    args = _parser().parse_args(argv)
    stop_on_sigterm()
    try:
        check_input_file(args.ifc, option="ifc", what="IFC file")
        check_site(args.ifc)
        config = AdaptConfig(**{f.name: getattr(args, f.name) for f in fields(AdaptConfig)})
        if args.all_stages and args.stage is not None:
            raise ConfigError(f"--stage {args.stage!r} and --all-stages: choose one")
        stages = None if args.all_stages else floor_stages(args.ifc, args.stage)
        import torch  # noqa: F401  (the train extra)
    except ImportError as err:
        return refuse(prog, f"{err}; adapt trains with torch: pip install 'uav-struct-env[train]'")
    except INPUT_ERRORS as err:
        return refuse(prog, err)
    try:
        folder = adapt(args.ifc, args.out, config, progress=not args.no_progress, overwrite=args.overwrite,
                       stages=stages)
    except (OutputExistsError, NotADirectoryError) as err:
        return refuse(prog, err)
    except WorkerDied as err:
        return refuse(prog, f"{err}; no adapted set written", status=1)
    except OSError as err:
        return refuse(prog, f"{err}; no adapted set written", status=1)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; no adapted set written", file=sys.stderr)
        return interrupted_status()
    found = adapted_weights(args.ifc)
    here = found is not None and found.model.parent == folder
    hint = (f"uav-struct study --site {args.ifc} now runs these weights" if here
            else f"for uav-struct study to run them: export {ADAPTED_DIR_ENV}={Path(args.out).resolve()}")
    print(f"wrote {folder} ({hint})")
    return 0
