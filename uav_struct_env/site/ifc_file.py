"""Guards on an IFC-SPF file before and after it is parsed: size, truncation, damaged coordinates.

ifcopenshell parses what it can and says nothing of what it could not: a file cut short imports
with the entities it reached, and a coordinate written as ``NAN``, ``INF`` or ``1E300`` is dropped
or kept as it comes -- either way a different building that the study would evaluate without a
word. These checks read the file's text and refuse such a file with the reason, naming the
entity. A file larger than :func:`max_file_bytes` is refused before parsing (a 200 MB export
parses for minutes in gigabytes of memory).

Pure (no ifcopenshell): the importer (:mod:`uav_struct_env.site.ifc`) calls them.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

from uav_struct_env.errors import IfcImportError

__all__ = [
    "MAX_COORDINATE_M",
    "MAX_FILE_MB",
    "MAX_FILE_MB_VARIABLE",
    "check_coordinates",
    "check_complete",
    "check_size",
    "max_file_bytes",
    "star_arguments",
]

#: Files larger than this are refused before parsing, MB (10^6 bytes); see MAX_FILE_MB_VARIABLE.
MAX_FILE_MB = 100.0
#: The environment variable that overrides MAX_FILE_MB (a number of MB).
MAX_FILE_MB_VARIABLE = "UAV_STRUCT_IFC_MAX_MB"
#: A point farther than this from the file's origin (after the length unit) is damaged, m
#: (projected map coordinates reach 10^7 m; nothing on Earth reaches 10^8).
MAX_COORDINATE_M = 1e8

# The entities whose numbers are coordinates (points) or directions, and their argument lists.
_POINTS = re.compile(rb"#(\d+)\s*=\s*(IFCCARTESIANPOINT(?:LIST[23]D)?|IFCDIRECTION)\s*\(((?:[^;'])*?)\)\s*;",
                     re.IGNORECASE)
_NUMBER = re.compile(rb"[^\s(),$]+")
_END = b"END-ISO-10303-21"
# A ``*`` argument (the derived-value mark), and an entity instance's head.
_STAR = re.compile(rb"[(,]\s*\*\s*[,)]")
_INSTANCE = re.compile(rb"#(\d+)\s*=\s*(\w+)\s*\(")


def max_file_bytes() -> int:
    """The size limit: MAX_FILE_MB, or the number of MB in the environment variable that overrides it.

    Raises:
        IfcImportError: if the variable is set to something other than a positive number.
    """
    raw = os.environ.get(MAX_FILE_MB_VARIABLE)
    if raw is None:
        return int(MAX_FILE_MB * 1e6)
    try:
        mb = float(raw)
    except ValueError:
        mb = math.nan
    if not (math.isfinite(mb) and mb > 0):
        raise IfcImportError(f"{MAX_FILE_MB_VARIABLE} must be a positive number of MB, got {raw!r}")
    return int(mb * 1e6)


def check_size(path: Path) -> None:
    """Refuse a file larger than :func:`max_file_bytes` before any parsing."""
    size, limit = path.stat().st_size, max_file_bytes()
    if size > limit:
        raise IfcImportError(
            f"{str(path)!r} is {size / 1e6:.1f} MB, more than the {limit / 1e6:.0f} MB an import may "
            f"parse (minutes and gigabytes of memory); set {MAX_FILE_MB_VARIABLE}=<MB> to allow it"
        )


def check_complete(path: Path, text: bytes) -> None:
    """Refuse a file whose DATA section is cut short (no ``END-ISO-10303-21;`` at its end)."""
    if _END not in text[-4096:].upper():
        raise IfcImportError(
            f"{str(path)!r} is truncated: an IFC-SPF file ends with 'END-ISO-10303-21;', this one "
            f"with {text[-40:].decode('latin-1')!r} (a partial download or copy?)"
        )


def check_coordinates(path: Path, text: bytes, length_unit_m: float) -> None:
    """Refuse a file with a point or direction that is not finite, or a point beyond MAX_COORDINATE_M.

    Args:
        path: the file, for the message.
        text: its bytes.
        length_unit_m: the file's length unit in metres (0.001 for millimetres).
    """
    for m in _POINTS.finditer(text):
        entity, kind = m.group(1).decode(), m.group(2).decode().upper()
        for token in _NUMBER.findall(m.group(3)):
            try:
                value = float(token)
            except ValueError:
                value = math.nan
            bad = not math.isfinite(value) or (
                kind != "IFCDIRECTION" and abs(value) * length_unit_m > MAX_COORDINATE_M)
            if bad:
                raise IfcImportError(
                    f"{str(path)!r} has a damaged coordinate: #{entity} {kind} holds "
                    f"{token.decode('latin-1')!r} (a finite number within {MAX_COORDINATE_M:.0e} m "
                    "was expected); the file would import as a different building"
                )


def _top_level_arguments(body: str) -> list[str]:
    """The comma-separated arguments of an instance (its text between the outer parentheses)."""
    args: list[str] = []
    depth, start, quoted = 0, 0, False
    for k, c in enumerate(body):
        if quoted:
            quoted = c != "'"  # an escaped quote ('') closes and reopens: same result
        elif c == "'":
            quoted = True
        elif c == "(":
            depth += 1
        elif c == ")":
            depth -= 1
        elif c == "," and depth == 0:
            args.append(body[start:k].strip())
            start = k + 1
    args.append(body[start:].strip())
    return args


def star_arguments(text: bytes) -> list[tuple[int, str, tuple[int, ...]]]:
    """The instances with a ``*`` argument: ``(entity id, TYPE, positions of the ``*`` arguments)``.

    ``*`` marks an attribute that a subtype derives; some exporters (Renga) also write it for
    an optional attribute left unset, where ``$`` belongs, and the geometry kernel then fails
    on the element ("Requested type <string> does not match actual type <derived>"). The
    importer reads such a ``*`` as unset (:func:`uav_struct_env.site.ifc._unset_star_arguments`,
    which knows from the schema which positions are derived). One instance per line, as the
    exporters write them.
    """
    found: dict[int, tuple[int, str, tuple[int, ...]]] = {}
    for m in _STAR.finditer(text):
        start = text.rfind(b"\n", 0, m.start()) + 1
        if start in found:
            continue
        end = text.find(b";", m.end())
        head = _INSTANCE.match(text, start)
        if head is None or end < 0:
            continue
        body = text[head.end():end].decode("latin-1").rstrip()
        args = _top_level_arguments(body[:-1] if body.endswith(")") else body)
        stars = tuple(k for k, a in enumerate(args) if a == "*")
        found[start] = (int(head.group(1)), head.group(2).decode().upper(), stars)
    return [v for v in found.values() if v[2]]
