"""The kernels are compiled (or loaded) before anything is timed, and a first compile is announced."""

from __future__ import annotations

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
