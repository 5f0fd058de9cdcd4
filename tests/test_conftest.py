"""The test session's own machinery (tests/conftest.py): the kernel compilers and their waits."""

import subprocess
import sys
import threading
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

HOLD = ("import fcntl, sys\n"
        "lock = open(sys.argv[1], 'w'); fcntl.flock(lock, fcntl.LOCK_EX)\n"
        "print('locked', flush=True); sys.stdin.readline()\n")


@pytest.fixture
def conftest(request):
    """tests/conftest.py as pytest loaded it (other folders' conftest modules share its name)."""
    path = Path(__file__).with_name("conftest.py")
    return next(p for p in request.config.pluginmanager.get_plugins()
                if getattr(p, "__file__", None) and Path(p.__file__) == path)


def test_every_kernel_free_entry_names_a_collected_module_or_test(conftest):
    for entry in conftest.KERNEL_FREE:
        path, _, name = entry.partition("::")
        assert (ROOT / path).is_file(), entry
        if name:
            assert f"def {name}(" in (ROOT / path).read_text(), entry


def test_the_kernel_free_tests_are_collected_first(request, conftest):
    free = [conftest._kernel_free(item) for item in request.session.items]
    assert free == sorted(free, reverse=True)  # whatever this run collected


def test_a_worker_waits_while_a_compiler_holds_its_group(tmp_path, monkeypatch, conftest):
    monkeypatch.setattr(conftest, "KERNEL_GROUPS", {"probe": lambda: None})
    monkeypatch.setattr(conftest, "_lock_path", lambda name: tmp_path / f"{name}.lock")
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(tmp_path / "probe.lock")],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        done = threading.Event()
        waiter = threading.Thread(target=lambda: (conftest._CompilerWait().wait(), done.set()))
        waiter.start()
        assert not done.wait(1.0)  # still compiling: the worker waits
        holder.stdin.write("done\n")
        holder.stdin.flush()
        assert holder.wait(timeout=30) == 0
        assert done.wait(30)  # released: the worker goes on
        waiter.join()
    finally:
        holder.kill()
