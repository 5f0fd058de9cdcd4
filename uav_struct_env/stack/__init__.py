"""The localization stack: one spec, one builder, one per-frame step (below ``wrappers/``).

    from uav_struct_env.stack import StackSpec, build_stack
    spec = StackSpec(landmarks="column_tops", detector="projection", association="robust")
    stack = build_stack(spec, K, (W, H), model_xyz=site.landmarks("column_tops").xyz, rng=rng)
    frame = stack.localize(image, info["landmarks"], prior_cam_from_world, gt_cam_from_world)
    frame.estimate, frame.scores, frame.translation_error_m, frame.latency_s

The study, the LocalizationWrapper and the benchmarks build their stacks here (docs/design.md,
"The localization stack").
"""

from uav_struct_env.stack.frame import FrameLocalization, localize_aruco_frame, localize_frame
from uav_struct_env.stack.spec import (
    ASSOCIATIONS,
    DETECTORS,
    PAPER_WIDTH_PX,
    STRUCTURAL_DETECTORS,
    LocalizationStack,
    StackSpec,
    build_stack,
    check_weights,
)

__all__ = [
    "ASSOCIATIONS",
    "DETECTORS",
    "PAPER_WIDTH_PX",
    "STRUCTURAL_DETECTORS",
    "FrameLocalization",
    "LocalizationStack",
    "StackSpec",
    "build_stack",
    "check_weights",
    "localize_aruco_frame",
    "localize_frame",
]
