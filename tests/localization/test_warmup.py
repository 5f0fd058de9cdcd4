"""The kernels are compiled (or loaded) before anything is timed, and a first compile is announced."""

from __future__ import annotations

import subprocess
import sys

import localization.warmup as warmup


def test_warm_up_leaves_every_python_called_kernel_compiled_and_cached():
    lines: list[str] = []
    seconds = warmup.warm_up(announce=lines.append)
    assert seconds >= 0.0 and lines in ([], [warmup.COMPILING])
    assert warmup.kernels_cached()
    kernels = warmup.compiled_kernels()
    assert len(kernels) >= 40
    compiled = {k.py_func.__module__ + "." + k.__name__ for k in kernels if k.signatures}
    # The pipeline's entry kernels (the others are called only from inside compiled code).
    for name in ("localization.pose.finish.finish_kernel",
                 "localization.associate.assign_kernels.refine_reassign",
                 "localization.associate.hypothesis_kernels.warm_hypothesis",
                 "localization.geometry.kernels.quat_wxyz", "localization.metrics.pose_error"):
        assert name in compiled


def test_a_first_compile_is_announced_once(monkeypatch):
    monkeypatch.setattr(warmup, "kernels_cached", lambda: False)
    lines: list[str] = []
    warmup.warm_up(announce=lines.append)
    assert lines == [warmup.COMPILING] and "compiling the localization kernels once" in lines[0]
    monkeypatch.setattr(warmup, "kernels_cached", lambda: True)
    warmup.warm_up(announce=lines.append)
    assert len(lines) == 1


_READ_ONLY_RUN = """
import numpy as np
from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import look_at, project
from localization.pipeline import Localizer
from localization.testing.synthetic import paper_prior
from localization.warmup import _scene, compiled_kernels, warm_up

warm_up(announce=None)
name = lambda k: k.py_func.__module__ + "." + k.__name__
before = {name(k): len(k.signatures) for k in compiled_kernels()}
tops, _ = _scene(np.random.default_rng(1))
tops.flags.writeable = False  # as a site's landmarks are
truth = look_at([2.0, -18.0, 14.0], [4.0, 5.5, 4.0])
uv, _ = project(PAPER_K, truth, tops)
for association in ("robust", "paper"):
    loc = Localizer(tops, PAPER_K, association=association, image_size=PAPER_IMAGE_SIZE)
    assert loc.localize(uv, paper_prior(truth, 0)).success
    assert loc.localize(uv, paper_prior(truth, 1), warm_start=truth).success
# the public stages a script calls with a site's arrays directly, each of them read-only
from localization.associate.paper import associate_paper
from localization.associate.robust import associate_robust
from localization.metrics import association_scores
from localization.pose.batch import refine_many

def read_only(a):
    a = np.array(a)
    a.flags.writeable = False
    return a

prior = read_only(paper_prior(truth, 2))
for associate in (associate_robust, associate_paper):
    a = associate(read_only(uv), tops, read_only(PAPER_K), prior, PAPER_IMAGE_SIZE, 40.0).assignment
    assert association_scores(a, read_only(np.arange(len(uv))), read_only(np.arange(len(tops)))).f1 == 1.0
R, t, cost = refine_many(read_only(PAPER_K), read_only(truth[None, :3, :3]), read_only(truth[None, :3, 3]),
                         read_only(tops[None]), read_only(uv[None]), read_only(np.ones((1, len(tops)), bool)))
assert cost[0] < 1e-6
print(sorted(name(k) for k in compiled_kernels() if len(k.signatures) > before[name(k)]))
"""


def test_a_read_only_landmark_set_compiles_nothing_the_warm_up_did_not():
    """numba compiles a kernel once per argument type, and a read-only array is another type: the
    localizer, and each public stage below it, hands the kernels writable arrays
    (``kernel_array``), so a site's (read-only) set runs the kernels the warm-up compiled instead of
    compiling others (seconds each) in its first, timed frames."""
    proc = subprocess.run([sys.executable, "-c", _READ_ONLY_RUN], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "[]"
