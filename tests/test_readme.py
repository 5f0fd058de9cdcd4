"""The README: its Python examples run as written, its links resolve, it says how to start."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def test_readme_python_blocks_run():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert len(blocks) >= 2
    namespace: dict = {}
    try:
        for block in blocks:
            exec(compile(block, str(README), "exec"), namespace)  # noqa: S102
        assert namespace["est"].success, namespace["est"].failure_reason
    finally:
        for name in ("env", "aec", "wenv", "train_env"):
            if name in namespace:
                namespace[name].close()


def test_readme_links_resolve_and_it_says_how_to_start():
    text = README.read_text()
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text)
    local = [link for link in links if "://" not in link]
    assert len(local) >= 10
    assert [link for link in local if not (ROOT / link).exists()] == []
    for promise in ("source .venv/bin/activate", "make demo", "make test", "make docs", "CITATION.cff"):
        assert promise in text, promise
