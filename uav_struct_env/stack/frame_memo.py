"""One frame's work shared by the guided detectors of several landmark sets.

The guided detectors of a site's landmark sets (slab corners, opening corners, ...) each run,
on the same frame, the learned detector over every landmark type and, where no first pose
exists, the alignment of the whole building model at the prior: the same calls on the same
arguments. :class:`FrameMemo` remembers a function's last results by the *values* of its
arguments (an image compared pixel for pixel, not by identity: a renderer may reuse its buffer
for the next frame), so the second set of a frame reuses what the first computed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from localization.checks import check_number

__all__ = ["FrameMemo", "SharedSeed"]


def _same(a: Any, b: Any) -> bool:
    """Whether two arguments are equal by value (arrays: shape, dtype and every element)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        if a.shape != b.shape or a.dtype != b.dtype:
            return False
        if a.ndim >= 2 and not np.array_equal(a[::17, ::13], b[::17, ::13]):  # cheap reject first
            return False
        return bool(np.array_equal(a, b))
    return bool(a == b)


def _size(a: Any) -> int:
    """How many elements an array argument holds (0 for others): the cost of comparing it."""
    return a.size if isinstance(a, np.ndarray) else 0


def _kept(a: Any) -> Any:
    """A copy of an array argument (the caller may change it in place later), others as they are."""
    return np.array(a, copy=True) if isinstance(a, np.ndarray) else a


class FrameMemo:
    """``fn(*args)``, remembered for the ``size`` argument tuples last used (compared by value).

    The results are returned as computed, not copied: callers must not change them in place.

    Args:
        fn: the function.
        size: how many argument tuples are remembered (at least 1).

    Raises:
        TypeError: if ``fn`` is not callable.
        ValueError: if ``size`` is below 1.
    """

    def __init__(self, fn: Callable[..., Any], size: int = 1) -> None:
        if not callable(fn):
            raise TypeError(f"fn must be callable, got {type(fn).__name__}")
        self.fn = fn
        self.size = check_number("size", size, 1, integer=True, type_error=ValueError)
        self._entries: list[tuple[tuple[Any, ...], Any]] = []

    def __call__(self, *args: Any) -> Any:
        """``fn(*args)``: the remembered result when the arguments equal a remembered tuple's.

        The smaller arguments are compared first: a pose that differs rejects an entry of the same
        frame before its image is compared pixel for pixel.
        """
        order = sorted(range(len(args)), key=lambda j: _size(args[j]))
        for i, (key, value) in enumerate(self._entries):
            if len(key) == len(args) and all(_same(key[j], args[j]) for j in order):
                self._entries.insert(0, self._entries.pop(i))  # the most recently used first
                return value
        value = self.fn(*args)
        self._entries = [(tuple(_kept(a) for a in args), value)] + self._entries[: self.size - 1]
        return value


class SharedSeed:
    """A first-pass detector's ``detect_all`` run once per frame for every set that asks for it.

    Args:
        detector: has ``detect_all(image) -> (uv, scores, types)`` (a
            :class:`~localization.detect.learned.LearnedDetector` of every type).
    """

    def __init__(self, detector: Any) -> None:
        self.detector = detector
        self.detect_all = FrameMemo(detector.detect_all, 1)

    def __repr__(self) -> str:
        return f"SharedSeed({self.detector!r})"
