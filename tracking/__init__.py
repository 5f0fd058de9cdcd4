"""Multi-view 3D tracking of workers from calibrated cameras at known or estimated poses.

Pure numpy / scipy / OpenCV (and :mod:`localization`'s geometry conventions); it never imports
the simulator, so it works on detections and poses from anywhere.

    from tracking import CameraView, WorkerDetection, track_workers
    views = [CameraView("uav_0", cam_from_world_0, K), CameraView("uav_1", cam_from_world_1, K)]
    result = track_workers(views, {"uav_0": [WorkerDetection(feet_uv, head_uv, 2.0)], "uav_1": [...]})
    [(w.feet_xyz, w.head_xyz, w.cameras) for w in result.tracked]

One stage per module: :mod:`~tracking.views` (inputs), :mod:`~tracking.associate` (cross-view
association by reprojection consistency), :mod:`~tracking.triangulate` (DLT + nonlinear
refinement), composed in :mod:`~tracking.tracker`; :mod:`~tracking.metrics` scores it.
"""

from tracking.associate import gate
from tracking.metrics import error_summary, worker_errors
from tracking.tracker import TrackingResult, WorkerEstimate, track_workers
from tracking.triangulate import PointEstimate, triangulate_point
from tracking.views import CameraView, WorkerDetection

__all__ = [
    "CameraView",
    "PointEstimate",
    "TrackingResult",
    "WorkerDetection",
    "WorkerEstimate",
    "error_summary",
    "gate",
    "track_workers",
    "triangulate_point",
    "worker_errors",
]
