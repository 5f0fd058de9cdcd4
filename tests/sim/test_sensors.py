import math

import numpy as np
import pytest

from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.sensors import (
    DegradedGnssNoise,
    GnssInsNoise,
    NoNoise,
    PaperNoise,
    Reading,
    make_noise,
)

POS = np.array([10.0, -20.0, 15.0])
ATT = np.array([0.0, 0.4, 1.0])


def reading(i=0, k=0, clearance=math.inf, dt=0.0, att=ATT):
    return Reading(i, k, POS, att, clearance, dt)


def test_paper_noise_magnitudes_and_documented_sign_pattern():
    m = PaperNoise()
    rng = np.random.default_rng(0)
    gnss, att = m.measure(m.start(rng, 4), rng, reading(0, 0))
    np.testing.assert_allclose(gnss - POS, [3, -3, 3])
    np.testing.assert_allclose(np.degrees(att - ATT), [2, -2, 5])
    for i in range(4):
        for k in range(10):
            g, a = m.measure(None, rng, reading(i, k))
            s = (-1) ** (i + k)
            np.testing.assert_allclose(g - POS, s * np.array([3, -3, 3]))
            np.testing.assert_allclose(np.degrees(a - ATT), s * np.array([2, -2, 5]))


def test_paper_noise_signs_balance_over_the_study_and_draw_nothing():
    m = PaperNoise()
    signs = [m.sign(i, k) for i in range(4) for k in range(10)]
    assert sum(signs) == 0
    rng = np.random.default_rng(5)
    before = rng.bit_generator.state
    m.measure(None, rng, reading(1, 3))
    assert rng.bit_generator.state == before


def test_angles_are_wrapped():
    m = PaperNoise()
    _, att = m.measure(
        None, np.random.default_rng(0), reading(0, 0, att=np.array([0.0, 0.0, math.pi - 0.01]))
    )
    assert -math.pi <= att[2] < math.pi


def test_gnss_ins_statistics_match_parameters():
    m = GnssInsNoise()
    rng = np.random.default_rng(1)
    n = 4000
    state = m.start(rng, n)
    errs = np.array([m.measure(state, rng, reading(i))[0] - POS for i in range(n)])
    expected = np.hypot(m.gnss_bias_sigma, m.gnss_white_sigma)
    np.testing.assert_allclose(errs.std(axis=0), expected, rtol=0.06)
    atts = np.array([m.measure(state, rng, reading(i))[1] - ATT for i in range(n)])
    np.testing.assert_allclose(
        atts.std(axis=0), np.hypot(m.attitude_bias_sigma, m.attitude_white_sigma), rtol=0.06
    )


def test_gnss_ins_bias_drifts_slowly_and_is_stationary():
    m = GnssInsNoise(gnss_white_sigma=(0, 0, 0), near_structure_gain=0.0)
    rng = np.random.default_rng(2)
    state = m.start(rng, 1)
    series = np.array([m.measure(state, rng, reading(0, dt=0.5))[0] - POS for _ in range(20000)])
    # consecutive readings 0.5 s apart are almost equal (tau = 120 s)...
    lag1 = np.corrcoef(series[:-1, 0], series[1:, 0])[0, 1]
    assert lag1 == pytest.approx(math.exp(-0.5 / 120), abs=0.01)
    # ...and the process keeps its stationary sigma
    assert series[:, 0].std() == pytest.approx(m.gnss_bias_sigma[0], rel=0.3)


def test_gnss_ins_error_grows_near_the_structure():
    m = GnssInsNoise()
    assert m.multipath_factor(0.0) == pytest.approx(3.0)
    assert m.multipath_factor(1e9) == pytest.approx(1.0)
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    sa, sb = m.start(rng_a, 1), m.start(rng_b, 1)
    far = m.measure(sa, rng_a, reading(clearance=1e9))[0] - POS
    near = m.measure(sb, rng_b, reading(clearance=0.0))[0] - POS
    np.testing.assert_allclose(near, 3.0 * far)


def test_seeded_generator_reproduces_readings():
    m = GnssInsNoise()
    out = []
    for _ in range(2):
        rng = np.random.default_rng(7)
        st = m.start(rng, 2)
        out.append([m.measure(st, rng, reading(i % 2, dt=0.5)) for i in range(10)])
    for (g1, a1), (g2, a2) in zip(*out, strict=True):
        assert np.array_equal(g1, g2) and np.array_equal(a1, a2)


def test_make_noise():
    assert isinstance(make_noise("paper"), PaperNoise)
    assert isinstance(make_noise("gnss_ins"), GnssInsNoise)
    assert isinstance(make_noise("none"), NoNoise)
    custom = PaperNoise(position_offset=1.0)
    assert make_noise(custom) is custom
    with pytest.raises(ConfigError, match="'gps'"):
        make_noise("gps")
    with pytest.raises(ConfigError, match="gnss_bias_sigma"):
        GnssInsNoise(gnss_bias_sigma=(1.0, -1.0, 1.0))
    with pytest.raises(ConfigError, match="position_pattern"):
        PaperNoise(position_pattern=(1, 2, 1))


def _series(model, clearance, n=2000, dt=0.5, seed=3):
    rng = np.random.default_rng(seed)
    st = model.start(rng, 1)
    first = model.measure(st, rng, reading(clearance=clearance, dt=0.0))[0]
    return first, np.array([model.measure(st, rng, reading(clearance=clearance, dt=dt))[0] for _ in range(n)])


def test_degraded_gnss_has_no_fix_close_to_the_structure_but_one_at_reset():
    m = DegradedGnssNoise()
    first, g = _series(m, clearance=m.outage_clearance - 0.5, n=20)
    assert np.all(np.isfinite(first))
    assert np.all(np.isnan(g))


def test_degraded_gnss_outage_schedule_matches_its_rates():
    """Far from the structure: outages only, a share of rate * duration / (1 + rate * duration)."""
    m = DegradedGnssNoise(outage_rate=1 / 30, outage_duration=6.0)
    _, g = _series(m, clearance=100.0, n=8000)
    out = np.isnan(g[:, 0])
    expected = (6.0 / 30) / (1 + 6.0 / 30)
    assert abs(out.mean() - expected) < 0.05, out.mean()
    starts = np.sum(out[1:] & ~out[:-1])
    assert 0.5 * 8000 * 0.5 / 30 < starts < 8000 * 0.5 / 30
    base = GnssInsNoise()
    # no jumps out there: the fixes are the base model's (multipath factor 1 at 100 m)
    err = g[~out] - POS
    assert np.all(np.abs(err) < 6 * np.hypot(base.gnss_bias_sigma, base.gnss_white_sigma) * 1.01)


def test_degraded_gnss_jumps_near_the_structure():
    m = DegradedGnssNoise(outage_rate=0.0, jump_rate=1 / 10, jump_duration=5.0, jump_sigma=(20.0, 20.0, 0.0))
    _, g = _series(m, clearance=m.jump_clearance - 1.0, n=4000)
    assert np.all(np.isfinite(g))
    horizontal = np.linalg.norm(g[:, :2] - POS[:2], axis=1)
    share = np.mean(horizontal > 15.0)  # the base model's horizontal error stays far below 15 m
    in_jump = 0.5 / (1 + 0.5)
    assert 0.5 * in_jump < share < in_jump
    _, far = _series(m, clearance=m.jump_clearance + 1.0, n=4000)
    assert np.mean(np.linalg.norm(far[:, :2] - POS[:2], axis=1) > 15.0) < 0.01


def test_degraded_gnss_reproduces_and_validates():
    m = DegradedGnssNoise()
    a = _series(m, clearance=8.0, n=200, seed=5)[1]
    b = _series(m, clearance=8.0, n=200, seed=5)[1]
    np.testing.assert_array_equal(a, b)
    assert isinstance(make_noise("gnss_degraded"), DegradedGnssNoise)
    with pytest.raises(ConfigError, match="jump_sigma"):
        DegradedGnssNoise(jump_sigma=(1.0, 2.0))
    with pytest.raises(ConfigError, match="outage_duration"):
        DegradedGnssNoise(outage_duration=0.0)


def test_every_sensor_model_names_the_filter_noise_that_matches_it():
    from localization.temporal import FilterNoise
    from uav_struct_env.wrappers.temporal import filter_noise_for

    ins = GnssInsNoise(gnss_bias_tau=60.0)
    assert ins.filter_noise() == FilterNoise(
        gnss_white_sigma=ins.gnss_white_sigma, gnss_bias_sigma=ins.gnss_bias_sigma, gnss_bias_tau=60.0,
        attitude_white_sigma=ins.attitude_white_sigma, attitude_bias_sigma=ins.attitude_bias_sigma,
    )
    assert DegradedGnssNoise(base=ins).filter_noise() == ins.filter_noise()  # jumps: the GNSS gate's
    paper = PaperNoise().filter_noise()
    assert paper.gnss_bias_sigma == (3.0,) * 3 and paper.gnss_bias_tau == 1.0e6
    assert paper.attitude_bias_sigma == tuple(math.radians(d) for d in (2.0, 2.0, 5.0))
    assert paper.gnss_white_sigma == (0.05,) * 3 and paper.attitude_white_sigma == (math.radians(0.05),) * 3
    none = NoNoise().filter_noise()
    assert not none.estimate_gnss_bias and not none.estimate_attitude_bias
    assert none.gnss_bias_sigma == (0.0,) * 3 and none.gnss_white_sigma == (0.05,) * 3
    for model in (ins, PaperNoise(), NoNoise()):
        assert filter_noise_for(model) == model.filter_noise()
    assert filter_noise_for(object()) == FilterNoise()  # a model that names none: the defaults
