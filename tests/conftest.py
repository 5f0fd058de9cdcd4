"""Shared fixtures: a seeded ``rng`` (every test that needs randomness takes it from here),
``load_script`` (a script of ``benchmarks/`` or ``examples/`` as a module) and ``shared_output``
(an expensive run made once per test session, however many pytest-xdist workers read it).

Before any test, each process that runs tests compiles (or loads from numba's cache) the
compiled kernels, one group at a time under a file lock (:func:`pytest_sessionstart`): on a fresh
clone the localization kernels (about 50 s of CPU, in two groups: the pose kernels and the rest)
and the simulator's (about 20 s) are then compiled once, by two workers side by side, instead of by
every worker and every subprocess that reaches them first (74 s of the fresh-clone run's wall time
before; 47 s with the localization kernels in one group, 40 s now); once cached, the warm-ups cost
about 2 s a session."""

from __future__ import annotations

import fcntl
import hashlib
import importlib.util
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _warm_localization() -> None:
    from localization.warmup import warm_up

    warm_up(announce=None)


def _warm_simulator() -> None:
    """The batched rasterizer, the landmark visibility and the ray casts: one step of a small
    training env (batched renderer) and of the default env, each with rendered and with ray-cast
    truth; the training configurations' layout features."""
    import uav_struct_env
    from uav_struct_env.wrappers.layout import _centroid_spread

    _centroid_spread(np.array([[1.0, 2.0], [3.0, 5.0]]), 640.0, 360.0)
    for settings in ({"preset": "train", "renderer": "batch"}, {}):  # the training and the default env
        for observe_image in (True, False):  # rendered truth, then ray-cast truth
            env = uav_struct_env.parallel_env(**settings, image_size=(64, 36), observe_image=observe_image)
            try:
                env.reset(seed=0)
                env.step({a: np.zeros(env.action_space(a).shape, np.float32) for a in env.agents})
            finally:
                env.close()


def _warm_pose() -> None:
    """The pose kernels (PnP refinement, the pose's finish and covariance) through the paper
    association, which compiles none of the robust association's: the localization group, run
    beside it, then loads them from the cache when its first robust localization reaches them."""
    from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
    from localization.geometry.transforms import look_at, project
    from localization.pipeline import Localizer
    from localization.testing.synthetic import paper_prior

    rng = np.random.default_rng(0)
    truth = look_at([4.0, -20.0, 15.0], [4.0, 5.5, 4.0])
    tops = np.array([[x, y, 7.0] for x in (0.0, 4.0, 8.0) for y in (0.0, 4.0, 7.0, 11.0)])
    slab = np.array([[-0.3, -0.3, 3.5], [8.3, -0.3, 3.5], [8.3, 11.3, 3.5], [-0.3, 11.3, 3.5]])
    for landmarks in (tops, slab):
        uv, _ = project(PAPER_K, truth, landmarks)
        Localizer(landmarks, PAPER_K, association="paper", image_size=PAPER_IMAGE_SIZE).localize(
            uv + rng.normal(0.0, 1.0, uv.shape), paper_prior(truth, 0))


KERNEL_GROUPS: dict[str, Callable[[], None]] = {"localization": _warm_localization,
                                                "simulator": _warm_simulator, "pose": _warm_pose}


def pytest_sessionstart(session) -> None:
    """Compile or load every kernel group before the first test, each group by one process at a time.

    pytest-xdist's controller runs no test and skips this; worker ``gw<i>`` takes the groups in an
    order of its own (odd workers reversed): on a fresh clone one compiles the localization kernels
    (about 38 s) while the other compiles the pose kernels those reach (14 s, so the first finds
    them cached) and the simulator's (21 s), and each then loads the other's from the cache.
    """
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker is None and getattr(session.config.option, "numprocesses", None):
        return
    order = ["localization", "simulator", "pose"]
    if worker is not None and int(worker.removeprefix("gw") or 0) % 2:
        order.reverse()
    tag = hashlib.sha1(str(ROOT).encode()).hexdigest()[:12]  # a lock per checkout: its cache is beside it
    for name in order:
        with open(Path(tempfile.gettempdir()) / f"uav-struct-kernels-{tag}-{name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
            KERNEL_GROUPS[name]()


@pytest.fixture
def rng() -> np.random.Generator:
    """A generator seeded identically for every test, so failures reproduce."""
    return np.random.default_rng(20240611)


@pytest.fixture(scope="session")
def load_script() -> Callable[[Path], ModuleType]:
    """``load(path)``: the script at ``path`` as a fresh module, loaded as running it would
    (its folder first on ``sys.path``, so that it finds its sibling modules)."""

    def load(path: Path) -> ModuleType:
        path = Path(path)
        if str(path.parent) not in sys.path:
            sys.path.insert(0, str(path.parent))
        spec = importlib.util.spec_from_file_location(path.stem, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load


@pytest.fixture(scope="session")
def shared_output(tmp_path_factory) -> Callable[[str, Callable[[Path], Any]], tuple[Path, Any]]:
    """``shared_output(name, make)``: ``(folder, value)`` of ``value = make(folder)``, run once.

    Once per test session, not once per module and worker: under pytest-xdist the first worker to
    ask runs ``make`` under a file lock in the session's shared temporary folder, and the others
    wait for it and read the same folder (and ``value``, pickled). Tests only read the folder.
    """
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the session's folder, above each worker's own

    def get(name: str, make: Callable[[Path], Any]) -> tuple[Path, Any]:
        folder, value = root / f"shared-{name}", root / f"shared-{name}.pkl"
        with open(root / f"shared-{name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
            if not value.exists():
                shutil.rmtree(folder, ignore_errors=True)  # a failed attempt's leftovers
                folder.mkdir()
                made = make(folder)
                value.write_bytes(pickle.dumps(made))
            return folder, pickle.loads(value.read_bytes())

    return get


def _quick_projection_study(folder: Path) -> tuple[Path, str]:
    out = folder / "study"
    proc = subprocess.run(
        [sys.executable, "-m", "uav_struct_env.study", "--quick", "--detector", "projection", "--out",
         str(out), "--no-progress"],
        capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, proc.stdout


@pytest.fixture(scope="session")
def quick_projection_study(shared_output) -> tuple[Path, str]:
    """``(out, stdout)`` of ``uav-struct study --quick --detector projection``, run once a session."""
    return shared_output("quick-projection-study", _quick_projection_study)[1]


#: The tiny landmark dataset's arguments: one random site, two views, a quarter of 1280 x 720.
TINY_DATASET = ["--layouts", "1", "--views", "2", "--seed", "7", "--scale", "0.25"]


def _tiny_landmark_dataset(folder: Path) -> Path:
    from uav_struct_env.datasets.__main__ import main as make_dataset

    assert make_dataset([str(folder / "data"), *TINY_DATASET]) == 0
    return folder / "data"


@pytest.fixture(scope="session")
def tiny_landmark_dataset(shared_output) -> Path:
    """``python -m uav_struct_env.datasets DIR`` + :data:`TINY_DATASET`, once a session (read only)."""
    return shared_output("tiny-landmark-dataset", _tiny_landmark_dataset)[1]


def _tiny_ppo_run(folder: Path, load_script) -> tuple[Path, dict]:
    train = load_script(Path(__file__).resolve().parents[1] / "examples" / "train_viewpoint_ppo.py")
    out = folder / "ppo"
    summary = train.main(out=str(out), total_timesteps=256, n_envs=1, num_cpus=0, n_steps=32,
                         batch_size=64, n_epochs=1, max_cycles=8, checkpoint_every=128,
                         progress_bar=False, seed=3)
    return out, summary


@pytest.fixture(scope="session")
def tiny_ppo_run(shared_output, load_script) -> tuple[Path, dict]:
    """``(out, summary)`` of a 256-agent-step PPO training run (seed 3), run once a session."""
    pytest.importorskip("stable_baselines3")
    return shared_output("tiny-ppo-run", lambda folder: _tiny_ppo_run(folder, load_script))[1]
