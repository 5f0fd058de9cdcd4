"""Onboard pose sensors: noisy GNSS camera position and noisy camera attitude.

Sensor models are small frozen dataclasses (their parameters) with two methods, after
dm_control's observables that carry a noise function taking the random state:

* ``start(rng, n_agents) -> state`` draws whatever is random per episode (biases);
* ``measure(state, rng, reading) -> (gnss (3,), attitude (3,))`` returns one noisy reading of
  the true camera position and (roll, pitch, yaw) and advances the state by ``reading.dt``.
  ``gnss`` all NaN means *no fix* (an outage); the environment then observes the last fix
  held and reports ``info["gnss_fix"] = False``. A model must give a fix at reset (``dt == 0``).

A model may also say what noise a pose filter should assume for it: ``filter_noise() ->``
:class:`localization.temporal.FilterNoise` (every model here does; a model without the method
gets the filter's defaults, :func:`uav_struct_env.wrappers.temporal.filter_noise_for`).

All randomness comes from the ``numpy.random.Generator`` passed in, in a fixed order, so a seeded
generator reproduces every reading. Angles are rad; attitudes follow
:mod:`uav_struct_env.sim.attitude` and the returned angles are wrapped to [-pi, pi).

Models: :class:`PaperNoise` (the paper's deterministic offsets), :class:`GnssInsNoise` (white
noise + Gauss-Markov bias, growing near the structure), :class:`DegradedGnssNoise` (that plus
outages and multipath jumps near the structure) and :class:`NoNoise`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from localization.checks import check_number
from localization.temporal import FilterNoise
from uav_struct_env.errors import ConfigError
from uav_struct_env.named import resolve_named

__all__ = [
    "NOISE_MODELS",
    "DegradedGnssNoise",
    "GnssInsNoise",
    "NoNoise",
    "PaperNoise",
    "Reading",
    "SensorModel",
    "make_noise",
]


@dataclass(frozen=True)
class Reading:
    """What a sensor model may look at for one agent at one instant.

    Attributes:
        agent_index: index of the agent in ``possible_agents``.
        viewpoint_index: the viewpoint counter used by :class:`PaperNoise` for its sign pattern
            (the scripted viewpoint ``k`` at a scripted reset, plus one per step).
        position: (3,) true camera position, m.
        attitude: (3,) true camera (roll, pitch, yaw), rad.
        clearance: distance from the camera to the nearest structural element, m.
        dt: time since this agent's previous reading, s (0 at reset).
    """

    agent_index: int
    viewpoint_index: int
    position: NDArray[np.float64]
    attitude: NDArray[np.float64]
    clearance: float = math.inf
    dt: float = 0.0


@runtime_checkable
class SensorModel(Protocol):
    """The interface every sensor model implements."""

    name: str

    def start(self, rng: np.random.Generator, n_agents: int) -> Any:
        """Draw the per-episode state (e.g. biases) for ``n_agents`` agents."""
        ...

    def measure(
        self, state: Any, rng: np.random.Generator, reading: Reading
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Noisy ``(gnss (3,), attitude (3,))`` of one agent; advances ``state``."""
        ...


#: White noise a pose filter assumes for a model that has none (``none``, ``paper``), m / rad.
_FLOOR_POSITION_M = 0.05
_FLOOR_ROTATION_RAD = math.radians(0.05)


def _wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _triple(name: str, v: Any) -> tuple[float, float, float]:
    """``v`` as three non-negative floats, or ConfigError naming ``name``."""
    if isinstance(v, (str, bytes)) or not hasattr(v, "__len__") or len(v) != 3:
        raise ConfigError(f"{name} must be three non-negative numbers, got {v!r}")
    return tuple(
        check_number(f"{name}[{k}]", x, 0, error=ConfigError, type_error=ConfigError) for k, x in enumerate(v)
    )


@dataclass(frozen=True)
class NoNoise:
    """Perfect sensors: the reading is the truth (for debugging and upper bounds)."""

    name: str = "none"

    def start(self, rng: np.random.Generator, n_agents: int) -> None:
        """Nothing to draw."""
        return None

    def measure(self, state: None, rng: np.random.Generator, reading: Reading):
        """The true position and attitude."""
        return np.array(reading.position, dtype=np.float64), _wrap(
            np.array(reading.attitude, dtype=np.float64)
        )

    def filter_noise(self) -> FilterNoise:
        """A tiny white-noise floor and no bias states: the readings are the truth."""
        return FilterNoise(
            gnss_white_sigma=(_FLOOR_POSITION_M,) * 3,
            gnss_bias_sigma=(0.0,) * 3,
            attitude_white_sigma=(_FLOOR_ROTATION_RAD,) * 3,
            attitude_bias_sigma=(0.0,) * 3,
            estimate_gnss_bias=False,
            estimate_attitude_bias=False,
        )


@dataclass(frozen=True)
class PaperNoise:
    """The paper's rough onboard pose (section III): fixed offsets with alternating signs.

    GNSS = true position + ``s * position_offset * position_pattern`` and
    attitude = true (roll, pitch, yaw) + ``s * (roll_offset, pitch_offset, yaw_offset) *
    attitude_pattern`` with ``s = (-1) ** (agent_index + viewpoint_index)``.

    With the default patterns, UAV 0 at viewpoint 0 reads ``(+3, -3, +3)`` m and
    ``(+2, -2, +5)`` deg; UAV 1 at viewpoint 0 and UAV 0 at viewpoint 1 read the opposite signs,
    so across the study's 4 x 10 images every axis is off by +offset in half the images and by
    -offset in the other half. Deterministic: it draws nothing from the generator.
    """

    position_offset: float = 3.0
    roll_offset: float = math.radians(2.0)
    pitch_offset: float = math.radians(2.0)
    yaw_offset: float = math.radians(5.0)
    position_pattern: tuple[int, int, int] = (1, -1, 1)
    attitude_pattern: tuple[int, int, int] = (1, -1, 1)
    name: str = "paper"

    def __post_init__(self) -> None:
        for pname in ("position_pattern", "attitude_pattern"):
            pattern = getattr(self, pname)
            if len(pattern) != 3 or any(p not in (-1, 0, 1) for p in pattern):
                raise ConfigError(f"PaperNoise.{pname} must be three of -1, 0, +1, got {pattern!r}")

    @staticmethod
    def sign(agent_index: int, viewpoint_index: int) -> int:
        """The alternating sign ``(-1) ** (agent_index + viewpoint_index)``."""
        return 1 if (agent_index + viewpoint_index) % 2 == 0 else -1

    def offsets(
        self, agent_index: int, viewpoint_index: int
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(position offset (3,) m, attitude offset (3,) rad)`` for one agent and viewpoint."""
        s = self.sign(agent_index, viewpoint_index)
        dp = s * self.position_offset * np.asarray(self.position_pattern, dtype=np.float64)
        da = (
            s
            * np.array([self.roll_offset, self.pitch_offset, self.yaw_offset])
            * np.asarray(self.attitude_pattern, dtype=np.float64)
        )
        return dp, da

    def start(self, rng: np.random.Generator, n_agents: int) -> None:
        """Nothing to draw."""
        return None

    def measure(self, state: None, rng: np.random.Generator, reading: Reading):
        """Truth plus the signed offsets of this agent and viewpoint."""
        dp, da = self.offsets(reading.agent_index, reading.viewpoint_index)
        return (
            np.asarray(reading.position, dtype=np.float64) + dp,
            _wrap(np.asarray(reading.attitude, dtype=np.float64) + da),
        )

    def filter_noise(self) -> FilterNoise:
        """A bias of the fixed offsets that never decorrelates (one per episode and viewpoint)."""
        return FilterNoise(
            gnss_white_sigma=(_FLOOR_POSITION_M,) * 3,
            gnss_bias_sigma=(self.position_offset,) * 3,
            gnss_bias_tau=1.0e6,
            attitude_white_sigma=(_FLOOR_ROTATION_RAD,) * 3,
            attitude_bias_sigma=(self.roll_offset, self.pitch_offset, self.yaw_offset),
        )


@dataclass
class GnssInsState:
    """Per-episode state of :class:`GnssInsNoise`.

    Unit-variance GNSS bias processes (n, 3) and the constant attitude biases (n, 3), rad.
    """

    gnss_bias_unit: NDArray[np.float64]
    attitude_bias: NDArray[np.float64]


@dataclass(frozen=True)
class GnssInsNoise:
    """Consumer GNSS + AHRS errors: white noise plus slowly drifting bias, worse near structure.

    GNSS position (per axis x, y, z, metres)::

        gnss = p + m(c) * (bias_sigma * b + white_sigma * n),   n ~ N(0, 1)
        b_{k+1} = phi * b_k + sqrt(1 - phi**2) * w,   phi = exp(-dt / bias_tau),  w ~ N(0, 1)
        m(c) = 1 + near_structure_gain * exp(-c / near_structure_scale)

    ``b`` is a first-order Gauss-Markov process with unit stationary variance, started from its
    stationary distribution at reset; ``c`` is the camera's clearance from the structure, and
    ``m(c)`` (3x at contact, ~1.7x at 10 m, ~1.3x at 20 m with the defaults) stands for multipath
    and blocked sky near the building.

    Attitude (roll, pitch, yaw, rad)::

        attitude = truth + attitude_bias + attitude_white_sigma * n,
        attitude_bias ~ N(0, attitude_bias_sigma**2) drawn once per episode.

    Defaults and where they come from:

    * GNSS: a u-blox M8-class single-frequency receiver specifies 2.5 m CEP horizontal (GPS)
      ~ 2.1 m 1-sigma per horizontal axis; DJI specifies the Mavic 2 Pro's GPS hover accuracy as
      +-1.5 m horizontal and +-0.5 m vertical (barometer-aided). Vertical GNSS error is typically
      1.5-2x horizontal. Here: bias 1.5 / 1.5 / 2.5 m and white 0.4 / 0.4 / 0.7 m (x / y / z),
      bias correlation time 120 s (GNSS error correlation times of minutes are standard in
      Gauss-Markov error models, e.g. Groves, *Principles of GNSS, Inertial, and Multisensor
      Integrated Navigation Systems*, 2nd ed., 2013).
    * Attitude: MEMS AHRS datasheets (e.g. VectorNav VN-100: 0.5 deg static / 1 deg dynamic
      pitch-roll, 2 deg magnetic heading) and the paper's own 2 deg / 5 deg budget. Here: bias
      1.0 / 1.0 / 2.5 deg and white 0.2 / 0.2 / 0.5 deg (roll / pitch / yaw). Heading is worst
      because it relies on the magnetometer, which steel reinforcement disturbs.
    """

    gnss_bias_sigma: tuple[float, float, float] = (1.5, 1.5, 2.5)
    gnss_white_sigma: tuple[float, float, float] = (0.4, 0.4, 0.7)
    gnss_bias_tau: float = 120.0
    near_structure_gain: float = 2.0
    near_structure_scale: float = 10.0
    attitude_bias_sigma: tuple[float, float, float] = tuple(
        math.radians(d) for d in (1.0, 1.0, 2.5)
    )
    attitude_white_sigma: tuple[float, float, float] = tuple(
        math.radians(d) for d in (0.2, 0.2, 0.5)
    )
    name: str = "gnss_ins"

    def __post_init__(self) -> None:
        for pname in (
            "gnss_bias_sigma",
            "gnss_white_sigma",
            "attitude_bias_sigma",
            "attitude_white_sigma",
        ):
            object.__setattr__(self, pname, _triple(f"GnssInsNoise.{pname}", getattr(self, pname)))
        for pname in ("gnss_bias_tau", "near_structure_scale"):
            check_number(f"GnssInsNoise.{pname}", getattr(self, pname), 0, lo_open=True,
                         error=ConfigError, type_error=ConfigError)
        check_number("GnssInsNoise.near_structure_gain", self.near_structure_gain, 0,
                     error=ConfigError, type_error=ConfigError)

    def multipath_factor(self, clearance: float) -> float:
        """Error multiplier ``m(c)`` at clearance ``c`` m from the structure."""
        c = max(float(clearance), 0.0)
        return 1.0 + self.near_structure_gain * math.exp(-c / self.near_structure_scale)

    def filter_noise(self) -> FilterNoise:
        """The model's own sigmas and bias time (the multipath factor scales them per fix)."""
        return FilterNoise(
            gnss_white_sigma=self.gnss_white_sigma,
            gnss_bias_sigma=self.gnss_bias_sigma,
            gnss_bias_tau=self.gnss_bias_tau,
            attitude_white_sigma=self.attitude_white_sigma,
            attitude_bias_sigma=self.attitude_bias_sigma,
        )

    def start(self, rng: np.random.Generator, n_agents: int) -> GnssInsState:
        """Stationary GNSS biases and per-episode attitude biases for every agent."""
        unit = rng.standard_normal((n_agents, 3))
        att = rng.standard_normal((n_agents, 3)) * np.asarray(self.attitude_bias_sigma)
        return GnssInsState(unit, att)

    def measure(self, state: GnssInsState, rng: np.random.Generator, reading: Reading):
        """One noisy reading; first advances the agent's GNSS bias by ``reading.dt``."""
        i = reading.agent_index
        if reading.dt > 0:
            phi = math.exp(-reading.dt / self.gnss_bias_tau)
            state.gnss_bias_unit[i] = phi * state.gnss_bias_unit[i] + math.sqrt(
                1.0 - phi * phi
            ) * rng.standard_normal(3)
        white = rng.standard_normal(6)
        m = self.multipath_factor(reading.clearance)
        gnss = np.asarray(reading.position, dtype=np.float64) + m * (
            np.asarray(self.gnss_bias_sigma) * state.gnss_bias_unit[i]
            + np.asarray(self.gnss_white_sigma) * white[:3]
        )
        attitude = (
            np.asarray(reading.attitude, dtype=np.float64)
            + state.attitude_bias[i]
            + np.asarray(self.attitude_white_sigma) * white[3:]
        )
        return gnss, _wrap(attitude)


@dataclass
class DegradedGnssState:
    """Per-episode state of :class:`DegradedGnssNoise`.

    The base model's state and, per agent (n,), the remaining outage and jump time (s) and the
    current jump offset (n, 3), m.
    """

    base: GnssInsState
    outage_left: NDArray[np.float64]
    jump_left: NDArray[np.float64]
    jump_offset: NDArray[np.float64]


@dataclass(frozen=True)
class DegradedGnssNoise:
    """GNSS degraded near the structure: :class:`GnssInsNoise` plus outages and multipath jumps.

    On top of the base model's reading (drawn first, so its numbers are the base model's):

    * **Outages** (no fix: the reading is NaN). Always within ``outage_clearance`` m of the
      structure (half the sky blocked by a storey-high face beside the UAV), and a seeded
      schedule elsewhere: an outage starts with rate ``outage_rate`` per second and lasts an
      exponential time of mean ``outage_duration`` s.
    * **Multipath jumps** (non-line-of-sight reception: the receiver tracks a reflection). Within
      ``jump_clearance`` m of the structure a jump starts with rate ``jump_rate`` per second,
      lasts an exponential time of mean ``jump_duration`` s and offsets the fix by a constant
      ``N(0, jump_sigma^2)`` per axis.

    Every reset reading is a fix (the survey starts with one). Numbers: NLOS reception gives
    pseudorange errors of tens of metres and position jumps of several metres beside buildings
    (Hsu, "Analysis and modeling GPS NLOS effect in highly urbanized area", *GPS Solutions* 22,
    2018; Groves, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems*,
    2nd ed., 2013, ch. 10); the defaults (5 / 5 / 8 m, a jump every ~20 s within 15 m, a ~5 s
    dwell, outages within 4 m and every ~2 min elsewhere for ~8 s) are this project's choices
    inside those ranges for a UAV beside a building a few storeys high, not a fit to data.
    """

    base: GnssInsNoise = GnssInsNoise()
    outage_clearance: float = 4.0
    outage_rate: float = 1.0 / 120.0
    outage_duration: float = 8.0
    jump_clearance: float = 15.0
    jump_rate: float = 1.0 / 20.0
    jump_duration: float = 5.0
    jump_sigma: tuple[float, float, float] = (5.0, 5.0, 8.0)
    name: str = "gnss_degraded"

    def __post_init__(self) -> None:
        if not isinstance(self.base, GnssInsNoise):
            raise ConfigError(f"DegradedGnssNoise.base must be a GnssInsNoise, got {self.base!r}")
        for pname in ("outage_clearance", "outage_rate", "jump_clearance", "jump_rate"):
            check_number(f"DegradedGnssNoise.{pname}", getattr(self, pname), 0,
                         error=ConfigError, type_error=ConfigError)
        for pname in ("outage_duration", "jump_duration"):
            check_number(f"DegradedGnssNoise.{pname}", getattr(self, pname), 0, lo_open=True,
                         error=ConfigError, type_error=ConfigError)
        object.__setattr__(self, "jump_sigma", _triple("DegradedGnssNoise.jump_sigma", self.jump_sigma))

    def multipath_factor(self, clearance: float) -> float:
        """The base model's error multiplier at ``clearance`` m (jumps not included)."""
        return self.base.multipath_factor(clearance)

    def filter_noise(self) -> FilterNoise:
        """The base model's: jumps are left to the filter's GNSS gate, outages to ``gnss_fix``."""
        return self.base.filter_noise()

    def start(self, rng: np.random.Generator, n_agents: int) -> DegradedGnssState:
        """The base model's state; no outage and no jump at reset."""
        return DegradedGnssState(
            self.base.start(rng, n_agents), np.zeros(n_agents), np.zeros(n_agents), np.zeros((n_agents, 3))
        )

    def measure(self, state: DegradedGnssState, rng: np.random.Generator, reading: Reading):
        """The base reading, then this step's outage and jump (four draws, always made)."""
        gnss, attitude = self.base.measure(state.base, rng, reading)
        i, dt = reading.agent_index, reading.dt
        u_outage, u_jump, length = rng.random(), rng.random(), rng.exponential()
        offset = rng.standard_normal(3) * np.asarray(self.jump_sigma)
        if dt <= 0:  # reset: a clean fix
            return gnss, attitude
        state.outage_left[i] = max(state.outage_left[i] - dt, 0.0)
        state.jump_left[i] = max(state.jump_left[i] - dt, 0.0)
        if state.outage_left[i] == 0.0 and u_outage < -math.expm1(-self.outage_rate * dt):
            state.outage_left[i] = length * self.outage_duration
        near = reading.clearance < self.jump_clearance
        if state.jump_left[i] == 0.0 and near and u_jump < -math.expm1(-self.jump_rate * dt):
            state.jump_left[i] = length * self.jump_duration
            state.jump_offset[i] = offset
        if state.outage_left[i] > 0.0 or reading.clearance < self.outage_clearance:
            return np.full(3, np.nan), attitude
        if state.jump_left[i] > 0.0:
            gnss = gnss + state.jump_offset[i]
        return gnss, attitude


NOISE_MODELS: dict[str, SensorModel] = {
    "paper": PaperNoise(),
    "gnss_ins": GnssInsNoise(),
    "gnss_degraded": DegradedGnssNoise(),
    "none": NoNoise(),
}


def make_noise(noise: str | SensorModel) -> SensorModel:
    """Resolve a noise argument: a model name (a key of :data:`NOISE_MODELS`) or a model.

    Raises:
        ConfigError: for an unknown name or an object that is not a sensor model.
    """
    return resolve_named("noise", noise, NOISE_MODELS, SensorModel, "a sensor model")
