"""Shared fixtures: a seeded ``rng`` (every test that needs randomness takes it from here) and
``load_script`` (a script of ``benchmarks/`` or ``examples/`` as a module)."""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest


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
