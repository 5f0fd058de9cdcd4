"""A time budget for one localization: the deadline its search checks between steps.

:class:`localization.Localizer`'s ``time_budget_s`` bounds one :meth:`~localization.Localizer.localize`
call in wall-clock seconds (``time.perf_counter``, from the call's start). The robust search
checks the :class:`Deadline` before each of its steps (each batch of hypotheses refined, the
layout vote, each round of the rival search; :mod:`localization.associate`); the verification's
second search runs under the same deadline. A call past its deadline fails as
:attr:`~localization.failure.FailureCode.TIMED_OUT`, never with a pose: a search cut short
cannot rule out the rivals a full one would have found. A step already running finishes first,
so a call may overrun its budget by one step (measured in ``benchmarks/integrity_fuzz.py
--time-budget``).

Without a budget (the default) nothing is timed and the results are the same to the bit on
every machine and load; with one they depend on how fast the machine runs at that moment.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

__all__ = ["Deadline", "OutOfTime"]


class OutOfTime(Exception):
    """Raised by :meth:`Deadline.check` when the deadline has passed; ``reason`` says where."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class Deadline:
    """When a localization must be done: ``start + budget_s`` on ``time.perf_counter``'s clock."""

    start: float
    budget_s: float

    @classmethod
    def after(cls, budget_s: float | None, start: float) -> Deadline | None:
        """The deadline ``budget_s`` after ``start``, or None without a budget."""
        return None if budget_s is None else cls(float(start), float(budget_s))

    def spent(self) -> float:
        """Seconds since the start."""
        return time.perf_counter() - self.start

    def passed(self) -> bool:
        """Whether the budget is spent."""
        return self.spent() > self.budget_s

    def reason(self, step: str) -> str:
        """The failure's reason: the budget, what was spent, and the step not reached in time."""
        return (
            f"out of time: {self.spent():.3f} s spent of a {self.budget_s:.3f} s budget "
            f"(Localizer time_budget_s) before {step}"
        )

    def check(self, step: str) -> None:
        """Raise :class:`OutOfTime` naming ``step`` (what would run next) if the budget is spent."""
        if self.passed():
            raise OutOfTime(self.reason(step))
