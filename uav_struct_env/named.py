"""Settings that take a preset name or an object of their own type (camera, imaging, activity, noise)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, TypeVar

from uav_struct_env.errors import ConfigError

T = TypeVar("T")


def resolve_named(setting: str, value: Any, presets: Mapping[str, T], kind: type, described: str) -> T:
    """``value`` itself when it is a ``kind``, the preset it names when it is a key of ``presets``.

    Raises:
        ConfigError: naming ``setting``, the preset names, ``described`` (what else it may be,
            e.g. ``"a CameraModel"``) and the value given.
    """
    if isinstance(value, kind):
        return value
    if isinstance(value, str) and value in presets:
        return presets[value]
    raise ConfigError(f"{setting} must be one of {sorted(presets)} or {described}, got {value!r}")
