"""The scalar validator, failure codes, image-size inference and array dataclasses' equality."""

import math

import numpy as np
import pytest

from localization import (
    Detections,
    FailureCode,
    Localizer,
    check_choice,
    check_number,
    image_size_from_K,
)
from localization.aruco import MarkerSpec
from localization.associate.paper import Association
from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import check_transform, matrix_from_quat_wxyz, project
from localization.pose.pnp import PnPResult
from localization.testing.synthetic import paper_prior, sample_viewpoints


def test_check_number_returns_typed_values_and_names_bad_ones():
    assert check_number("x", 3, 0.0) == 3.0 and isinstance(check_number("x", 3, 0.0), float)
    assert check_number("n", np.int64(4), 1, integer=True) == 4
    with pytest.raises(ValueError, match=r"threads must be an int >= 1, got 0"):
        check_number("threads", 0, 1, integer=True)
    with pytest.raises(TypeError, match="n must be an int, got 2.5"):
        check_number("n", 2.5, integer=True)
    with pytest.raises(TypeError, match="flag must be a number, got True"):
        check_number("flag", True)
    with pytest.raises(ValueError, match=r"p must be a number in \(0, 1\], got 0"):
        check_number("p", 0, 0.0, 1.0, lo_open=True)
    with pytest.raises(ValueError, match="s must be finite and > 0, got nan"):
        check_number("s", math.nan, 0.0, lo_open=True)
    with pytest.raises(ValueError, match="s must be finite, got inf"):
        check_number("s", math.inf)
    assert check_number("s", math.inf, 0.0, finite=False) == math.inf

    class Mine(ValueError):
        pass

    with pytest.raises(Mine, match="r must be finite and <= 2"):
        check_number("r", 3, hi=2, error=Mine)


def test_check_choice():
    assert check_choice("mode", "paper", ("paper", "robust")) == "paper"
    with pytest.raises(ValueError, match=r"mode must be one of \('paper', 'robust'\), got 'x'"):
        check_choice("mode", "x", ("paper", "robust"))
    with pytest.raises(TypeError, match="mode must be one of"):
        check_choice("mode", 3, ("paper", "robust"), type_error=TypeError)


def test_image_size_from_K_exact_for_paper_and_scaled_cameras():
    assert image_size_from_K(PAPER_K) == (1280, 720)
    for w, h in ((128, 72), (64, 36), (640, 360), (256, 144)):
        sx, sy = w / 1280, h / 720
        K = np.array([[1108.5 * sx, 0, 640.5 * sx - 0.5], [0, 1108.5 * sy, 360.5 * sy - 0.5], [0, 0, 1]])
        assert image_size_from_K(K) == (w, h)
        assert Localizer(np.eye(3) * 5, K).image_size == (w, h)
    assert Localizer(np.eye(3) * 5, PAPER_K, image_size=(1000, 700)).image_size == (1000, 700)
    with pytest.raises(ValueError, match="image_size"):
        Localizer(np.eye(3) * 5, PAPER_K, image_size=(0, 700))


def test_failures_carry_a_code_and_a_message():
    X = np.random.default_rng(0).uniform(-5, 5, (8, 3))
    loc = Localizer(X, PAPER_K)
    est = loc.localize(np.zeros((2, 2)), np.eye(4))
    assert not est.success
    assert est.failure_code is FailureCode.TOO_FEW_DETECTIONS
    assert est.failure_reason == "too few detections: 2 usable (finite) detections, need 4"
    assert FailureCode(est.failure_code.value) is FailureCode.TOO_FEW_DETECTIONS
    T = sample_viewpoints(np.random.default_rng(1), 1, X.mean(axis=0))[0]
    uv, _ = project(PAPER_K, T, X)
    ok = loc.localize(uv, paper_prior(T, 0))
    assert ok.success and ok.failure_code is None and ok.failure_reason is None


def test_equality_of_array_dataclasses_is_identity_and_never_raises():
    a = np.zeros((3, 2))
    for make in (
        lambda: Detections(a),
        lambda: Association(np.zeros(3, np.int64), np.eye(4), 0.0, 0.0),
        lambda: PnPResult(True, np.eye(4), 0.0, np.ones(3, bool)),
        lambda: MarkerSpec(1, 0.5, np.eye(4)),
    ):
        x, y = make(), make()
        assert x == x and not (x == y) and x != y
    est = Localizer(np.eye(3) * 5, PAPER_K).localize(np.zeros((0, 2)), np.eye(4))
    assert est == est and est != Localizer(np.eye(3) * 5, PAPER_K).localize(np.zeros((0, 2)), np.eye(4))


def _allclose_reference(T: np.ndarray) -> bool:
    """check_transform's tests written with np.allclose / np.linalg.det, the reference it must match."""
    R = T[:3, :3]
    return bool(np.all(np.isfinite(T)) and np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9)
                and np.allclose(R.T @ R, np.eye(3), atol=1e-6) and np.linalg.det(R) >= 0)


def test_check_transform_names_each_fault_and_agrees_with_allclose_off_the_boundary():
    rng = np.random.default_rng(7)
    good = np.eye(4)
    good[:3, 3] = [1.0, -2.0, 30.0]
    assert check_transform("T", good) is good  # float64 input: no copy
    assert check_transform("T", good.astype(np.float32)).dtype == np.float64
    assert check_transform("T", np.asfortranarray(good)).shape == (4, 4)
    assert check_transform("T", good.tolist()).shape == (4, 4)
    off_row = good.copy()
    off_row[3, 2] = 2e-9
    cases = {
        r"T must be finite, got \[\[nan": np.where(np.eye(4, dtype=bool), np.nan, good),
        r"T last row must be \[0, 0, 0, 1\], got \[0.0, 0.0, 2e-09, 1.0\]": off_row,
        r"T rotation block must be a proper rotation, got \[\[1.0, 0.0, 0.0\]": np.diag([1.0, 1, -1, 1]),
    }
    for message, T in cases.items():
        with pytest.raises(ValueError, match=message):
            check_transform("T", T)
    with pytest.raises(ValueError, match=r"T must have shape \(4, 4\), got \(3, 4\)"):
        check_transform("T", good[:3])
    with pytest.raises(TypeError, match="T must be a numeric 4x4 array, got dtype object"):
        check_transform("T", np.full((4, 4), None))
    with pytest.raises(TypeError, match="got dtype bool"):
        check_transform("T", np.eye(4, dtype=bool))
    # random rotations perturbed on both sides of the tolerances (1e-6 on R^T R, 1e-9 on the last row)
    verdicts = []
    for _ in range(400):
        T = np.eye(4)
        noise = rng.choice([1e-7, 1e-6, 1e-5]) * rng.normal(size=(3, 3))
        T[:3, :3] = matrix_from_quat_wxyz(rng.normal(size=4)) + noise
        T[:3, 3] = rng.normal(0, 50, 3)
        T[3, :3] = rng.choice([0.0, 3e-10, 3e-9]) * rng.normal(size=3)
        if rng.random() < 0.2:
            T[:3, 0] *= -1  # a reflection
        try:
            check_transform("T", T)
            accepted = True
        except ValueError:
            accepted = False
        assert accepted == _allclose_reference(T)
        verdicts.append(accepted)
    assert 0.1 < np.mean(verdicts) < 0.9  # both sides of the boundary were tried


def test_as_floats_passes_float_tuples_through_converts_the_rest_and_names_a_bad_size():
    from localization.checks import as_floats

    t = (1.0, 2.5, -3.0)
    assert as_floats("p", t, 3) is t
    got = as_floats("p", np.array([1, 2, 3], dtype=np.int32), 3)
    assert got == (1.0, 2.0, 3.0) and all(type(v) is float for v in got)
    assert as_floats("c", [np.float64(0.5), 2], 2) == (0.5, 2.0)
    with pytest.raises(ValueError, match=r"center_xy must hold 2 numbers"):
        as_floats("center_xy", [1.0, 2.0, 3.0], 2)
