"""Confident wrong poses from pixels: count them in study outputs, record and replay localizations.

Issue 44 calls a success *wrong* when its camera centre lies farther than ``max(1 m, 3 x the
view's Cramer-Rao bound)`` from the truth (``per_image.csv``'s ``translation_error_m`` and
``crb_translation_m``). Five commands:

``count`` prints, for every ``per_image.csv`` under the folders given, per method: the views,
the views with at least four visible landmarks, the successes, the wrong ones and the median
error, then each wrong row (uav, viewpoint, error, limit, pairs, RMS).

    .venv/bin/python benchmarks/wrong_poses.py count results/paper results/busy ...

``record`` runs a command (``uav-struct study ...`` or ``benchmarks/site_conditions_study.py``)
with ``benchmarks/recording`` on ``PYTHONPATH``, which pickles every structural localization
(the localizer, the detections, the prior, the truth, the frame's image and the site the stack was
built with) into ``--into``, in the spawned workers too.

    .venv/bin/python benchmarks/wrong_poses.py record --into rec/paper -- \\
        .venv/bin/uav-struct study --workers 2 --out results/paper --overwrite --no-figures

``replay`` localizes every recorded frame again with the code as it is now, the detections fixed,
and prints per method the successes and wrong poses of the recording and of the replay, the wrong
ones of the replay, and the poses that changed. Where the recording holds the image and the site
and the detector reads the image, the replayed pose is held to the building's structure as the
stack holds it (:mod:`uav_struct_env.stack.confirm`); ``--no-confirm`` leaves that out. The bound
comes from the study's ``per_image.csv``
(the row with the same method and true camera centre), so ``--study`` names the run's output.
A replay of the guided detector's runs holds its detections fixed: a change to the localizer
that moves its first pass moves its detections in a real run, not here.

    .venv/bin/python benchmarks/wrong_poses.py replay rec/paper --study results/paper

``cost`` times, on the recorded frames whose pose the confirmation assesses (successes on four
pairs, detector reading the image), the learned detector (default weights, the set's landmarks,
on one thread) and the confirmation, alternating frame by frame, and prints both medians and
their ratio: the confirmation's share of a frame's latency under the machine's load of the moment.

    .venv/bin/python benchmarks/wrong_poses.py cost rec/paper --frames 60

``diagnose`` replays the successes of recordings (detections fixed, held to the structure as
``replay`` holds them) and prints, per recording and in total, what the verification weighs: the
right successes, those beyond 3 x the bound (and of them those resting on a wrong pair), the wrong
ones, how many wrong ones an
efficient localizer (Gaussian at the view's Cramer-Rao covariance, the study's pixel sigma) would
show by chance, and what a bias test at the fit's a posteriori sigma (its residuals' noise, when
larger than the detector's declared one) would refuse of each; then the successes beyond 3 x the
bound (the wrong ones first), each with its pairs, sigmas, protection levels and tolerance.

    .venv/bin/python benchmarks/wrong_poses.py diagnose rec/a rec/b --studies results/a results/b
"""

from __future__ import annotations

import argparse
import math
import os
import pickle
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

#: A success farther than ``max(FLOOR_M, FACTOR x bound)`` from the truth is wrong (issue 44, item 3).
FLOOR_M = 1.0
FACTOR = 3.0

_HERE = Path(__file__).resolve().parent


def limit_m(bound_m: float) -> float:
    """The error beyond which a success with this Cramer-Rao bound is wrong, m."""
    return max(FLOOR_M, FACTOR * bound_m) if math.isfinite(bound_m) else FLOOR_M


def is_success(row: dict) -> bool:
    """Whether a ``per_image.csv`` row is a success."""
    return row["success"] in ("True", "1", "true")


def is_wrong(row: dict) -> bool:
    """Whether a ``per_image.csv`` row is a wrong success."""
    if not is_success(row):
        return False
    return float(row["translation_error_m"]) > limit_m(float(row["crb_translation_m"]))


def rows_by_method(path: Path, structural_only: bool = True) -> dict[str, list[dict]]:
    """The rows of one ``per_image.csv`` by method, in file order (the ArUco ones left out unless asked)."""
    from uav_struct_env.study.cells import read_records_csv

    by_method: dict[str, list[dict]] = defaultdict(list)
    for r in read_records_csv(path):
        if not (structural_only and r["method"].startswith("aruco")):
            by_method[r["method"]].append(r)
    return by_method


def per_image_files(folders: list[Path]) -> list[Path]:
    """Every ``per_image.csv`` in or under ``folders``, sorted."""
    out = []
    for folder in folders:
        out += [folder] if folder.name == "per_image.csv" else sorted(folder.rglob("per_image.csv"))
    return out


def count(folders: list[Path], structural_only: bool = True) -> dict[str, dict]:
    """Print and return, per ``per_image.csv`` and method: views, posable views, successes, wrong."""
    summary = {}
    total = [0, 0]
    for path in per_image_files(folders):
        name = str(path.parent)
        for method, mine in rows_by_method(path, structural_only).items():
            ok = [r for r in mine if is_success(r)]
            wrong = [r for r in mine if is_wrong(r)]
            posable = sum(int(r["n_visible"]) >= 4 for r in mine)
            errs = [float(r["translation_error_m"]) for r in ok]
            med = float(np.median(errs)) if errs else float("nan")
            summary[f"{name}:{method}"] = {"views": len(mine), "posable": posable, "poses": len(ok),
                                           "wrong": len(wrong), "median_m": med}
            total[0] += len(ok)
            total[1] += len(wrong)
            print(f"{name:<48} {method:<16} views {len(mine):>3} (>=4 visible {posable:>3}) "
                  f"poses {len(ok):>3} wrong {len(wrong):>2} median {med:.3f} m")
            for r in wrong:
                err, lim = float(r["translation_error_m"]), limit_m(float(r["crb_translation_m"]))
                print(f"    wrong: uav {r['uav']} vp {r['viewpoint']} error {err:.2f} m limit {lim:.2f} m"
                      f" pairs {r['n_inliers']} correct {r['n_correct']}/{r['n_assigned']}"
                      f" rms {float(r['reprojection_rmse_px']):.2f} px")
    print(f"total: {total[0]} poses, {total[1]} wrong")
    return summary


def record(into: Path, command: list[str]) -> int:
    """Run ``command`` with every structural localization pickled into ``into``; its return code."""
    env = dict(os.environ)
    env["UAV_STRUCT_RECORD"] = str(into)
    paths = [str(_HERE.parent), str(_HERE / "recording"), env.get("PYTHONPATH", "")]
    env["PYTHONPATH"] = os.pathsep.join(p for p in paths if p)
    return subprocess.call(command, env=env)


def _view_key(method: str, centre) -> tuple:
    """A view's key: its method and true camera centre rounded to 1 mm."""
    return (method, *(round(float(x), 3) for x in centre))


def _rows_by_centre(study: Path) -> dict[tuple, dict]:
    """:func:`_view_key` -> the ``per_image.csv`` row, for every file under ``study``."""
    from uav_struct_env.study.cells import read_records_csv

    out = {}
    for path in per_image_files([study]):
        for r in read_records_csv(path):
            out[_view_key(r["method"], (r["gt_x"], r["gt_y"], r["gt_z"]))] = r
    return out


def _bounds(study: Path) -> dict[tuple, float]:
    """:func:`_view_key` -> the view's bound, from every per_image.csv under ``study``."""
    return {key: float(r["crb_translation_m"]) for key, r in _rows_by_centre(study).items()}


class _Confirmations:
    """The stack's pose confirmation for recorded frames: one set of templates per recorded site."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._templates: dict[str, tuple] = {}

    def __call__(self, rec: dict) -> tuple[object, object] | None:
        """``(confirmation, image)`` for a recording, or None where the stack would hold none."""
        import cv2

        from localization.verify import CONFIRM_TOLERANCE_M
        from uav_struct_env.sim.templates import SiteTemplates
        from uav_struct_env.stack.confirm import confirmation_for

        if rec.get("site") is None or rec.get("image") is None or rec.get("detector") == "projection":
            return None
        if rec["site"] not in self._templates:
            site = pickle.loads((self.folder / rec["site"]).read_bytes())
            self._templates[rec["site"]] = (site.landmarks("all").xyz, SiteTemplates(site))
        stage_xyz, templates = self._templates[rec["site"]]
        image = cv2.imread(str(self.folder / rec["image"]), cv2.IMREAD_COLOR)[..., ::-1]
        return confirmation_for(templates, stage_xyz, rec["localizer"], CONFIRM_TOLERANCE_M), image


def _replay_one(rec: dict, held: tuple | None = None) -> tuple[bool, float, object]:
    """Localize a recorded frame again: (success, error m, estimate).

    ``held``: ``(confirmation, image)`` the pose is held to (:class:`_Confirmations`), or None.
    """
    from localization import Detections
    from localization.metrics import pose_errors

    det = Detections(rec["uv"], rec["scores"])
    est = rec["localizer"].localize(det, rec["prior"], prior_sigmas=rec["prior_sigmas"],
                                    warm_start=rec["warm_start"])
    if held is not None:
        assessed = est.success and est.n_inliers <= held[0].max_pairs
        t0 = time.perf_counter()
        est = held[0].confirmed(held[1], est, rec["prior"])
        if assessed:
            est.timings["confirm"] = time.perf_counter() - t0
    err = pose_errors(est.cam_from_world, rec["gt"])[0] if est.success else float("nan")
    return bool(est.success), float(err), est


def replay(records: Path, study: Path, show: int = 40, confirm: bool = True) -> dict[str, list[int]]:
    """Replay every recording in ``records`` against the bounds of ``study``; print and return counts.

    ``confirm``: hold the replayed poses to the building's structure where the recording allows.

    Returns per method ``[poses recorded, wrong recorded, poses replayed, wrong replayed]``.
    """
    from localization.geometry.transforms import camera_center

    bounds = _bounds(study)
    counts: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0, 0])
    changed, wrong_now = [], []
    times, verify_times, confirm_times = [], [], []
    confirmations = _Confirmations(records) if confirm else None
    for path in sorted(records.glob("[0-9]*.pkl")):
        rec = pickle.loads(path.read_bytes())
        bound = bounds.get(_view_key(rec["landmarks"], camera_center(rec["gt"])), float("nan"))
        lim = limit_m(bound)
        held = None if confirmations is None else confirmations(rec)
        t0 = time.perf_counter()
        ok, err, est = _replay_one(rec, held)
        times.append(time.perf_counter() - t0)
        verify_times.append(est.timings.get("verify", 0.0))
        if "confirm" in est.timings:
            confirm_times.append(est.timings["confirm"])
        was_ok, was_err = rec["success"], rec["translation_error_m"]
        n = counts[rec["landmarks"]]
        n[0] += was_ok
        n[1] += was_ok and was_err > lim
        n[2] += ok
        n[3] += ok and err > lim
        tag = f"{path.name} {rec['landmarks']}"
        if ok and err > lim:
            wrong_now.append(f"{tag}: error {err:.2f} m limit {lim:.2f} pairs {est.n_inliers} "
                             f"rms {est.reprojection_rmse_px:.2f} px")
        if ok != was_ok:
            why = "" if ok else f" ({est.failure_code.value}: {est.failure_reason})"
            changed.append(f"{tag}: {'refused' if was_ok else 'gained'}, error "
                           f"{(was_err if was_ok else err):.2f} m limit {lim:.2f}{why}")
    for method, (p0, w0, p1, w1) in sorted(counts.items()):
        print(f"{str(records):<48} {method:<16} poses {p0:>3} -> {p1:>3}  wrong {w0} -> {w1}")
    for line in wrong_now:
        print("  wrong now:", line)
    for line in changed[:show]:
        print("  changed:", line)
    if len(changed) > show:
        print(f"  ... {len(changed) - show} more changed")
    if times:
        ms, vms = 1e3 * np.asarray(times), 1e3 * np.asarray(verify_times)
        print(f"  replay time per frame: median {np.median(ms):.1f} ms, P99 {np.percentile(ms, 99):.0f} ms; "
              f"of it the verification: median {np.median(vms):.1f} ms, P99 {np.percentile(vms, 99):.0f} ms")
    if confirm_times:
        cms = 1e3 * np.asarray(confirm_times)
        print(f"  the confirmation, on the {cms.size} poses it assessed: median {np.median(cms):.1f} ms, "
              f"P99 {np.percentile(cms, 99):.0f} ms")
    return dict(counts)


def chance_beyond(rec: dict, row: dict, samples: np.ndarray | None = None) -> float:
    """P(error > the limit) for an efficient localizer: Gaussian at the view's Cramer-Rao covariance.

    The covariance of the set's landmarks the true pose projects into the image, at the study's
    pixel sigma (``crb_pixel_sigma_px``), scaled so that its RMS is the row's bound (its shape is
    what counts); the probability by Monte Carlo over ``samples`` ((S, 3) standard normal draws).
    """
    from localization.pose.covariance import pose_covariance
    from localization.verify import predicted_in_image

    loc, T, bound = rec["localizer"], rec["gt"], float(row["crb_translation_m"])
    seen = predicted_in_image(loc.K, T, loc.landmarks_xyz, loc.image_size)
    cov = pose_covariance(loc.K, T, loc.landmarks_xyz[seen], float(row["crb_pixel_sigma_px"]))[:3, :3]
    if not (np.all(np.isfinite(cov)) and math.isfinite(bound) and np.trace(cov) > 0):
        return float("nan")
    if samples is None:
        samples = np.random.default_rng(0).standard_normal((20000, 3))
    vals = np.linalg.eigvalsh(cov * (bound**2 / np.trace(cov)))
    e = np.linalg.norm(samples * np.sqrt(np.clip(vals, 0.0, None)), axis=1)  # the norm is rotation-free
    return float(np.mean(e > limit_m(bound)))


def diagnosis(rec: dict, est: object) -> dict:
    """What the verification weighs in one success: its pairs, its fit's sigma, its bias test.

    ``pairs``, ``wrong_pairs`` (by the detections' true ids), ``sigma_px`` (the detector's declared
    fit sigma), ``posterior_sigma_px`` (``sqrt(chi2 / (2n - 6))`` of the fit at that sigma, times it:
    the noise its residuals show), ``tolerance_m`` (the verification's), ``level_m`` (the protection
    level at :data:`localization.verify.BIAS_SHARE` of the declared sigma, the test the verification
    makes) and ``posterior_level_m`` (at that share of the larger of the two sigmas).
    """
    from localization.geometry.transforms import project
    from localization.verify import BIAS_SHARE, CONFIRM_TOLERANCE_M, position_tolerance, protection_level

    loc = rec["localizer"]
    a = est.assignment
    m = a >= 0
    uv = np.asarray(rec["uv"], dtype=np.float64)
    X = loc.landmarks_xyz[a[m]]
    res = project(loc.K, est.cam_from_world, X)[0] - uv[m]
    sigma = loc.fit_sigma_px if loc.fit_sigma_px is not None else loc.pixel_sigma
    n = int(m.sum())
    posterior = sigma * math.sqrt(float(np.sum(res**2)) / sigma**2 / max(2 * n - 6, 1))
    tol = position_tolerance(loc.K, est.cam_from_world, loc.landmarks_xyz, loc.image_size, sigma,
                             loc.tolerance_m if loc.tolerance_m is not None else CONFIRM_TOLERANCE_M)[0]
    if rec["true_ids"] is None:  # a detector without ground truth: no pair can be shown right
        wrong = n
    else:
        wrong = int(np.count_nonzero(np.asarray(rec["model_ids"])[a[m]] != np.asarray(rec["true_ids"])[m]))
    return {"pairs": n, "wrong_pairs": wrong, "sigma_px": sigma, "posterior_sigma_px": posterior,
            "tolerance_m": tol, "level_m": protection_level(loc.K, est.cam_from_world, X, BIAS_SHARE * sigma),
            "posterior_level_m": protection_level(loc.K, est.cam_from_world, X,
                                                  BIAS_SHARE * max(sigma, posterior))}


def diagnose(pairs: list[tuple[Path, Path]], show: int = 40) -> dict[str, int | float]:
    """Replay the successes of each ``(records, study)`` and print what the verification weighs.

    Each frame is localized again and held to the building's structure where the recording allows
    (as :func:`replay` does), so its successes are the stack's.

    Per folder and in total: the successes; the right ones (error at most 3 x the bound); those
    beyond 3 x the bound, and of them those resting on a wrong pair; the wrong ones (beyond the
    limit); the wrong ones an efficient localizer would show by chance (:func:`chance_beyond`,
    summed); and what a bias test at the fit's a posteriori sigma would refuse of each group
    (``posterior_level_m > tolerance_m``, :func:`diagnosis`); the successes' median error, in
    metres and in their bounds. Then the successes beyond 3 x the bound, the wrong ones first,
    each group worst first (``show`` of them). Returns the totals (the medians as
    ``median_error_m`` and ``median_error_bounds``, NaN without a success).
    """
    from localization.geometry.transforms import camera_center

    samples = np.random.default_rng(0).standard_normal((20000, 3))
    keys = ("successes", "right", "beyond_3x", "beyond_3x_wrong_pair", "wrong", "refused_right",
            "refused_beyond_3x", "refused_beyond_3x_wrong_pair", "refused_wrong")
    total: dict[str, int | float] = dict.fromkeys(keys, 0) | {"chance_wrong": 0.0}
    beyond = []
    errors: list[tuple[float, float]] = []  # (error m, error / bound) of every success
    for records, study in pairs:
        rows = _rows_by_centre(study)
        confirmations = _Confirmations(records)
        c: dict[str, int | float] = dict.fromkeys(keys, 0) | {"chance_wrong": 0.0}
        first = len(errors)
        for path in sorted(records.glob("[0-9]*.pkl")):
            rec = pickle.loads(path.read_bytes())
            row = rows.get(_view_key(rec["landmarks"], camera_center(rec["gt"])))
            if row is None:
                continue
            ok, err, est = _replay_one(rec, confirmations(rec))
            if not ok:
                continue
            d = diagnosis(rec, est)
            bound = float(row["crb_translation_m"])
            errors.append((err, err / bound))
            refused = d["posterior_level_m"] > d["tolerance_m"]
            groups = {"successes": True, "right": err <= FACTOR * bound, "beyond_3x": err > FACTOR * bound,
                      "beyond_3x_wrong_pair": err > FACTOR * bound and d["wrong_pairs"] > 0,
                      "wrong": err > limit_m(bound)}
            for g, inside in groups.items():
                c[g] += inside
                if g != "successes":
                    c[f"refused_{g}"] += inside and refused
            p = chance_beyond(rec, row, samples)
            c["chance_wrong"] += p if math.isfinite(p) else 0.0
            if groups["beyond_3x"]:
                beyond.append((groups["wrong"], err / bound, f"{path} {rec['landmarks']}: error {err:.2f} m, "
                               f"bound {bound:.3f} m, pairs {d['pairs']} ({d['wrong_pairs']} wrong), sigma "
                               f"{d['sigma_px']:.2f} -> {d['posterior_sigma_px']:.2f} px, level "
                               f"{d['level_m']:.2f} -> {d['posterior_level_m']:.2f} m, tolerance "
                               f"{d['tolerance_m']:.2f} m"))
        for k in total:
            total[k] += c[k]
        _print_diagnosis(str(records), c | _medians(errors[first:]))
    total |= _medians(errors)
    _print_diagnosis("total", total)
    for wrong, _, line in sorted(beyond, reverse=True)[:show]:  # the wrong ones first
        print("  wrong:" if wrong else "  beyond 3x:", line)
    return total


def _medians(errors: list[tuple[float, float]]) -> dict[str, float]:
    """``median_error_m``, ``median_error_bounds`` of ``[(error m, error / bound), ...]``; NaN if empty."""
    if not errors:
        return {"median_error_m": float("nan"), "median_error_bounds": float("nan")}
    m, b = np.median(np.asarray(errors), axis=0)
    return {"median_error_m": float(m), "median_error_bounds": float(b)}


def _print_diagnosis(name: str, c: dict) -> None:
    print(f"{name:<48} successes {c['successes']:>4}: right {c['right']} (refused {c['refused_right']}), "
          f"beyond 3x {c['beyond_3x']} (refused {c['refused_beyond_3x']}; with a wrong pair "
          f"{c['beyond_3x_wrong_pair']}, refused {c['refused_beyond_3x_wrong_pair']}), wrong {c['wrong']} "
          f"(refused {c['refused_wrong']}; by chance {c['chance_wrong']:.2f}), median error "
          f"{c['median_error_m']:.4f} m ({c['median_error_bounds']:.3f}x the bound)")


def cost(records: Path, frames: int = 60) -> tuple[float, float]:
    """Median ms of the learned detector and of the confirmation over up to ``frames`` assessed frames."""
    from localization.detect.learned import LearnedDetector  # its networks run on one thread

    confirmations = _Confirmations(records)
    detectors: dict[str, object] = {}
    t_det, t_conf = [], []
    for path in sorted(records.glob("[0-9]*.pkl")):
        rec = pickle.loads(path.read_bytes())
        if not rec["success"] or rec["n_inliers"] > 4:
            continue
        held = confirmations(rec)
        if held is None:
            continue
        conf, image = held
        if rec["landmarks"] not in detectors:
            detectors[rec["landmarks"]] = LearnedDetector.for_localizer(rec["landmarks"], image.shape[1],
                                                                        "robust")
            detectors[rec["landmarks"]].detect(image, {})  # the first call sets the sessions up
        _, _, est = _replay_one(rec)
        t0 = time.perf_counter()
        detectors[rec["landmarks"]].detect(image, {})
        t1 = time.perf_counter()
        conf.confirmed(image, est, rec["prior"])
        t_det.append(t1 - t0)
        t_conf.append(time.perf_counter() - t1)
        if len(t_det) >= frames:
            break
    if not t_det:
        print(f"{records}: no frame the confirmation assesses")
        return float("nan"), float("nan")
    det, conf_ms = 1e3 * float(np.median(t_det)), 1e3 * float(np.median(t_conf))
    load = " ".join(Path("/proc/loadavg").read_text().split()[:3]) if Path("/proc/loadavg").exists() else "?"
    print(f"{records}: {len(t_det)} frames, learned detector median {det:.1f} ms, confirmation median "
          f"{conf_ms:.1f} ms (P90 {1e3 * float(np.percentile(t_conf, 90)):.1f}), ratio {conf_ms / det:.2f}; "
          f"load average {load}")
    return det, conf_ms


def main(argv: list[str] | None = None) -> None:
    """The command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    c = sub.add_parser("count", help="count wrong successes in per_image.csv files",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    c.add_argument("folders", nargs="+", type=Path, help="study output folders, searched for per_image.csv")
    r = sub.add_parser("record", help="run a command, recording its structural localizations",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    r.add_argument("--into", type=Path, required=True, help="folder the pickles go to")
    r.add_argument("cmd", nargs=argparse.REMAINDER, help="the command, after --")
    p = sub.add_parser("replay", help="localize recorded frames again with the current code",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("records", type=Path, help="a folder of recordings")
    p.add_argument("--study", type=Path, required=True, help="the recorded run's output (its per_image.csv)")
    p.add_argument("--show", type=int, default=40, help="changed poses printed")
    p.add_argument("--no-confirm", action="store_true",
                   help="do not hold the replayed poses to the building's structure (stack/confirm.py)")
    t = sub.add_parser("cost", help="time the confirmation against the learned detector on recorded frames",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    t.add_argument("records", type=Path, help="a folder of recordings (with images and sites)")
    t.add_argument("--frames", type=int, default=60, help="frames timed")
    g = sub.add_parser("diagnose", help="what the verification weighs in each recorded success",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    g.add_argument("records", type=Path, nargs="+", help="folders of recordings")
    g.add_argument("--studies", type=Path, nargs="+", required=True,
                   help="each recorded run's output (its per_image.csv), in the order of the recordings")
    g.add_argument("--show", type=int, default=40, help="successes beyond 3 x the bound printed")
    args = ap.parse_args(argv)
    if args.command == "count":
        count(args.folders)
    elif args.command == "record":
        cmd = args.cmd[1:] if args.cmd[:1] == ["--"] else args.cmd
        sys.exit(record(args.into, cmd))
    elif args.command == "cost":
        cost(args.records, args.frames)
    elif args.command == "diagnose":
        if len(args.records) != len(args.studies):
            ap.error(f"diagnose needs one --studies folder per recordings folder, got {len(args.records)} "
                     f"recordings and {len(args.studies)} studies")
        diagnose(list(zip(args.records, args.studies, strict=True)), args.show)
    else:
        replay(args.records, args.study, args.show, confirm=not args.no_confirm)


if __name__ == "__main__":
    main()
