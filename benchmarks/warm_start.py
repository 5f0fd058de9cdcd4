"""The warm start against the full search, frame by frame, on the training configuration's flights.

Runs the ``state`` training configuration (warm start on) and localizes every frame that has a
warm start a second time with the full hypothesis search (no warm start), from the same
detections and prior. Prints how often the warm start answered, whether the two agree (success,
identities, pose) and how often either gave a wrong identity (association precision below 1);
where they differ, the frame.

    .venv/bin/python benchmarks/warm_start.py --steps 4000                   # hover at the starts
    .venv/bin/python benchmarks/warm_start.py --policy random --steps 4000
    .venv/bin/python benchmarks/warm_start.py --model runs/RUN --steps 4000  # a policy's flights

One agent-step is one agent's frame; frames at a reset or after a failure have no warm start.
What the warm start saves: ``benchmarks/wrapper_throughput.py --warm-start / --no-warm-start``.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(policy: str = "hold", steps: int = 4000, seed: int = 0, model: str | None = None,
         episodes: int = 20) -> dict:
    warnings.filterwarnings("ignore", "The `render_mode` attribute is not defined")
    from wrapper_throughput import measure, record

    from localization.metrics import association_scores, pose_errors
    from uav_struct_env.stack import LocalizationStack
    from uav_struct_env.wrappers import make_train_env

    counts: Counter = Counter()
    differ: list[tuple] = []
    pose_gap = [0.0]
    localize = LocalizationStack.localize

    def both(self, image, truth, prior, gt=None, prior_sigmas=None, warm_start=None):
        frame = localize(self, image, truth, prior, gt, prior_sigmas=prior_sigmas, warm_start=warm_start)
        if not checking or warm_start is None:
            return frame
        warm = frame.estimate
        full = self.localizer.localize(frame.detections, prior, prior_sigmas=prior_sigmas)

        def precision(est):
            ids = frame.detections.true_ids
            return association_scores(est.assignment, ids, self.model_ids).precision if est.success else 1.0

        counts.update(frames=1, answered=warm.warm_started, warm_success=warm.success,
                      full_success=full.success, warm_wrong=precision(warm) < 1,
                      full_wrong=precision(full) < 1)
        if warm.success and full.success and np.array_equal(warm.assignment, full.assignment):
            counts.update(same=1)
            pose_gap[0] = max(pose_gap[0], pose_errors(warm.cam_from_world, full.cam_from_world)[0])
        elif warm.success or full.success:
            errors = [pose_errors(e.cam_from_world, gt)[0] if e.success else float("nan")
                      for e in (warm, full)]
            differ.append((warm.warm_started, full.failure_code.value if full.failure_code else "success",
                           int(warm.n_inliers), int(full.n_inliers), *errors))
        return frame

    env = make_train_env("state")
    checking = False
    flights = record(env, model, episodes, seed) if model is not None else policy
    LocalizationStack.localize = both
    try:
        checking = True
        measure(env, steps, flights, seed)
    finally:
        LocalizationStack.localize = localize
        env.close()
    n = counts["frames"]
    print(f"flights: {'trained (' + model + ')' if model else policy}, seed {seed}, {steps} agent-steps")
    print(f"frames with a warm start       {n}")
    print(f"answered by it (no search)     {counts['answered']} ({counts['answered'] / max(n, 1):.1%})")
    print(f"successes: warm start / full   {counts['warm_success']} / {counts['full_success']}")
    print(f"both succeed, same identities  {counts['same']} (poses within {pose_gap[0]:.2g} m)")
    print(f"wrong identities: warm / full  {counts['warm_wrong']} / {counts['full_wrong']}")
    print(f"frames where they differ       {len(differ)}")
    if differ:
        print("  answered | full search's result | pairs warm / full | error warm / full [m]")
        for answered, result, pw, pf, ew, ef in differ:
            print(f"  {answered!s:8} | {result:27} | {pw:2d} / {pf:2d} | {ew:.3f} / {ef:.3f}")
    return {**counts, "max_pose_gap_m": pose_gap[0], "differ": differ}


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--policy", default="hold", choices=("hold", "random"),
                   help="the flights replayed (without --model)")
    p.add_argument("--steps", type=int, default=4000, help="env steps recorded")
    p.add_argument("--seed", type=int, default=0, help="env seed")
    p.add_argument("--model", default=None, help="a trained policy's folder: its flights, replayed")
    p.add_argument("--episodes", type=int, default=20, help="episodes recorded with --model")
    args = p.parse_args()
    if args.steps < 1 or args.episodes < 1:
        p.error(f"--steps and --episodes must be at least 1, got {args.steps} and {args.episodes}")
    main(**vars(args))
