"""Record every structural localization of a run, for :mod:`benchmarks.wrong_poses`'s replay.

Python imports ``sitecustomize`` at start-up from the path, so a run started with this folder on
``PYTHONPATH`` and ``UAV_STRUCT_RECORD=DIR`` set records in every process it spawns too (the
study's workers are spawned, and a patch made in the parent would not reach them). Each call of
:meth:`uav_struct_env.stack.LocalizationStack.localize` on a structural set writes one pickle to
``DIR``: the localizer, the detections, the prior, its sigmas, the warm start, the truth, the
outcome (and its pose and pairs), the frame's image (``image``: a PNG file in ``DIR``, one per
distinct image) and the site the stack was built with (``site``: a pickle in ``DIR``, one per site
and process; None without one), which a replay of the pose confirmation
(:mod:`uav_struct_env.stack.confirm`) renders. Without ``UAV_STRUCT_RECORD`` nothing is patched.
"""

import os

if os.environ.get("UAV_STRUCT_RECORD"):
    import hashlib
    import itertools
    import pickle
    from pathlib import Path

    import uav_struct_env.stack as _stack
    from uav_struct_env.stack import spec as _spec

    _OUT = Path(os.environ["UAV_STRUCT_RECORD"])
    _OUT.mkdir(parents=True, exist_ok=True)
    _COUNT = itertools.count()
    _SITES: dict[int, tuple[object, str]] = {}
    _localize = _spec.LocalizationStack.localize
    _build = _spec.build_stack

    def _site_file(site):
        """The file name the site is pickled to (written once per site and process), or None."""
        if site is None:
            return None
        if id(site) not in _SITES or _SITES[id(site)][0] is not site:
            name = f"site_{os.getpid()}_{len(_SITES)}.pkl"
            (_OUT / name).write_bytes(pickle.dumps(site))
            _SITES[id(site)] = (site, name)
        return _SITES[id(site)][1]

    def _image_file(image):
        """The PNG file name of ``image`` (written once per distinct image), or None."""
        import cv2
        import numpy as np

        if image is None:
            return None
        arr = np.ascontiguousarray(image)
        name = f"img_{hashlib.sha1(arr.tobytes()).hexdigest()[:20]}.png"
        if not (_OUT / name).exists():
            cv2.imwrite(str(_OUT / name), arr[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 1])
        return name

    def _built(spec, K, image_size, **kwargs):
        stack = _build(spec, K, image_size, **kwargs)
        stack._recorded_site = kwargs.get("site")
        return stack

    def _recorded(self, image, landmark_truth, prior_cam_from_world, gt_cam_from_world=None,
                  prior_sigmas=None, warm_start=None):
        frame = _localize(self, image, landmark_truth, prior_cam_from_world, gt_cam_from_world,
                          prior_sigmas, warm_start)
        if self.localizer is not None:
            det = frame.detections
            est = frame.estimate
            record = {
                "landmarks": self.spec.landmarks, "localizer": self.localizer, "uv": det.uv,
                "scores": det.scores, "true_ids": det.true_ids, "model_ids": self.model_ids,
                "prior": prior_cam_from_world, "gt": gt_cam_from_world, "prior_sigmas": prior_sigmas,
                "warm_start": warm_start, "success": bool(est.success),
                "translation_error_m": frame.translation_error_m,
                "cam_from_world": est.cam_from_world, "n_inliers": int(est.n_inliers),
                "detector": self.spec.detector if isinstance(self.spec.detector, str) else "object",
                "image": _image_file(image), "site": _site_file(getattr(self, "_recorded_site", None)),
            }
            path = _OUT / f"{os.getpid()}_{next(_COUNT):05d}.pkl"
            path.write_bytes(pickle.dumps(record))
        return frame

    _spec.LocalizationStack.localize = _recorded
    _spec.build_stack = _built
    _stack.build_stack = _built
