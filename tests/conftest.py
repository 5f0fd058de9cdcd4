"""Shared fixtures: a seeded ``rng`` (every test that needs randomness takes it from here)."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def rng() -> np.random.Generator:
    """A generator seeded identically for every test, so failures reproduce."""
    return np.random.default_rng(20240611)
