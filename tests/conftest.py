"""Shared fixtures: a seeded ``rng`` (every test that needs randomness takes it from here),
``load_script`` (a script of ``benchmarks/`` or ``examples/`` as a module) and ``shared_output``
(an expensive run made once per test session, however many pytest-xdist workers read it).

The compiled kernels (numba, cached on disk beside the package) are compiled once a session, by
one process per group (:func:`pytest_sessionstart`): on a fresh clone the localization kernels
(about 45 s of CPU) and the simulator's (about 20 s) compile in two processes of their own while
the pytest-xdist workers run the tests that need neither; a worker that reaches a kernel, or starts
a child process that may, first waits for them and then loads the kernels from the cache. Before,
every worker compiled or loaded both groups before its first test (and before that, every worker
and subprocess compiled what it reached first: 74 s of the fresh-clone run's wall time). Once
cached, loading the groups costs about 2 s a session."""

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


KERNEL_GROUPS: dict[str, Callable[[], None]] = {"localization": _warm_localization,
                                                "simulator": _warm_simulator}


def _lock_path(name: str) -> Path:
    tag = hashlib.sha1(str(ROOT).encode()).hexdigest()[:12]  # a lock per checkout: its cache is beside it
    return Path(tempfile.gettempdir()) / f"uav-struct-kernels-{tag}-{name}.lock"


def _compile_group(name: str) -> None:
    """Compile (or load) one kernel group holding its lock; ``python tests/conftest.py GROUP``."""
    with open(_lock_path(name), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        print("locked", flush=True)
        os.dup2(os.open(os.devnull, os.O_WRONLY), 1)  # pybullet's banner; a failure still shows (stderr)
        KERNEL_GROUPS[name]()


def pytest_sessionstart(session) -> None:
    """Compile or load every kernel group once, beside the tests rather than before them.

    Under pytest-xdist the controller (which runs no test) starts one compiler process per group,
    each holding its group's lock, before the workers exist; a worker waits for them only when it
    first reaches a compiled kernel or starts a child process (:func:`_wait_for_compilers`), so the
    tests that need neither run meanwhile. Without xdist the groups compile here, one by one.
    """
    if os.environ.get("PYTEST_XDIST_WORKER") is not None:
        _wait_for_compilers.install()
        return
    if not getattr(session.config.option, "numprocesses", None):
        for name in KERNEL_GROUPS:
            with open(_lock_path(name), "w") as lock:
                fcntl.flock(lock, fcntl.LOCK_EX)
                KERNEL_GROUPS[name]()
        return
    compilers = []
    for name in KERNEL_GROUPS:
        proc = subprocess.Popen([sys.executable, __file__, name], cwd=ROOT, stdout=subprocess.PIPE,
                                text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
        if proc.stdout.readline().strip() != "locked":  # it failed: the tests compile what they need
            proc.wait()
        compilers.append(proc)
    session.config.stash[_COMPILERS] = compilers


def pytest_sessionfinish(session) -> None:
    for proc in session.config.stash.get(_COMPILERS, []):
        proc.wait()


_COMPILERS = pytest.StashKey[list]()

#: Test modules that reach no compiled kernel, in their own process or a child (each checked alone
#: with a fresh kernel cache): they run first, while the kernel groups compile, and their child
#: processes (ruff, mkdocs, ``--help``) do not wait for the compilers. A module missing here only
#: runs later; one listed wrongly only waits at its first kernel (tests/test_conftest.py keeps the
#: list to existing files).
KERNEL_FREE = (
    "tests/site/test_activity.py", "tests/site/test_ifc_any_building.py", "tests/site/test_ifc_cache.py",
    "tests/site/test_ifc_damaged.py", "tests/site/test_ifc_markers.py", "tests/site/test_imports.py",
    "tests/site/test_mesh.py", "tests/site/test_model.py", "tests/site/test_site_files.py",
    "tests/site/test_textures.py", "tests/photos/test_calibration.py", "tests/photos/test_georef.py",
    "tests/photos/test_metadata.py", "tests/photos/test_real_dji_headers.py",
    "tests/training/test_ensemble.py", "tests/training/test_jpeg_augment.py", "tests/test_code_shape.py",
    "tests/test_layers.py", "tests/localization/test_stats.py", "tests/test_outputs.py",
    "tests/test_doc_numbers.py", "tests/localization/detect/test_weights.py",
    "tests/test_benchmark_help.py", "tests/sim/test_imaging_names.py", "tests/site/test_ifc_speed.py",
    "tests/test_docs.py::test_docs_site_builds_in_strict_mode",
)


def _kernel_free(item: pytest.Item) -> bool:
    return item.nodeid.split("::")[0] in KERNEL_FREE or item.nodeid.split("[")[0] in KERNEL_FREE


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The kernel-free tests first (a stable sort: otherwise the collection's order)."""
    items.sort(key=lambda item: not _kernel_free(item))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem):
    _wait_for_compilers.skip_children = _kernel_free(item)
    try:
        return (yield)
    finally:
        _wait_for_compilers.skip_children = False


class _CompilerWait:
    """Until the compiler processes are done, the first kernel compilation and the first child
    process of a worker wait for them (then load the kernels from numba's cache instead of
    compiling a second copy); after that wait, nothing is patched any more. The children of a
    kernel-free test (:data:`KERNEL_FREE`) start without waiting."""

    def __init__(self) -> None:
        self._saved: list[tuple[object, str, Callable]] = []
        self.skip_children = False

    def install(self) -> None:
        import multiprocessing.process

        from numba.core.dispatcher import Dispatcher

        for owner, attr, child in ((Dispatcher, "compile", False), (subprocess.Popen, "__init__", True),
                                   (multiprocessing.process.BaseProcess, "start", True)):
            original = getattr(owner, attr)
            self._saved.append((owner, attr, original))
            setattr(owner, attr, self._waiting(original, child))

    def _waiting(self, original: Callable, child: bool) -> Callable:
        def call(*args, **kwargs):
            if not (child and self.skip_children):
                self.wait()
            return original(*args, **kwargs)

        return call

    def wait(self) -> None:
        saved, self._saved = self._saved, []
        for owner, attr, original in saved:
            setattr(owner, attr, original)
        for name in KERNEL_GROUPS:
            with open(_lock_path(name), "w") as lock:
                fcntl.flock(lock, fcntl.LOCK_SH)


_wait_for_compilers = _CompilerWait()


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


if __name__ == "__main__":
    _compile_group(sys.argv[1])
