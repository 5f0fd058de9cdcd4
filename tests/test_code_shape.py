"""Functions a newcomer can read: at most 80 lines and cyclomatic complexity 15 in the core.

The scope is the localization package, the IFC importer and the wrappers (the issue's "no
function over 80 lines or cyclomatic complexity 15"). Lines run from ``def`` to the function's
last line, its docstring not counted; complexity is ruff's C901 (mccabe) at 15.
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCOPE = ["localization", "uav_struct_env/site/ifc.py", "uav_struct_env/wrappers"]
MAX_LINES = 80
MAX_COMPLEXITY = 15


def _files() -> list[Path]:
    out: list[Path] = []
    for entry in SCOPE:
        path = ROOT / entry
        out.extend(sorted(path.rglob("*.py")) if path.is_dir() else [path])
    return out


def function_lengths(source: str) -> list[tuple[str, int, int]]:
    """``(name, first line, length)`` of every function in ``source``, docstrings not counted."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        first = min([node.lineno] + [d.lineno for d in node.decorator_list])
        length = node.end_lineno - first + 1
        body = node.body
        if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
            if isinstance(body[0].value.value, str):
                length -= body[0].end_lineno - body[0].lineno + 1
        out.append((node.name, node.lineno, length))
    return out


def test_no_function_over_80_lines() -> None:
    long = [
        f"{path.relative_to(ROOT)}:{line} {name} ({length} lines)"
        for path in _files()
        for name, line, length in function_lengths(path.read_text())
        if length > MAX_LINES
    ]
    assert long == []


def test_the_length_count_leaves_out_the_docstring() -> None:
    doc = "\n".join(f"    line {i}" for i in range(100))
    source = f'def f():\n    """Doc.\n{doc}\n    """\n    return 1\n'
    assert function_lengths(source) == [("f", 1, 2)]
    body = "\n".join(f"    x{i} = {i}" for i in range(90))
    assert function_lengths(f"def g():\n{body}\n")[0][2] == 91


def _ruff() -> list[str]:
    exe = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if exe is None:
        pytest.skip("ruff is not installed (the dev extra)")
    return [exe]


def test_cyclomatic_complexity_at_most_15() -> None:
    cmd = _ruff() + [
        "check", "--select", "C901", "--config", f"lint.mccabe.max-complexity={MAX_COMPLEXITY}",
        "--output-format", "concise", "--no-cache", *SCOPE,
    ]  # fmt: skip
    run = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    assert run.returncode == 0, run.stdout + run.stderr


def test_the_complexity_check_can_fail(tmp_path: Path) -> None:
    branches = "\n".join(f"    if x == {i}:\n        return {i}" for i in range(20))
    (tmp_path / "branchy.py").write_text(f'"""Branchy."""\n\n\ndef f(x):\n    """F."""\n{branches}\n')
    cmd = _ruff() + [
        "check", "--select", "C901", "--config", f"lint.mccabe.max-complexity={MAX_COMPLEXITY}",
        "--no-cache", str(tmp_path / "branchy.py"),
    ]  # fmt: skip
    run = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert run.returncode == 1 and "C901" in run.stdout
