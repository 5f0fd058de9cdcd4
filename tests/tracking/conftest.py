"""A synthetic four-camera scene: the paper's camera at the study's distances, workers on a site."""

from __future__ import annotations

import numpy as np
import pytest

from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import look_at, project
from tracking import CameraView, WorkerDetection

SITE_CENTRE = np.array([10.0, 7.5, 0.0])


def four_views(distance: float = 25.0, height: float = 15.0) -> list[CameraView]:
    """One camera per side of the site, ``distance`` m out and ``height`` m up, aimed at its centre."""
    views = []
    for k, az in enumerate(np.radians([0.0, 90.0, 180.0, 270.0])):
        eye = SITE_CENTRE + np.array([distance * np.cos(az), distance * np.sin(az), height])
        views.append(CameraView(f"uav_{k}", look_at(eye, SITE_CENTRE), PAPER_K))
    return views


def random_workers(rng: np.random.Generator, n: int, spacing: float = 1.0) -> dict[str, np.ndarray]:
    """``n`` workers (feet on the ground, head top 1.6-1.9 m up) at least ``spacing`` m apart."""
    out: dict[str, np.ndarray] = {}
    while len(out) < n:
        xy = SITE_CENTRE[:2] + rng.uniform([-9.0, -6.0], [9.0, 6.0])
        if any(np.linalg.norm(p[0, :2] - xy) < spacing for p in out.values()):
            continue
        out[f"w{len(out)}"] = np.array([[*xy, 0.0], [*xy, rng.uniform(1.6, 1.9)]])
    return out


def detect(
    views: list[CameraView],
    workers: dict[str, np.ndarray],
    rng: np.random.Generator | None = None,
    sigma: float = 1.0,
    truth_views: list[CameraView] | None = None,
) -> dict[str, list[WorkerDetection]]:
    """Project every worker into every view (true poses ``truth_views``, default ``views``) + noise."""
    out = {}
    for view in truth_views or views:
        dets = []
        for name, pts in workers.items():
            uv, depth = project(view.K, view.cam_from_world, pts)
            assert np.all(depth > 0)
            if rng is not None:
                uv = uv + rng.normal(0.0, sigma, uv.shape)
            dets.append(WorkerDetection(uv[0], uv[1], sigma, label=name))
        order = rng.permutation(len(dets)) if rng is not None else np.arange(len(dets))
        out[view.name] = [dets[i] for i in order]
    return out


@pytest.fixture
def views() -> list[CameraView]:
    return four_views()
