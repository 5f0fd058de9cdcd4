"""The project's small exception hierarchy (after gymnasium.error)."""

from __future__ import annotations


class UavStructError(Exception):
    """Base class of every error this project raises on purpose."""


class SiteGeometryError(UavStructError, ValueError):
    """A building description that cannot exist (overlaps, non-positive sizes, duplicates)."""


class ConfigError(UavStructError, ValueError):
    """An unknown or out-of-range configuration value."""


class RendererUnavailableError(UavStructError, RuntimeError):
    """A requested rendering backend cannot start on this machine."""


class IfcImportError(SiteGeometryError):
    """An IFC file that cannot become a site (not IFC, no structure, no landmark-bearing floor)."""


class ClosedError(UavStructError, RuntimeError):
    """An environment (or its world) was used after ``close()``: make a new one instead."""


class UsageError(UavStructError, ValueError):
    """A command-line input that cannot work: the message names the option and what was expected."""


class ResetNeededError(UavStructError, RuntimeError):
    """An environment was stepped before its first ``reset()``."""
