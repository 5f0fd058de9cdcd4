"""Every environment setting as a reference table, generated from the code.

The rows are the fields of :class:`~uav_struct_env.envs.config.EnvConfig` and of the settings
objects it nests (:class:`~uav_struct_env.sim.uav.FlightLimits`,
:class:`~uav_struct_env.sim.uav.Geofence`, :class:`~uav_struct_env.sim.schedule.ScheduleSpec`):
name, type and default from the dataclass, the ``train`` preset's value where it differs, and
the meaning from the class docstring's ``Attributes:`` section. The documentation site's
environment page is built from :func:`settings_markdown`; a field without a meaning there raises
:class:`UndocumentedSettingError`, so a new setting cannot go undocumented (the docs build and a
test fail).
"""

from __future__ import annotations

import dataclasses
import inspect
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from uav_struct_env.envs.config import PRESETS, EnvConfig
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.imaging import IMAGING_PRESETS
from uav_struct_env.sim.lens import CAMERA_MODELS
from uav_struct_env.sim.schedule import ScheduleSpec
from uav_struct_env.sim.sensors import NOISE_MODELS
from uav_struct_env.sim.uav import FlightLimits, Geofence
from uav_struct_env.site.activity import ACTIVITY_PRESETS

__all__ = ["NESTED", "Setting", "UndocumentedSettingError", "settings", "settings_markdown"]

#: The settings objects EnvConfig nests, by its field name, each given a table of its own.
NESTED: dict[str, type] = {"limits": FlightLimits, "geofence": Geofence, "schedule": ScheduleSpec}

#: Registries whose resolved objects are shown by name (``noise="gnss_ins"`` is stored resolved).
_NAMED = (NOISE_MODELS, IMAGING_PRESETS, CAMERA_MODELS, ACTIVITY_PRESETS)


class UndocumentedSettingError(ConfigError):
    """A settings dataclass has a field its docstring's ``Attributes:`` does not describe."""


@dataclass(frozen=True)
class Setting:
    """One row of the settings table (Markdown-ready strings)."""

    name: str
    type: str
    default: str
    train: str  # the ``train`` preset's value where it differs from the default, else ""
    meaning: str


def _attribute_docs(cls: type) -> dict[str, str]:
    """``name -> text`` of the Google-style ``Attributes:`` section of ``cls``'s docstring."""
    lines = inspect.cleandoc(cls.__doc__ or "").splitlines()
    docs: dict[str, str] = {}
    try:
        start = lines.index("Attributes:") + 1
    except ValueError:
        return docs
    name = None
    for line in lines[start:]:
        if line and not line.startswith(" "):
            break  # the next section
        entry = re.match(r"^ {4}(\w+): (.*)$", line)
        if entry:
            name, text = entry.groups()
            docs[name] = text
        elif name and line.strip():
            docs[name] += " " + line.strip()
    return docs


def _markdown(text: str) -> str:
    """Docstring reST to Markdown table text: roles to code, ``x`` to `x`, pipes escaped."""
    text = re.sub(r":\w+:`~?([\w.]+)`", lambda m: f"`{m.group(1).rsplit('.', 1)[-1]}`", text)
    return text.replace("``", "`").replace("|", "\\|")


def _plain(value: Any) -> Any:
    """Numbers as a reader writes them: numpy scalars to Python, floats to 6 significant digits."""
    if isinstance(value, tuple):
        return tuple(_plain(v) for v in value)
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return float(f"{value:.6g}")
    return value


def _show(value: Any) -> str:
    for registry in _NAMED:
        for key, obj in registry.items():
            if value is obj:
                return f"`{key!r}`"
    if dataclasses.is_dataclass(value) and value == type(value)():
        return f"`{type(value).__name__}()`"
    return f"`{_plain(value)!r}`"


def _default(f: dataclasses.Field) -> Any:
    return f.default_factory() if f.default is dataclasses.MISSING else f.default


def settings(cls: type = EnvConfig) -> list[Setting]:
    """The rows of ``cls``'s table, in field order.

    Raises:
        UndocumentedSettingError: a field has no meaning in the docstring, or the docstring
            describes a field that does not exist.
    """
    docs = _attribute_docs(cls)
    fields = dataclasses.fields(cls)
    names = [f.name for f in fields]
    missing = [n for n in names if not docs.get(n, "").strip()]
    stale = sorted(set(docs) - set(names))
    if missing or stale:
        raise UndocumentedSettingError(
            f"{cls.__name__}'s docstring (Attributes:) must describe every field: "
            f"undocumented {missing}, describes missing fields {stale}"
        )
    paper, train = PRESETS["paper"], PRESETS["train"]
    rows = []
    for f in fields:
        differs = cls is EnvConfig and getattr(train, f.name) != getattr(paper, f.name)
        rows.append(Setting(
            name=f"`{f.name}`",
            type=_markdown(f"``{f.type}``"),
            default=_markdown(_show(_default(f))),
            train=_markdown(_show(getattr(train, f.name))) if differs else "",
            meaning=_markdown(docs[f.name]),
        ))
    return rows


def settings_markdown() -> str:
    """The settings tables: EnvConfig's, then one per nested settings object."""
    out = ["| setting | type | default | `train` preset | meaning |", "|---|---|---|---|---|"]
    out += [f"| {s.name} | {s.type} | {s.default} | {s.train} | {s.meaning} |" for s in settings()]
    for field_name, cls in NESTED.items():
        out += [
            "",
            f"`{field_name}` is a `{cls.__name__}` (`{cls.__module__}`); pass "
            f"`{field_name}={cls.__name__}(...)` with the fields to change:",
            "",
            "| field | type | default | meaning |",
            "|---|---|---|---|",
        ]
        out += [f"| {s.name} | {s.type} | {s.default} | {s.meaning} |" for s in settings(cls)]
    return "\n".join(out) + "\n"
