"""Procedural textures: seeded, non-repeating, plausible colours; crisp ArUco sheets."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from uav_struct_env.site import ArucoMarker
from uav_struct_env.site.textures import (
    aruco_texture,
    clear_texture_memo,
    concrete_texture,
    fractal_noise,
    ground_texture,
    texture_memo,
    value_noise,
)


def test_value_noise_is_smooth_and_bounded(rng):
    n = value_noise(rng, 256, cells=8)
    assert n.shape == (256, 256) and n.dtype == np.float32
    assert -1.0 <= n.min() and n.max() <= 1.0
    assert np.abs(np.diff(n, axis=1)).max() < 0.2  # no jumps between neighbours


def test_fractal_noise_is_normalised_and_does_not_repeat(rng):
    n = fractal_noise(rng, 256, extent=8.0, feature=1.0)
    assert abs(float(n.mean())) < 1e-4 and float(n.std()) == pytest.approx(1.0, rel=1e-4)
    # Non-repeating: no shift by a whole number of lattice periods reproduces the texture.
    for shift in (32, 64, 128):
        assert np.corrcoef(n[:, :-shift].ravel(), n[:, shift:].ravel())[0, 1] < 0.5


def test_concrete_is_grey_and_seeded():
    a = concrete_texture(np.random.default_rng(5), 128, 3.0)
    b = concrete_texture(np.random.default_rng(5), 128, 3.0)
    c = concrete_texture(np.random.default_rng(6), 128, 3.0)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.shape == (128, 128, 3) and a.dtype == np.uint8
    mean = a.reshape(-1, 3).mean(axis=0)
    assert 100 < mean.mean() < 190 and np.ptp(mean) < 20  # mid grey, barely tinted
    assert a.std() > 5  # has variation


def test_ground_is_browner_and_darker_than_concrete(rng):
    g = ground_texture(rng, 128, 40.0).reshape(-1, 3).mean(axis=0)
    c = concrete_texture(rng, 128, 3.0).reshape(-1, 3).mean(axis=0)
    assert g[0] > g[2] + 8  # red above blue: soil brown
    assert g.mean() < c.mean() + 5


@pytest.mark.parametrize("marker_id", [0, 7, 49])
def test_aruco_texture_detects_with_quiet_zone_and_corner_order(marker_id):
    marker = ArucoMarker(id=marker_id, side=1.0, center=(0.0, 0.0, 0.01), quiet_zone=0.25)
    tex = aruco_texture(marker, module_px=10)
    assert tex.shape == (90, 90, 3)  # 6 modules + 1.5 modules quiet zone each side
    quiet = 15
    assert (tex[:quiet] == 255).all() and (tex[:, -quiet:] == 255).all()
    assert set(np.unique(tex).tolist()) == {0, 255}  # crisp: two levels only
    detector = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), cv2.aruco.DetectorParameters()
    )
    corners, ids, _ = detector.detectMarkers(cv2.cvtColor(tex, cv2.COLOR_RGB2GRAY))
    assert ids is not None and ids.ravel().tolist() == [marker_id]
    # OpenCV order: top-left, top-right, bottom-right, bottom-left of the image.
    lo, hi = quiet - 0.5, 90 - quiet - 0.5
    expected = np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]])
    np.testing.assert_allclose(corners[0].reshape(4, 2), expected, atol=1.0)


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda: value_noise(np.random.default_rng(0), 1, 4), ValueError, "texture size"),
        (lambda: value_noise(0, 16, 4), TypeError, "rng must be"),
        (lambda: value_noise(np.random.default_rng(0), 16, 0), ValueError, "cells"),
        (lambda: fractal_noise(np.random.default_rng(0), 16, -1.0, 1.0), ValueError, "extent"),
        (lambda: aruco_texture(ArucoMarker(0, 1.0, (0, 0, 0)), 0), ValueError, "module_px"),
    ],
)
def test_bad_arguments_raise(call, error, match):
    with pytest.raises(error, match=match):
        call()


@pytest.mark.parametrize("draw", [lambda r: concrete_texture(r, 128, 2.0),
                                  lambda r: ground_texture(r, 256, 30.0)])
def test_a_repeated_draw_is_the_same_texture_and_leaves_the_generator_where_drawing_would(draw):
    clear_texture_memo()
    first_rng, again_rng = np.random.default_rng(11), np.random.default_rng(11)
    first = draw(first_rng)  # drawn, and memoized
    again = draw(again_rng)  # replayed
    assert texture_memo() == (1, first.nbytes) and np.array_equal(first, again)
    assert first_rng.uniform() == again_rng.uniform()  # the generators go on alike
    again[:] = 0  # a caller's copy: the memo keeps its own
    assert np.array_equal(draw(np.random.default_rng(11)), first)
    assert not np.array_equal(draw(np.random.default_rng(12)), first)  # another state, another texture
