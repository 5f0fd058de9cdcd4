"""Imports point down the layers that docs/design.md draws ("Layers"), inside ``localization`` too.

Every import statement of the three packages (module level or inside a function) is read with
``ast``; a module may import its own layer or a lower one, never a higher one. Importing the
top-level ``uav_struct_env`` package itself is allowed where it is only for ``__version__`` or the
env constructors (``uav_struct_env.parallel_env``), which the top package exports.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Lowest first. A module belongs to the layer of the longest prefix that names it.
LAYERS: list[tuple[str, ...]] = [
    ("localization.budget", "localization.checks", "localization.failure", "localization.stats"),
    ("localization.geometry",),
    ("localization.detect", "localization.pose"),
    # the verification's kernels beside the search's (verify.py, a layer up, calls them)
    ("localization.associate", "localization.verify_kernels"),
    ("localization.pipeline", "localization.verify", "localization.metrics", "localization.temporal",
     "localization.testing"),
    ("localization.aruco",),
    ("localization",),
    ("tracking",),
    ("uav_struct_env.errors",),
    ("uav_struct_env.named", "uav_struct_env.outputs", "uav_struct_env.processes"),
    ("uav_struct_env.site",),
    ("uav_struct_env.sim",),
    ("uav_struct_env.envs",),
    ("uav_struct_env",),  # the top package: the env constructors and __version__ (exact name only)
    ("uav_struct_env.stack", "uav_struct_env.validate", "uav_struct_env.provenance"),
    ("uav_struct_env.tracking_sim", "uav_struct_env.baselines", "uav_struct_env.datasets"),
    ("uav_struct_env.wrappers",),
    ("uav_struct_env.vector",),
    ("uav_struct_env.training",),
    ("uav_struct_env.study",),
    ("uav_struct_env.photos",),  # uav-struct localize: writes its CSV with the study's writer
    ("uav_struct_env.demo", "uav_struct_env.cli"),
]

#: Layers that hold one module, not the package below it.
EXACT = {"uav_struct_env"}


def layer_of(module: str) -> int | None:
    """Index of ``module``'s layer in :data:`LAYERS` (longest prefix), None outside the packages."""
    best, best_len = None, -1
    for i, names in enumerate(LAYERS):
        for name in names:
            below = module.startswith(name + ".") and name not in EXACT
            if (module == name or below) and len(name) > best_len:
                best, best_len = i, len(name)
    return best


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> list[tuple[int, str]]:
    """``(line, imported module)`` of every absolute import in ``path``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module == "uav_struct_env" and all(
                a.name in ("__version__", "parallel_env", "env") for a in node.names
            ):
                continue
            out.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            out.extend((node.lineno, a.name) for a in node.names if a.name != "uav_struct_env")
    return out


SOURCES = sorted(
    p for pkg in ("localization", "tracking", "uav_struct_env") for p in (ROOT / pkg).rglob("*.py")
)


def test_every_module_has_a_layer() -> None:
    assert [module_name(p) for p in SOURCES if layer_of(module_name(p)) is None] == []


def test_imports_point_down() -> None:
    upward = []
    for path in SOURCES:
        mine = layer_of(module_name(path))
        for line, target in imports_of(path):
            theirs = layer_of(target)
            if theirs is not None and theirs > mine:
                upward.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    assert upward == []


@pytest.mark.parametrize(
    ("module", "expected"),
    [
        ("localization.associate.robust", 3),
        ("localization.pose.covariance", 2),
        ("uav_struct_env.sim.camera", 11),
        ("uav_struct_env", 13),
    ],
)
def test_layer_of(module: str, expected: int) -> None:
    assert layer_of(module) == expected


def test_an_upward_import_is_caught(tmp_path: Path) -> None:
    """The check can fail: geometry importing the pipeline is reported."""
    bad = tmp_path / "bad.py"
    bad.write_text("from localization.pipeline import Localizer\n")
    [(_, target)] = imports_of(bad)
    assert layer_of(target) > layer_of("localization.geometry.transforms")
