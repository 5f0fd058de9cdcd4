"""Record every structural localization of a run, for :mod:`benchmarks.wrong_poses`'s replay.

Python imports ``sitecustomize`` at start-up from the path, so a run started with this folder on
``PYTHONPATH`` and ``UAV_STRUCT_RECORD=DIR`` set records in every process it spawns too (the
study's workers are spawned, and a patch made in the parent would not reach them). Each call of
:meth:`uav_struct_env.stack.LocalizationStack.localize` on a structural set writes one pickle to
``DIR``: the localizer, the detections, the prior, its sigmas, the warm start, the truth and the
outcome. Without ``UAV_STRUCT_RECORD`` nothing is patched.
"""

import os

if os.environ.get("UAV_STRUCT_RECORD"):
    import itertools
    import pickle
    from pathlib import Path

    from uav_struct_env.stack import spec as _spec

    _OUT = Path(os.environ["UAV_STRUCT_RECORD"])
    _OUT.mkdir(parents=True, exist_ok=True)
    _COUNT = itertools.count()
    _localize = _spec.LocalizationStack.localize

    def _recorded(self, image, landmark_truth, prior_cam_from_world, gt_cam_from_world=None,
                  prior_sigmas=None, warm_start=None):
        frame = _localize(self, image, landmark_truth, prior_cam_from_world, gt_cam_from_world,
                          prior_sigmas, warm_start)
        if self.localizer is not None:
            det = frame.detections
            record = {
                "landmarks": self.spec.landmarks, "localizer": self.localizer, "uv": det.uv,
                "scores": det.scores, "true_ids": det.true_ids, "model_ids": self.model_ids,
                "prior": prior_cam_from_world, "gt": gt_cam_from_world, "prior_sigmas": prior_sigmas,
                "warm_start": warm_start, "success": bool(frame.estimate.success),
                "translation_error_m": frame.translation_error_m,
            }
            path = _OUT / f"{os.getpid()}_{next(_COUNT):05d}.pkl"
            path.write_bytes(pickle.dumps(record))
        return frame

    _spec.LocalizationStack.localize = _recorded
