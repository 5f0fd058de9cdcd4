import pathlib

import numpy as np
import pytest

from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import invert, look_at
from localization.testing.synthetic import landmark_context, perturb_attitude, sample_viewpoints

ROOT = pathlib.Path(__file__).resolve().parents[3]


def test_perturb_attitude_matches_the_environment_convention():
    attitude = pytest.importorskip("uav_struct_env.sim.attitude")
    T = look_at([30, -5, 18], [4, 5.5, 3.4])
    dpos, datt = np.array([3.0, -3.0, 3.0]), np.radians([2.0, -2.0, 5.0])
    pos, att = attitude.attitude_from_world_from_cam(invert(T))
    expected = invert(attitude.world_from_cam_from_attitude(pos + dpos, att + datt))
    np.testing.assert_allclose(perturb_attitude(T, dpos, datt), expected, atol=1e-12)


def test_viewpoints_follow_the_protocol():
    views = sample_viewpoints(np.random.default_rng(0), 40, [4.0, 5.5, 3.4])
    for k, T in enumerate(views):
        C = invert(T)[:3, 3]
        assert 15 <= np.hypot(C[0] - 4, C[1] - 5.5) <= 35 and 10 <= C[2] <= 25
        side = int(np.round(np.arctan2(C[1] - 5.5, C[0] - 4) / (np.pi / 2) + 1)) % 4
        assert side == k % 4


def test_landmark_context_layout():
    T = look_at([4, -20, 18], [4, 5.5, 3.4])
    X = np.array([[0.0, 0, 0], [4, 0, 0], [0, 100, 0]])
    ctx = landmark_context(PAPER_K, T, {"s": (np.array([7, 8, 9]), X)})
    g = ctx["landmarks"]["s"]
    assert set(g) == {"ids", "xyz", "uv", "in_frame", "visible"}
    assert g["in_frame"].tolist() == [True, True, False]


def test_benchmark_smoke(capsys, load_script):
    pytest.importorskip("uav_struct_env.site")
    out = load_script(ROOT / "benchmarks" / "localizer.py").main(images=4, aruco_images=1, seed=0)
    assert "column_tops/miss10+fp1/robust" in out["structural"]
    assert "Cramér-Rao" in capsys.readouterr().out


def test_package_is_pure():
    """localization imports neither the environment, pybullet nor gymnasium."""
    import subprocess
    import sys

    code = (
        "import sys, localization, localization.aruco, localization.testing.synthetic; "
        "bad = [m for m in sys.modules if m.split('.')[0] in "
        "('uav_struct_env', 'pybullet', 'gymnasium', 'pettingzoo')]; print(bad)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
