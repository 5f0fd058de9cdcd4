"""Test fixtures: synthetic scenes and the integrity fuzz.

:mod:`~localization.testing.synthetic` and :mod:`~localization.testing.fuzz` are pure, like the rest
of the package; the tests and benchmarks use them, the localizer never does.
"""
