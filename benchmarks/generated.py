"""Generated blocks in Markdown files: the figures a script writes between two markers.

A block starts with ``<!-- BEGIN generated: COMMAND -->`` (the command that writes it) and ends
with ``<!-- END generated -->``; the scripts under ``benchmarks/`` that regenerate documentation
figures (``model_card_study.py``) rewrite only what lies between.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

END = "<!-- END generated -->"


def begin(command: str) -> str:
    """The opening marker of the block written by ``command``."""
    return f"<!-- BEGIN generated: {command} -->"


def replace_block(text: str, command: str, block: str) -> str:
    """``text`` with the block of ``command`` replaced by ``block`` (markers included)."""
    pattern = re.compile(re.escape(begin(command)) + r".*?" + re.escape(END), flags=re.S)
    if not pattern.search(text):
        raise ValueError(f"no {begin(command)} ... {END} block")
    return pattern.sub(lambda _: block, text)


def update_file(path: Path, command: str, block: str, check: bool) -> bool:
    """Write ``block`` into ``path`` (or with ``check`` only compare); True when it matched.

    Raises:
        ValueError: ``path`` has no block of ``command``.
    """
    text = path.read_text()
    try:
        new = replace_block(text, command, block)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    if check:
        if new != text:
            print(f"{path} differs from the run:\n{block}", file=sys.stderr)
            return False
        print(f"{path}: the generated block matches the run")
        return True
    path.write_text(new)
    print(f"wrote the generated block of {path}")
    return True
