"""What every study output shares at its edges: the JSON and CSV boundaries and the table cells.

A module of its own (importing nothing of the study) so that the report, the sweep, the temporal
study and worker tracking (which :mod:`~uav_struct_env.study.protocol` imports) all use it.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from uav_struct_env.outputs import atomic_path


def json_ready(obj: Any) -> Any:
    """The JSON boundary: NaN and infinities (undefined statistics) become null."""
    if isinstance(obj, dict):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    return obj


def cell(x: float | None, digits: int = 3) -> str:
    """A table cell: ``x`` to ``digits`` decimals, an em dash for None (undefined)."""
    return "—" if x is None else f"{x:.{digits}f}"


def pct_cell(x: float | None) -> str:
    """A table cell: the fraction ``x`` in percent to 2 decimals, an em dash for None."""
    return "—" if x is None else f"{100 * x:.2f}"


def write_records_csv(
    path: Path,
    record_type: type,
    rows: Sequence[Any],
    lead: tuple[Sequence[str], Sequence[Sequence[Any]]] = ((), ()),
    comment: str | None = None,
) -> None:
    """Dataclass records of ``record_type`` as CSV, one row each, its fields as the columns.

    ``lead``: ``(names, values)``, columns written before the record's, ``values[i]`` for row
    ``i`` (the sweep's ``site`` and ``seed`` of the run each row came from). ``comment``: a first
    line ``# <comment>`` (how the file was made; :func:`read_records_csv` and
    ``pandas.read_csv(path, comment="#")`` skip it).
    """
    names, values = lead
    fields = [*names, *(f.name for f in dataclasses.fields(record_type))]
    with atomic_path(path) as tmp, tmp.open("w", newline="") as fh:
        if comment is not None:
            fh.write("# " + " ".join(comment.split()) + "\n")
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        for i, r in enumerate(rows):
            writer.writerow({**(dict(zip(names, values[i], strict=True)) if names else {}),
                             **dataclasses.asdict(r)})


def read_records_csv(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV written by :func:`write_records_csv` (strings), its ``#`` lines skipped."""
    with Path(path).open(newline="") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))
