"""CPU time of recorded localizations, and a digest of every estimate to compare code versions bit for bit.

A speed change to the localizer must keep its outputs: record the localizations of a run once
(``benchmarks/wrong_poses.py record``), write the digest of their replay with the code before the
change, and check the code after against it:

    .venv/bin/python benchmarks/wrong_poses.py record --into REC -- \\
        .venv/bin/python benchmarks/wrapper_throughput.py --config state --steps 1500
    .venv/bin/python benchmarks/localization_replay.py REC --write before.txt   # the code before
    .venv/bin/python benchmarks/localization_replay.py REC --check before.txt   # the code after

The digest hashes every field of each :class:`localization.PoseEstimate` but its timings (success,
pose, assignment, covariance, RMSE, failure code and reason, ...) to the bit. The frames are
localized ``--repeats`` times after a warm-up pass; the CPU ms per localization of each pass is
printed (the fastest is the least disturbed: on a shared machine compare code versions in
alternating runs, never across hours).
"""

from __future__ import annotations

import argparse
import hashlib
import pickle
import sys
import time
from pathlib import Path

import numpy as np


def digest(est) -> str:
    """A hex digest of a :class:`localization.PoseEstimate`'s outcome (every field but its timings)."""
    h = hashlib.sha1()
    for v in (est.success, est.reprojection_rmse_px, est.n_inliers, est.failure_reason,
              est.prior_mahalanobis_sq, est.n_hypotheses, est.failure_code, est.warm_started):
        h.update(repr(v).encode())
    for a in (est.cam_from_world, est.assignment, est.covariance, est.refused_cam_from_world):
        h.update(b"None" if a is None else np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def load(folders: list[Path]) -> list[dict]:
    """The recorded localizations (``wrong_poses.py record``'s pickles) in the folders, in name order."""
    records = []
    for folder in folders:
        paths = sorted(folder.glob("[0-9]*.pkl"))
        if not paths:
            raise SystemExit(f"{folder}: no recorded localizations (none of wrong_poses.py record's pickles)")
        records += [pickle.loads(p.read_bytes()) for p in paths]
    return records


def replay(records: list[dict], repeats: int = 3) -> tuple[list[float], list[str], int]:
    """``(CPU ms per localization of each pass, digests of the last pass, successes)``."""
    from localization import Detections

    detections = [Detections(r["uv"], r["scores"]) for r in records]

    def one_pass() -> list:
        return [r["localizer"].localize(d, r["prior"], prior_sigmas=r["prior_sigmas"],
                                        warm_start=r["warm_start"])
                for r, d in zip(records, detections, strict=True)]

    one_pass()  # compile and warm the caches
    ms, estimates = [], []
    for _ in range(repeats):
        t0 = time.process_time()
        estimates = one_pass()
        ms.append(1e3 * (time.process_time() - t0) / len(records))
    return ms, [digest(e) for e in estimates], sum(bool(e.success) for e in estimates)


def main(argv: list[str] | None = None) -> int:
    """The command line (module docstring); 1 when ``--check`` finds a difference."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("records", nargs="+", type=Path, help="folders of recorded localizations")
    ap.add_argument("--repeats", type=int, default=3, help="timed passes over the frames")
    group = ap.add_mutually_exclusive_group()
    group.add_argument("--write", type=Path, default=None, help="write the digests to this file")
    group.add_argument("--check", type=Path, default=None, help="compare the digests with this file")
    args = ap.parse_args(argv)
    records = load(args.records)
    ms, digests, successes = replay(records, args.repeats)
    loadavg = Path("/proc/loadavg")
    load_avg = " ".join(loadavg.read_text().split()[:3]) if loadavg.exists() else "?"
    print(f"{len(records)} localizations, {successes} successes; CPU ms per localization, each pass: "
          + ", ".join(f"{m:.3f}" for m in ms) + f" (load average {load_avg})")
    if args.write is not None:
        args.write.write_text("\n".join(digests) + "\n")
        print(f"wrote {len(digests)} digests to {args.write}")
    if args.check is not None:
        ref = args.check.read_text().split()
        if len(ref) != len(digests):
            print(f"DIFFERENT: {args.check} has {len(ref)} digests, the replay {len(digests)}")
            return 1
        changed = [i for i, (a, b) in enumerate(zip(ref, digests, strict=True)) if a != b]
        if changed:
            print(f"DIFFERENT: {len(changed)} of {len(digests)} estimates changed (first: {changed[:10]})")
            return 1
        print(f"identical: all {len(digests)} estimates equal {args.check}'s to the bit")
    return 0


if __name__ == "__main__":
    sys.exit(main())
