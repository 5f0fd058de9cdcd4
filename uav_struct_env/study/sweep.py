"""Sweeps: the study over many sites and seeds, on a local process pool or on Ray, in one table.

``uav-struct sweep --sites random:0-99 --seeds 0-2 --detector projection --quick`` runs the
study (:func:`uav_struct_env.study.run.run_units`, one process per run) for every (site, seed)
pair and merges the per-image rows of all runs into one ``results.json`` (each method pooled
over every run, plus each run's own summary), ``table.md`` and ``per_image.csv`` (with ``site``
and ``seed`` columns). Each says how it was made: ``table.md`` opens with the settings line
(:func:`sweep_settings_line`: the study's, over every site and seed), ``per_image.csv`` with it as
a ``# Settings: ...`` comment, and ``results.json`` has it as ``"settings"``.

Sites: ``paper``, ``random:N`` (the random site drawn from seed N, the one
``uav-struct study --site random --seed N`` renders), ``random:A-B`` (A to B inclusive), a site
file (``*.json``) or an IFC file (``*.ifc``), comma-separated. Seeds: ``0-2`` or ``0,3,7``.

Where it runs: ``workers`` spawned processes (:func:`uav_struct_env.processes.run_chunks`), or,
with ``ray``, Ray tasks of one CPU each, on a local Ray instance (``"local"``) or a running
cluster (its address, e.g. ``"auto"`` or ``"ray://head:10001"``; every node needs this package
and any site file at the same path). Each run is seeded by its (site, seed) alone, so both give
identical results; only the wall-clock columns (``latency_s``, ``elapsed_s``) differ.
"""

from __future__ import annotations

import dataclasses
import os
import re
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from localization.metrics import median_p90
from uav_struct_env.errors import ConfigError
from uav_struct_env.outputs import OutputExistsError, StagedOutput, atomic_write_text
from uav_struct_env.processes import run_chunks
from uav_struct_env.provenance import software
from uav_struct_env.study.cells import cell, json_ready, write_records_csv
from uav_struct_env.study.protocol import METHODS, StudyConfig
from uav_struct_env.study.report import settings_line, summarize, write_results_json
from uav_struct_env.study.run import ImageResult, bound_source, run_units
from uav_struct_env.validate import CommandParser

__all__ = [
    "SWEEP_FILES",
    "SweepRun",
    "comparable",
    "main",
    "parse_seeds",
    "parse_sites",
    "require_ray",
    "run_sweep",
    "sweep",
    "sweep_results",
    "sweep_settings_line",
    "table_markdown",
    "write_rows_csv",
]

#: What a sweep writes; ``results.json`` (written last) says that a set is complete.
SWEEP_FILES = ("results.json", "table.md", "per_image.csv")

#: The summary of each run kept in ``results.json["runs"]`` (the pooled entry has them all).
_RUN_KEYS = ("successful", "total", "translation_error_m", "rotation_error_deg")

_RANDOM = re.compile(r"random:(\d+)(?:-(\d+))?$")


def _range(text: str, what: str) -> list[int]:
    m = re.fullmatch(r"(\d+)(?:-(\d+))?", text.strip())
    if m is None:
        raise ConfigError(f"{what} must be N or A-B with integers A <= B, got {text!r}")
    lo = int(m.group(1))
    hi = lo if m.group(2) is None else int(m.group(2))
    if hi < lo:
        raise ConfigError(f"{what} range {text!r} is empty: {hi} < {lo}")
    return list(range(lo, hi + 1))


def parse_sites(text: str) -> tuple[str, ...]:
    """``"paper,random:0-2,b.ifc"`` -> ``("paper", "random:0", "random:1", "random:2", "b.ifc")``.

    Raises:
        ConfigError: an empty list, a malformed ``random:`` range, a repeated site, or an item
            that is neither ``paper``, ``random:N[-M]`` nor an existing ``*.json`` / ``*.ifc`` file.
    """
    out: list[str] = []
    for item in (s.strip() for s in str(text).split(",")):
        if item.startswith("random:"):
            out += [f"random:{n}" for n in _range(item[len("random:"):], "a random site")]
        elif item == "paper" or (item.lower().endswith((".json", ".ifc")) and Path(item).is_file()):
            out.append(item)
        else:
            raise ConfigError(
                "each site must be paper, random:N, random:A-B or an existing site file (*.json) "
                f"or IFC file (*.ifc), got {item!r}"
            )
    repeated = sorted({s for s in out if out.count(s) > 1})
    if repeated:
        raise ConfigError(f"sites must be distinct, got {repeated} more than once")
    return tuple(out)


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0-2"`` -> ``(0, 1, 2)``; ``"0,5,7-8"`` -> ``(0, 5, 7, 8)`` (distinct, in order given)."""
    seeds: list[int] = []
    for item in str(text).split(","):
        seeds += _range(item, "a seed")
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"seeds must be distinct, got {text!r}")
    return tuple(seeds)


@dataclasses.dataclass(frozen=True)
class SweepRun:
    """One study run of a sweep: its site (as given), its seed and its per-image rows."""

    site: str
    seed: int
    rows: tuple[ImageResult, ...]


#: This process's site files of ``random:N`` sites (in a temp folder removed at exit).
_SITE_FILES: dict[str, str] = {}


def _site_file(site: str) -> str:
    """The ``StudyConfig.site`` of a sweep site: a random site is written to a site file first.

    ``random:N`` is :func:`~uav_struct_env.site.random_site` drawn from ``default_rng(N)``, saved
    once per process into a temp folder (removed when the process exits), so that a run's own
    seed is free to vary and every Ray node makes its own copy from the code it runs.
    """
    m = _RANDOM.match(site)
    if m is None:
        return site
    if site not in _SITE_FILES:
        import atexit
        import shutil

        from uav_struct_env.site import random_site
        from uav_struct_env.site.io import save_site

        if not _SITE_FILES:
            folder = tempfile.mkdtemp(prefix="uav-struct-sweep-")
            atexit.register(shutil.rmtree, folder, ignore_errors=True)
            _SITE_FILES[""] = folder
        path = Path(_SITE_FILES[""]) / f"random_{int(m.group(1))}.json"
        save_site(random_site(np.random.default_rng(int(m.group(1)))), path)
        _SITE_FILES[site] = str(path)
    return _SITE_FILES[site]


def require_ray():
    """The ``ray`` module, or a ConfigError that says how to install it."""
    try:
        import ray
    except ImportError as err:
        raise ConfigError(
            "--ray needs Ray: pip install 'uav-struct-env[ray]' (or run without --ray on a process pool)"
        ) from err
    return ray


def _run(task: tuple[StudyConfig, str, int]) -> SweepRun:
    """One (site, seed) run of the study, in this process (``workers=1``)."""
    base, site, seed = task
    config = dataclasses.replace(base, site=_site_file(site), seed=seed, workers=1)
    rows, _ = run_units(config)  # the overlays (Fig. 2 images) are not kept
    return SweepRun(site, seed, tuple(rows))


def _pool(tasks: list, workers: int) -> Iterator[SweepRun]:
    """Run ``tasks`` in ``workers`` spawned processes, one task per chunk."""
    yield from run_chunks(_run, [[t] for t in tasks], workers, name="sweep-worker")


def _ray(tasks: list, address: str, workers: int) -> Iterator[SweepRun]:
    """Run ``tasks`` as Ray tasks of one CPU each; ``address`` ``"local"`` starts a local instance."""
    ray = require_ray()
    started = not ray.is_initialized()
    if started:
        local = address == "local"
        ray.init(
            address=None if local else address,
            num_cpus=workers if local else None,
            include_dashboard=False,
            log_to_driver=False,
            # local workers import this package from wherever the driver does
            runtime_env={"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}}
            if local else None,
        )
    remote = ray.remote(num_cpus=1, max_retries=0)(_run)
    pending = [remote.remote(t) for t in tasks]
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield ray.get(done[0])
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        if started:
            ray.shutdown()


def run_sweep(
    base: StudyConfig,
    sites: Sequence[str],
    seeds: Sequence[int],
    *,
    workers: int = 1,
    ray: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[SweepRun]:
    """Run the study for every (site, seed) and return the runs in (site, seed) order.

    Args:
        base: every study setting but ``site`` and ``seed`` (its ``workers`` is ignored: one
            process per run).
        sites: as :func:`parse_sites` returns them.
        seeds: the study seeds of every site.
        workers: processes of the local pool, or CPUs of a local Ray instance.
        ray: None (the local pool), ``"local"`` (a local Ray instance) or a Ray cluster address.
        progress: called with (done, total) after each run.
    """
    if not sites or not seeds:
        raise ConfigError(
            f"a sweep needs at least one site and one seed, got {list(sites)} and {list(seeds)}"
        )
    tasks = [(base, site, int(seed)) for site in sites for seed in seeds]
    it = _pool(tasks, workers) if ray is None else _ray(tasks, ray, workers)
    runs: dict[tuple[str, int], SweepRun] = {}
    for run in it:
        runs[(run.site, run.seed)] = run
        if progress is not None:
            progress(len(runs), len(tasks))
    return [runs[(site, seed)] for _, site, seed in tasks]


def sweep_results(base: StudyConfig, runs: Sequence[SweepRun], extra_config: dict | None = None) -> dict:
    """The sweep's ``results.json``: every method pooled over all runs, and each run's summary."""
    cfg = dataclasses.asdict(base)
    for key in ("site", "seed", "workers"):
        cfg.pop(key)
    cfg["image_size"] = list(base.image_size)
    cfg["methods"] = list(base.methods)
    cfg["sites"] = sorted({r.site for r in runs}, key=[r.site for r in runs].index)
    cfg["seeds"] = sorted({r.seed for r in runs}, key=[r.seed for r in runs].index)
    cfg.update(extra_config or {})
    keys = [m.key for m in METHODS if any(r.method == m.key for run in runs for r in run.rows)]
    pooled, per_run = {}, []
    for m in (m for m in METHODS if m.key in keys):
        rows = [r for run in runs for r in run.rows if r.method == m.key]
        pooled[m.key] = summarize(m, rows, bound_source(base, m))
        medians = [
            summarize(m, [r for r in run.rows if r.method == m.key])["translation_error_m"]["median"]
            for run in runs if any(r.method == m.key for r in run.rows)
        ]
        pooled[m.key]["runs"] = len(medians)
        pooled[m.key]["run_translation_median_m"] = {
            **median_p90(medians), "min": _finite_min(medians), "max": _finite_max(medians)
        }
    for run in runs:
        methods = {}
        for m in (m for m in METHODS if m.key in keys):
            rows = [r for r in run.rows if r.method == m.key]
            if rows:
                s = summarize(m, rows)
                methods[m.key] = {k: s[k] for k in _RUN_KEYS}
        per_run.append({"site": run.site, "seed": run.seed, "methods": methods})
    results = {"config": cfg, "software": software(), "methods": json_ready(pooled),
               "runs": json_ready(per_run)}
    return {**results, "settings": sweep_settings_line(results)}


def sweep_settings_line(results: dict) -> str:
    """The study's settings line of a sweep's ``results`` (the ``config`` and ``software`` entries).

    It names every site (file names) and seed where the study's names one.
    """
    cfg = dict(results["config"])
    sites, seeds = cfg.pop("sites"), cfg.pop("seeds")
    cfg["site"] = ", ".join(s if s in ("paper",) or s.startswith("random:") else Path(s).name for s in sites)
    cfg["seed"] = ", ".join(str(s) for s in seeds)
    cfg.pop("methods", None)
    return settings_line({"config": cfg, "software": results.get("software") or {}})


def _finite_min(values: Sequence[float]) -> float:
    ok = [v for v in values if np.isfinite(v)]
    return min(ok) if ok else float("nan")


def _finite_max(values: Sequence[float]) -> float:
    ok = [v for v in values if np.isfinite(v)]
    return max(ok) if ok else float("nan")


def comparable(results: dict) -> dict:
    """``results`` without what the wall clock decides (latency, elapsed time, the backend)."""
    out = {k: v for k, v in results.items() if k not in ("software", "settings")}
    out["config"] = {k: v for k, v in results["config"].items() if k not in ("elapsed_s", "backend")}
    out["methods"] = {
        k: {f: v for f, v in s.items() if f != "latency_s"} for k, s in results["methods"].items()
    }
    return out


def table_markdown(results: dict) -> str:
    """One table: each method pooled over every run, with the spread of the runs' medians."""
    c = results["config"]
    lines = [
        f"Settings: {results['settings']}",
        "",
        f"Sweep: {len(c['sites'])} sites x {len(c['seeds'])} seeds ({len(results['runs'])} runs), "
        f"{c['detector']} detector, {c['association']} association, {c['noise']} prior, "
        f"{c['n_viewpoints']} viewpoints x {c['n_agents']} UAVs per run, {c.get('backend', '?')}.",
        "",
        "| Method | Runs | Successful | Translation median / P90 (m) | Rotation median / P90 (°) "
        "| Run medians: median [min, max] (m) |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for m in METHODS:
        r = results["methods"].get(m.key)
        if r is None:
            continue
        t, rot, spread = r["translation_error_m"], r["rotation_error_deg"], r["run_translation_median_m"]
        lines.append(
            f"| {m.label} | {r['runs']} | {r['successful']}/{r['total']} "
            f"| {cell(t['median'])} / {cell(t['p90'])} "
            f"| {cell(rot['median'])} / {cell(rot['p90'])} "
            f"| {cell(spread['median'])} [{cell(spread['min'])}, {cell(spread['max'])}] |"
        )
    lines += ["", "Errors over successful poses only, pooled over every image of every run (the "
              "study's convention); the last column is the spread of the runs' own medians."]
    return "\n".join(lines) + "\n"


def write_rows_csv(path: Path, runs: Sequence[SweepRun], settings: str | None = None) -> None:
    """Every per-image row of every run, with its ``site`` and ``seed`` first.

    ``settings``: the sweep's settings line, written first as ``# Settings: ...``.
    """
    rows = [r for run in runs for r in run.rows]
    which = [(run.site, run.seed) for run in runs for _ in run.rows]
    write_records_csv(path, ImageResult, rows, lead=(("site", "seed"), which),
                      comment=None if settings is None else f"Settings: {settings}")


def sweep(
    base: StudyConfig,
    sites: Sequence[str],
    seeds: Sequence[int],
    out: str | Path,
    *,
    workers: int = 1,
    ray: str | None = None,
    progress: bool = True,
    overwrite: bool = False,
) -> dict:
    """Run a sweep into ``out`` (``results.json``, ``table.md``, ``per_image.csv``, all at once)."""
    staged = StagedOutput(out, overwrite=overwrite, owned=SWEEP_FILES)
    with staged:
        t0 = time.perf_counter()
        bar = tqdm(total=len(sites) * len(seeds), unit="run", desc="sweep", disable=not progress,
                   file=sys.stderr)
        try:
            runs = run_sweep(base, sites, seeds, workers=workers, ray=ray,
                             progress=lambda done, total: bar.update(done - bar.n))
        finally:
            bar.close()
        backend = "process pool" if ray is None else f"Ray ({ray})"
        results = sweep_results(base, runs, {"elapsed_s": round(time.perf_counter() - t0, 1),
                                             "backend": backend})
        write_results_json(staged.stage / "results.json", results)
        atomic_write_text(staged.stage / "table.md", table_markdown(results))
        write_rows_csv(staged.stage / "per_image.csv", runs, results["settings"])
    return results


def _parser() -> CommandParser:
    p = CommandParser(
        prog="uav-struct sweep",
        allow_abbrev=False,
        description="Run the study over many sites and seeds, on a local process pool or on Ray, "
        "and merge the runs into one table (table.md) and results.json.",
        epilog="Every other option of `uav-struct study` (--detector, --association, --noise, --quick, "
        "--stage, --as-built, --pixel-sigma, --renderer, ...) is accepted and applies to every run; "
        "see `uav-struct study --help`.",
    )
    p.add_argument("--sites", required=True,
                   help="comma-separated: paper, random:N, random:A-B (inclusive), site files (*.json), "
                   "IFC files (*.ifc); required, no default")
    p.add_argument("--seeds", default="0", help="study seeds of every site: N, A-B or a comma list")
    p.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                   help="run on Ray: alone, a local Ray instance with --workers CPUs; with an address "
                   "(auto, host:6379, ray://host:10001), that running cluster (default: no Ray, a local "
                   "process pool of --workers processes)")
    p.add_argument("--workers", type=int, default=1, help="local processes (or local Ray CPUs)")
    p.add_argument("--out", default="sweep", help="output folder")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the results of an earlier sweep in --out")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """``uav-struct sweep``; returns the exit status."""
    from uav_struct_env.processes import WorkerDied
    from uav_struct_env.study.study import _parser as study_parser
    from uav_struct_env.study.study import study_config
    from uav_struct_env.validate import INPUT_ERRORS, check_option, check_output_dir, check_site, refuse

    prog = "uav-struct sweep"
    args, rest = _parser().parse_known_args(argv)
    taken = [a for a in rest if a.split("=")[0] in ("--site", "--seed", "--out", "--workers", "--no-figures")]
    if taken:
        return refuse(prog, f"{taken[0].split('=')[0]} is not a sweep option (use --sites, --seeds; "
                      "a sweep writes no figures)")
    study = study_parser()
    study.prog, study.allow_abbrev = prog, False
    study_args = study.parse_args(rest)
    try:
        base = study_config(study_args, site="paper", seed=0, workers=1)
        sites = parse_sites(args.sites)
        seeds = parse_seeds(args.seeds)
        check_option("--workers", args.workers, 1, integer=True)
        if args.ray is not None:
            require_ray()
        for site in sites:
            if not site.startswith("random:") and site != "paper":
                check_site(site, study_args.stage)
        check_output_dir(args.out, overwrite=args.overwrite)
    except INPUT_ERRORS as err:
        return refuse(prog, err)
    try:
        results = sweep(base, sites, seeds, args.out, workers=args.workers, ray=args.ray,
                        progress=not args.no_progress, overwrite=args.overwrite)
    except (OutputExistsError, NotADirectoryError) as err:  # another run took --out since the check
        return refuse(prog, err)
    except (WorkerDied, OSError) as err:
        return refuse(prog, f"{err}; nothing written to {args.out}", status=1)
    out = Path(args.out)
    print((out / "table.md").read_text())
    print(f"Wrote {out.resolve()}/ ({', '.join(SWEEP_FILES)}) in {results['config']['elapsed_s']} s")
    return 0
