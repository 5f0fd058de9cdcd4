"""One frame's work remembered by value and shared by the guided detectors of a site's sets."""

import numpy as np
import pytest

from uav_struct_env.stack.frame_memo import FrameMemo, SharedSeed


class _Counted:
    def __init__(self):
        self.calls = 0

    def __call__(self, image, *rest):
        self.calls += 1
        return float(image.sum()) + sum(float(np.sum(r)) for r in rest)


def test_equal_arguments_are_computed_once_and_a_changed_image_again():
    fn = _Counted()
    memo = FrameMemo(fn)
    image = np.zeros((72, 128, 3), np.uint8)
    assert memo(image, np.eye(4)) == 4.0
    assert memo(image.copy(), np.eye(4)) == 4.0  # another array of the same values: remembered
    assert fn.calls == 1
    image[40, 50, 1] = 7  # the same buffer, a new frame: not its identity, its values count
    assert memo(image, np.eye(4)) == 11.0
    assert memo(image, 2 * np.eye(4)) == 15.0
    assert fn.calls == 3


def test_the_last_size_argument_tuples_are_remembered():
    fn = _Counted()
    memo = FrameMemo(fn, size=2)
    a, b, c = (np.full((8, 8), v, np.float64) for v in (1.0, 2.0, 3.0))
    memo(a), memo(b), memo(b), memo(a)  # a used last
    assert fn.calls == 2
    memo(c), memo(a)  # c pushed b out (used longest ago); a is still there
    assert fn.calls == 3
    memo(b)
    assert fn.calls == 4


def test_memo_refuses_bad_input():
    with pytest.raises(TypeError, match="fn must be callable"):
        FrameMemo(3)
    with pytest.raises(ValueError, match="size"):
        FrameMemo(len, size=0)


def test_a_shared_seed_runs_its_detector_once_per_frame():
    class Detector:
        calls = 0

        def detect_all(self, image):
            Detector.calls += 1
            return np.array([[1.0, 2.0]]), np.array([0.9]), np.array([0])

    seed = SharedSeed(Detector())
    image = np.zeros((72, 128, 3), np.uint8)
    first, second = seed.detect_all(image), seed.detect_all(image)
    assert Detector.calls == 1 and first is second
    seed.detect_all(image + 1)
    assert Detector.calls == 2
