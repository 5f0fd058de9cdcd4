"""``benchmarks/*.py --help`` shows every option's default (read from the scripts, not run)."""

import ast
from pathlib import Path

import pytest

SCRIPTS = sorted((Path(__file__).resolve().parents[1] / "benchmarks").glob("*.py"))


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)
            and n.func.attr == name]


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_every_option_shows_its_default(script):
    tree = ast.parse(script.read_text())
    parsers = _calls(tree, "ArgumentParser")
    for call in parsers:  # the formatter that appends "(default: ...)" to each help text
        formatter = {k.arg: ast.unparse(k.value) for k in call.keywords}.get("formatter_class")
        assert formatter == "argparse.ArgumentDefaultsHelpFormatter", f"{script.name}:{call.lineno}"
    for call in _calls(tree, "add_argument") if parsers else ():
        keywords = {k.arg: k.value for k in call.keywords}
        flags = [ast.literal_eval(a) for a in call.args]
        flag_only = isinstance(keywords.get("action"), ast.Constant) and \
            keywords["action"].value in ("store_true", "store_false")
        if not flag_only:  # the formatter shows a default only beside a help text
            assert "help" in keywords, f"{script.name}:{call.lineno}: {flags} has no help: no default shown"
        text = ast.unparse(keywords["help"]) if "help" in keywords else ""
        assert "(default" not in text, f"{script.name}:{call.lineno}: {flags} would show its default twice"
