"""Property tests: random layouts, poses, noise, misses and clutter.

1. ``Localizer.localize`` never raises on well-typed input and always returns a valid pose
   (the prior when it fails, with a reason).
2. Stated bound: with correct detections (every in-frame landmark, <= 1 px noise, no clutter) a
   ``robust`` success is never farther from the truth than ``max(1 m, 10 x)`` the position RMS
   from its own covariance. (``paper`` association makes no such promise: with a prior that is
   off by metres it silently picks wrong identities, which is why ``robust`` exists.)

Besides the paper's camera over random points (``scenes``), both draw from
:func:`localization.testing.fuzz.draw_case` (``fuzz_scenes``): regular and irregular grids on one or
several levels, long lenses and off-centre principal points -- the layouts of issue 19, where a
regular grid seen through a long lens broke the bound.

``derandomize=True`` makes every run (CI included) draw the same examples, so a failure is
reproducible rather than a rare flake; to explore new examples, drop it locally.
"""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from localization import Localizer
from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import check_transform, look_at, project
from localization.testing.fuzz import draw_case
from localization.testing.synthetic import perturb_attitude

W, H = 1280, 720


@st.composite
def scenes(draw, clean=False):
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    m = draw(st.integers(4, 14))
    planar = draw(st.booleans())
    X = rng.uniform([-6, -6, 0], [6, 6, 6], size=(m, 3))
    if planar:
        X[:, 2] = draw(st.floats(0.0, 6.0))
    d = draw(st.floats(12.0, 40.0))
    az = draw(st.floats(0, 2 * np.pi))
    h = draw(st.floats(5.0, 25.0))
    T = look_at([d * np.cos(az), d * np.sin(az), h], X.mean(axis=0))
    uv, depth = project(PAPER_K, T, X)
    vis = (depth > 0) & (uv[:, 0] > 0) & (uv[:, 0] < W - 1) & (uv[:, 1] > 0) & (uv[:, 1] < H - 1)
    sigma = draw(st.floats(0.0, 1.0 if clean else 3.0))
    miss = 0.0 if clean else draw(st.floats(0.0, 0.4))
    n_fp = 0 if clean else draw(st.integers(0, 4))
    keep = vis & (rng.random(m) >= miss)
    det = uv[keep] + rng.normal(0, sigma, (int(keep.sum()), 2))
    det = np.vstack([det, rng.uniform([0, 0], [W, H], (n_fp, 2))])
    det = det[rng.permutation(det.shape[0])]
    prior = perturb_attitude(
        T,
        rng.uniform(-3, 3, 3),
        np.radians(rng.uniform([-2, -2, -5], [2, 2, 5])),
    )
    mode = draw(st.sampled_from(["paper", "robust"]))
    return X, PAPER_K, (W, H), T, det, prior, mode


@st.composite
def fuzz_scenes(draw):
    case = draw_case(np.random.default_rng(draw(st.integers(0, 2**32 - 1))))
    mode = draw(st.sampled_from(["paper", "robust"]))
    return (
        case.landmarks_xyz,
        case.K,
        case.image_size,
        case.cam_from_world,
        case.detections_uv,
        case.prior_cam_from_world,
        mode,
    )


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(scenes(), fuzz_scenes()))
def test_never_crashes_and_always_returns_a_valid_pose(scene):
    X, K, size, T, det, prior, mode = scene
    est = Localizer(X, K, association=mode, image_size=size).localize(det, prior)
    check_transform("cam_from_world", est.cam_from_world)
    assert est.assignment.shape == (det.shape[0],)
    assert np.all((est.assignment >= -1) & (est.assignment < X.shape[0]))
    assigned = est.assignment[est.assignment >= 0]
    assert np.unique(assigned).size == assigned.size  # one-to-one
    if est.success:
        assert est.n_inliers >= 4 and np.isfinite(est.reprojection_rmse_px)
    else:
        assert isinstance(est.failure_reason, str) and est.failure_reason
        np.testing.assert_array_equal(est.cam_from_world, prior)


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(scenes(clean=True), fuzz_scenes()))
def test_robust_success_with_correct_detections_is_near_the_truth(scene):
    X, K, size, T, det, prior, _ = scene
    est = Localizer(X, K, association="robust", image_size=size).localize(det, prior)
    if est.success:
        err = np.linalg.norm(est.position - np.linalg.inv(T)[:3, 3])
        rms = np.sqrt(np.trace(est.covariance[:3, :3]))
        assert err <= max(1.0, 10.0 * rms), (err, rms)
