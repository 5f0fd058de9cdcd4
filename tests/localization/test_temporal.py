"""The pose filter (localization.temporal) on synthetic trajectories with known noise."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from localization.geometry.attitude import attitude_from_world_from_cam, world_from_cam_from_attitude
from localization.geometry.transforms import invert, so3_exp, so3_log
from localization.metrics import pose_errors, pose_nees
from localization.temporal import FilterNoise, PoseFilter

DT = 0.5
NOISE = FilterNoise()


def orbit(n_steps: int, radius: float = 25.0, height: float = 15.0, period: float = 60.0):
    """Truth ``world_from_cam`` of a camera orbiting the origin and looking at it."""
    out = []
    for k in range(n_steps):
        a = 2 * math.pi * k * DT / period
        pos = np.array([radius * math.cos(a), radius * math.sin(a), height])
        yaw = a + math.pi
        pitch = math.atan2(height, radius)
        out.append(world_from_cam_from_attitude(pos, [0.0, pitch, yaw]))
    return out


def motion(T0, T1):
    """The exact world-frame displacement and rotation vector from T0 to T1."""
    return T1[:3, 3] - T0[:3, 3], so3_log(T1[:3, :3] @ T0[:3, :3].T)


class Sensors:
    """GNSS (Gauss-Markov bias + white) and attitude (constant bias + white) as FilterNoise says."""

    def __init__(self, rng):
        self.rng = rng
        self.b_g = rng.standard_normal(3) * NOISE.gnss_bias_sigma
        self.b_a = rng.standard_normal(3) * NOISE.attitude_bias_sigma

    def read(self, T, dt):
        phi = math.exp(-dt / NOISE.gnss_bias_tau)
        step = math.sqrt(1 - phi * phi) * self.rng.standard_normal(3) * NOISE.gnss_bias_sigma
        self.b_g = phi * self.b_g + step
        gnss = T[:3, 3] + self.b_g + self.rng.standard_normal(3) * NOISE.gnss_white_sigma
        att = attitude_from_world_from_cam(T)[1] + self.b_a
        att = att + self.rng.standard_normal(3) * NOISE.attitude_white_sigma
        return gnss, att


def fix_from(T_true, cov, rng):
    """A visual fix drawn from ``cov`` around the truth (``cam_from_world``)."""
    e = rng.multivariate_normal(np.zeros(6), cov)
    W = T_true.copy()
    W[:3, 3] += e[:3]
    W[:3, :3] = so3_exp(e[3:]) @ W[:3, :3]
    return invert(W)


FIX_COV = np.diag([0.1**2] * 3 + [math.radians(0.2) ** 2] * 3)


def run(seed: int, n_steps: int = 80, noise: FilterNoise = NOISE):
    """Fly the orbit with motion input drawn from ``noise``, GNSS, attitude and a fix per step."""
    rng = np.random.default_rng(seed)
    truth = orbit(n_steps)
    sensors = Sensors(rng)
    filt = PoseFilter(noise)
    filt.start(*sensors.read(truth[0], 0.0))
    nees, errors = [], []
    for k in range(1, n_steps):
        d, r = motion(truth[k - 1], truth[k])
        d = d + rng.standard_normal(3) * noise.velocity_sigma * DT
        r = r + rng.standard_normal(3) * noise.angular_rate_sigma * DT
        filt.predict(DT, d, r)
        gnss, att = sensors.read(truth[k], DT)
        filt.update_gnss(gnss)
        filt.update_attitude(att)
        filt.update_pose(fix_from(truth[k], FIX_COV, rng), FIX_COV)
        nees.append(pose_nees(filt.cam_from_world, invert(truth[k]), filt.pose_covariance))
        errors.append(pose_errors(filt.cam_from_world, invert(truth[k])))
    return np.array(nees), np.array(errors), filt, truth


#: A smooth flight: the motion input is good to 5 cm/s and 0.1 deg/s, so fixes average out.
SMOOTH = FilterNoise(velocity_sigma=0.05, angular_rate_sigma=math.radians(0.1))


@pytest.mark.parametrize("noise", [NOISE, SMOOTH], ids=["default", "smooth"])
def test_converges_to_the_truth_with_consistent_nees(noise):
    """Over 20 seeded runs the NEES of the filtered pose is chi-square(6) and its error small."""
    all_nees, errors = [], []
    for seed in range(20):
        nees, err, _, _ = run(seed, noise=noise)
        all_nees.append(nees[20:])
        errors.append(err[20:])
    nees = np.concatenate(all_nees)
    # mean NEES of N chi2(6) draws: 6 within its 99.9 % interval (correlation in time widens it x3)
    n = len(nees)
    half = 3 * (chi2.ppf(0.9995, 6 * n) - 6 * n) / n
    assert abs(nees.mean() - 6.0) < half, (nees.mean(), half)
    errors = np.concatenate(errors)
    # one fix alone: 0.1 m per axis, median 3-D error 0.154 m; 0.2 deg per axis, median 0.31 deg
    single_t, single_r = 0.1 * math.sqrt(chi2.ppf(0.5, 3)), 0.2 * math.sqrt(chi2.ppf(0.5, 3))
    factor = 1.0 if noise is NOISE else 0.5  # a smooth flight averages several fixes
    assert np.median(errors[:, 0]) < factor * single_t
    assert np.median(errors[:, 1]) < factor * single_r


def test_a_fix_far_off_is_gated_and_reported():
    _, _, filt, truth = run(1, n_steps=30)
    before = filt.world_from_cam.copy()
    wrong = truth[-1].copy()
    wrong[:3, 3] += [3.0, 0.0, 0.0]  # a wrong association: 3 m off, claiming 0.1 m
    upd = filt.update_pose(invert(wrong), FIX_COV)
    assert not upd.accepted
    assert upd.nis > upd.gate == pytest.approx(chi2.ppf(0.999, 6))
    assert "inconsistent with the prediction" in upd.reason
    np.testing.assert_array_equal(filt.world_from_cam, before)
    good = filt.update_pose(fix_from(truth[-1], FIX_COV, np.random.default_rng(5)), FIX_COV)
    assert good.accepted and good.nis < good.gate


def test_prediction_through_an_outage_grows_the_covariance_then_a_fix_shrinks_it():
    _, _, filt, truth = run(2, n_steps=40)
    std0 = filt.pose_std
    for _ in range(10):  # no GNSS, no fix: predict only
        filt.predict(DT, [1.0, 0.0, 0.0], [0.0, 0.0, 0.01])
    std1 = filt.pose_std
    assert np.all(std1[:3] > std0[:3])
    # position variance grows by (velocity_sigma * dt)^2 per step at least
    assert np.all(std1[:3] ** 2 >= std0[:3] ** 2 + 10 * (NOISE.velocity_sigma * DT) ** 2 - 1e-12)
    sig = filt.prior_sigmas()
    np.testing.assert_allclose(sig.position_m, std1[:3])
    W = filt.world_from_cam
    upd = filt.update_pose(invert(W), FIX_COV)
    assert upd.accepted
    assert np.all(filt.pose_std[:3] < 0.11)


def test_gnss_jump_is_gated_as_long_as_fixes_confirm_the_filter():
    _, _, filt, truth = run(3, n_steps=40)
    jump = truth[-1][:3, 3] + filt.gnss_bias + np.array([0.0, 15.0, 0.0])
    rng = np.random.default_rng(0)
    for _ in range(2 * NOISE.max_rejections):
        upd = filt.update_gnss(jump)
        assert not upd.accepted and upd.kind == "gnss"
        assert filt.update_pose(fix_from(truth[-1], FIX_COV, rng), FIX_COV).accepted
    # without fixes the jump persists beyond max_rejections: the GNSS is believed again
    ups = [filt.update_gnss(jump) for _ in range(NOISE.max_rejections + 1)]
    assert [u.accepted for u in ups] == [False] * NOISE.max_rejections + [True]


def test_bias_estimation_recovers_the_gnss_bias():
    """With a fix every step the GNSS bias state follows the true bias within its sigma."""
    rng = np.random.default_rng(11)
    truth = orbit(60)
    sensors = Sensors(rng)
    filt = PoseFilter(NOISE)
    filt.start(*sensors.read(truth[0], 0.0))
    for k in range(1, 60):
        filt.predict(DT, *motion(truth[k - 1], truth[k]))
        gnss, att = sensors.read(truth[k], DT)
        filt.update_gnss(gnss)
        filt.update_attitude(att)
        filt.update_pose(fix_from(truth[k], FIX_COV, rng), FIX_COV)
    bias_std = np.sqrt(np.diag(filt.covariance)[6:9])
    assert np.all(np.abs(filt.gnss_bias - sensors.b_g) < 4 * bias_std)
    assert np.all(bias_std < 0.25 * np.asarray(NOISE.gnss_bias_sigma))  # learned: 1/4 of its prior sigma
    att_std = np.sqrt(np.diag(filt.covariance)[9:12])
    assert np.all(np.abs(filt.attitude_bias - sensors.b_a) < 4 * att_std)


def test_seeds_reproduce():
    a = run(7, n_steps=20)
    b = run(7, n_steps=20)
    np.testing.assert_array_equal(a[2].covariance, b[2].covariance)
    np.testing.assert_array_equal(a[2].world_from_cam, b[2].world_from_cam)


def test_bad_input_is_named():
    filt = PoseFilter()
    with pytest.raises(RuntimeError, match="before start"):
        filt.predict(0.5)
    filt.start([0, 0, 10], [0, 0.5, 0])
    with pytest.raises(ValueError, match="gnss must be finite"):
        filt.update_gnss([np.nan, 0, 0])
    with pytest.raises(ValueError, match=r"covariance must have shape \(6, 6\)"):
        filt.update_pose(np.eye(4), np.eye(3))
    with pytest.raises(ValueError, match="dt"):
        filt.predict(-1.0)
    with pytest.raises(ValueError, match="gnss_bias_sigma"):
        FilterNoise(gnss_bias_sigma=(1.0, 2.0))
    with pytest.raises(TypeError, match="FilterNoise"):
        PoseFilter(noise={"velocity_sigma": 1})


def test_a_wrong_filter_recovers_through_repeated_sensor_readings():
    """A filter sure of a pose 20 deg off in yaw: attitude readings are gated, then fused."""
    truth = orbit(1)[0]
    _, att = attitude_from_world_from_cam(truth)
    wrong = world_from_cam_from_attitude(truth[:3, 3], att + [0.0, 0.0, math.radians(20)])
    filt = PoseFilter(NOISE)
    filt.reset_pose(wrong, 0.1, math.radians(0.1))
    updates = [filt.update_attitude(att) for _ in range(NOISE.max_rejections + 1)]
    assert not any(u.accepted for u in updates[:-1])
    assert updates[-1].accepted and "rejections in a row" in updates[-1].reason
    for _ in range(5):
        filt.predict(DT)
        filt.update_attitude(att)
    assert pose_errors(filt.cam_from_world, invert(truth))[1] < 3.0
