"""Declarative argument checks: one scalar validator and one choice validator for the project.

Every public constructor validates its numbers through :func:`check_number` instead of
hand-written ``isinstance``/range chains, so a bad value always gets the same kind of message::

    check_number("miss_rate", 1.5, 0.0, 1.0)          # miss_rate must be a number in [0, 1], got 1.5
    check_number("threads", 0, 1, integer=True)       # threads must be an int >= 1, got 0
    check_number("pixel_sigma", -1, 0, lo_open=True)  # pixel_sigma must be finite and > 0, got -1

Pure Python + numpy: :mod:`uav_struct_env` imports it too (the layers point down only).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["as_floats", "check_choice", "check_number"]


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(float(x))


def _bounds(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    if lo is not None and hi is not None:
        return f"in {'(' if lo_open else '['}{_fmt(lo)}, {_fmt(hi)}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {_fmt(lo)}"
    if hi is not None:
        return f"{'<' if hi_open else '<='} {_fmt(hi)}"
    return ""


def check_number(
    name: str,
    value: Any,
    lo: float | None = None,
    hi: float | None = None,
    *,
    integer: bool = False,
    finite: bool = True,
    lo_open: bool = False,
    hi_open: bool = False,
    error: type[Exception] = ValueError,
    type_error: type[Exception] = TypeError,
) -> Any:
    """Return ``value`` as a ``float`` (``int`` with ``integer=True``) after checking it.

    Args:
        name: the argument's name, first word of the message.
        value: the value to check; ``bool`` is never a number here.
        lo: lower bound, inclusive unless ``lo_open`` (None: unbounded).
        hi: upper bound, inclusive unless ``hi_open`` (None: unbounded).
        integer: require an integer (Python or numpy int).
        finite: reject NaN and +-inf (floats only).
        lo_open: ``lo`` itself is out of range.
        hi_open: ``hi`` itself is out of range.
        error: exception raised for a value out of range (e.g. the project's ``ConfigError``).
        type_error: exception raised for a value that is not a number (or not an int).

    Raises:
        ``type_error`` / ``error``: with a message ``"<name> must be <what>, got <value>"``.
    """
    bounds = _bounds(lo, hi, lo_open, hi_open)
    if integer:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise type_error(f"{name} must be an int{' ' + bounds if bounds else ''}, got {value!r}")
        out: Any = int(value)
        what = f"an int {bounds}"
    else:
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise type_error(f"{name} must be a number, got {value!r}")
        out = float(value)
        if lo is not None and hi is not None:
            what = f"a number {bounds}"
        elif bounds:
            what = f"finite and {bounds}" if finite else f"a number {bounds}"
        else:
            what = "finite"
        if math.isnan(out) or (finite and not math.isfinite(out)):
            raise error(f"{name} must be {what}, got {value!r}")
    ok = (
        (lo is None or (out > lo if lo_open else out >= lo))
        and (hi is None or (out < hi if hi_open else out <= hi))
    )
    if not ok:
        raise error(f"{name} must be {what}, got {value!r}")
    return out


def check_choice(
    name: str,
    value: Any,
    options: Sequence[str],
    *,
    error: type[Exception] = ValueError,
    type_error: type[Exception] | None = None,
) -> str:
    """Return ``value`` if it is one of the names ``options``, else raise naming both.

    A value that is not a ``str`` raises ``type_error`` (default: ``error``).
    """
    if not isinstance(value, str):
        raise (type_error or error)(f"{name} must be one of {tuple(options)}, got {value!r}")
    if value not in options:
        raise error(f"{name} must be one of {tuple(options)}, got {value!r}")
    return value


def as_floats(name: str, values: Any, n: int) -> tuple[float, ...]:
    """``values`` (``n`` numbers) as a tuple of Python floats, or ValueError naming ``name``.

    A tuple of ``n`` floats (a state's position, say) is returned as it is: the per-step callers
    pay no array conversion.
    """
    if type(values) is tuple and len(values) == n and all(type(v) is float for v in values):
        return values
    arr = np.asarray(values, dtype=np.float64)
    if arr.size != n:
        raise ValueError(f"{name} must hold {n} numbers, got {values!r}")
    return tuple(float(v) for v in arr.reshape(n))
