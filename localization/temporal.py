"""Localization over time: an error-state Kalman filter fusing visual fixes with GNSS and attitude.

One :class:`PoseFilter` per camera. Its nominal state is the camera pose ``world_from_cam``
(centre ``C`` and rotation ``R``), the GNSS bias ``b_g`` (m, project x, y, z) and the attitude
bias ``b_a`` (rad, on roll, pitch, yaw); its error state (12,) is::

    [dC (3, m), dtheta (3, rad), db_g (3, m), db_a (3, rad)]

with the package's pose parameterization (:mod:`localization.pose.pnp`): ``C = C_hat + dC`` and the
world-frame rotation vector ``R = exp([dtheta]x) R_hat``, so the first 6 x 6 block of
:attr:`PoseFilter.covariance` is directly comparable with a :class:`~localization.PoseEstimate`'s
covariance and gives the association prior's sigmas (:meth:`PoseFilter.prior_sigmas`).

    filt = PoseFilter(FilterNoise())
    filt.start(gnss, attitude)                      # first reading: pose and covariance
    filt.predict(dt, displacement=v * dt, rotation=w * dt)    # motion input, world frame
    filt.update_gnss(gnss); filt.update_attitude(attitude)
    est = localizer.localize(uv, filt.cam_from_world, prior_sigmas=filt.prior_sigmas())
    if est.success: filt.update_pose(est.cam_from_world, est.covariance)   # chi-square gated

Models (the simulator's :mod:`uav_struct_env.sim.sensors` uses the same ones; this module does not
import it):

* Motion: the caller's displacement and rotation over the step (commanded or odometry; zero
  when unknown), wrong by ``velocity_sigma * dt`` per axis and ``angular_rate_sigma * dt``.
* GNSS: ``z = C + b_g + w``, ``w ~ N(0, (s * gnss_white_sigma)^2)``; ``b_g`` a first-order
  Gauss-Markov process with stationary sigma ``s * gnss_bias_sigma`` and correlation time
  ``gnss_bias_tau``. ``s`` (>= 1, the caller's multipath factor near the structure) rescales the
  bias state when it changes: the same unit process seen through a larger factor.
* Attitude: ``z = euler(R) + b_a + w`` (roll, pitch, yaw of :mod:`localization.geometry.attitude`),
  ``b_a`` constant, ``w ~ N(0, attitude_white_sigma^2)``.
* Visual fix: a pose with its (6, 6) covariance (a :class:`~localization.PoseEstimate`).

Every update is gated by the chi-square quantile ``gate_probability`` of its degrees of freedom
on the normalized innovation squared (NIS); a rejected update leaves the state unchanged and is
reported in the returned :class:`Update`. A fix far from the prediction (a wrong association)
and a multipath jump of the GNSS are rejected this way.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from localization.geometry.attitude import attitude_from_world_from_cam, world_from_cam_from_attitude
from localization.geometry.transforms import check_transform, invert, so3_exp
from localization.pose.covariance import PriorSigmas, pose_difference
from localization.stats import chi2_quantile

__all__ = ["FilterNoise", "PoseFilter", "Update", "attitude_of"]

_N = 12  # error-state dimension
_C, _TH, _BG, _BA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
#: Standard deviations of the "unknown" pose before the first reading (m, rad).
_UNKNOWN_POSITION_M = 1.0e3
_UNKNOWN_ROTATION_RAD = 1.0
#: cos(pitch) below which roll and yaw are degenerate (gimbal lock): no attitude update.
_GIMBAL_LOCK_COS = 0.05


def _triple(owner: str, name: str, value: ArrayLike) -> tuple[float, float, float]:
    arr = np.asarray(value, dtype=np.float64).reshape(-1) if not isinstance(value, str) else None
    if arr is None or arr.shape != (3,):
        raise ValueError(f"{owner}.{name} must be three non-negative numbers, got {value!r}")
    return tuple(check_number(f"{owner}.{name}[{k}]", float(x), 0) for k, x in enumerate(arr))


def _wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def attitude_of(world_from_cam: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Roll, pitch, yaw of a camera pose, without scipy's gimbal-lock warning.

    As :func:`~localization.geometry.attitude.attitude_from_world_from_cam`.

    At pitch +-90 deg (a camera looking straight down) roll and yaw are not separable; the
    filter then skips the attitude update and says so (:meth:`PoseFilter.update_attitude`).
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected", category=UserWarning)
        return attitude_from_world_from_cam(world_from_cam)


@dataclass(frozen=True)
class FilterNoise:
    """Noise model of a :class:`PoseFilter` (SI units, rad).

    The GNSS and attitude defaults are the ``gnss_ins`` sensor model's
    (:class:`uav_struct_env.sim.sensors.GnssInsNoise`, which documents their sources).

    Attributes:
        velocity_sigma: error of the motion input, m/s per axis (wind, tracking error).
        angular_rate_sigma: error of the rotation input, rad/s per axis.
        gnss_white_sigma: (3,) GNSS white noise, m (x, y, z).
        gnss_bias_sigma: (3,) stationary sigma of the GNSS Gauss-Markov bias, m.
        gnss_bias_tau: its correlation time, s.
        attitude_white_sigma: (3,) attitude white noise, rad (roll, pitch, yaw).
        attitude_bias_sigma: (3,) constant attitude bias sigma, rad.
        estimate_gnss_bias: keep ``b_g`` in the state; otherwise the bias is folded into each
            GNSS reading's noise as if it were white (the ablation of docs/temporal.md).
        estimate_attitude_bias: likewise for ``b_a``.
        gate_probability: chi-square quantile of every update's gate.
        max_rejections: after this many consecutive rejected GNSS or attitude readings the next
            one is fused ungated, the part of the pose it measures (position or rotation) reset
            to unknown first: the filter is then more likely wrong than the sensor (a wrong
            visual fix accepted, a disturbance beyond the motion noise). An accepted visual fix
            restarts the count (it confirms the filter). Visual fixes are always gated.
        min_prior_sigmas: floors of :meth:`PoseFilter.prior_sigmas`: (position m, rotation rad).
    """

    velocity_sigma: float = 0.5
    angular_rate_sigma: float = math.radians(2.0)
    gnss_white_sigma: tuple[float, float, float] = (0.4, 0.4, 0.7)
    gnss_bias_sigma: tuple[float, float, float] = (1.5, 1.5, 2.5)
    gnss_bias_tau: float = 120.0
    attitude_white_sigma: tuple[float, float, float] = tuple(math.radians(d) for d in (0.2, 0.2, 0.5))
    attitude_bias_sigma: tuple[float, float, float] = tuple(math.radians(d) for d in (1.0, 1.0, 2.5))
    estimate_gnss_bias: bool = True
    estimate_attitude_bias: bool = True
    gate_probability: float = 0.999
    max_rejections: int = 10
    min_prior_sigmas: tuple[float, float] = (0.05, math.radians(0.1))

    def __post_init__(self) -> None:
        for name in ("velocity_sigma", "angular_rate_sigma"):
            check_number(f"FilterNoise.{name}", getattr(self, name), 0)
        for name in ("gnss_white_sigma", "gnss_bias_sigma", "attitude_white_sigma", "attitude_bias_sigma"):
            object.__setattr__(self, name, _triple("FilterNoise", name, getattr(self, name)))
        check_number("FilterNoise.gnss_bias_tau", self.gnss_bias_tau, 0, lo_open=True)
        check_number("FilterNoise.gate_probability", self.gate_probability, 0, 1, lo_open=True, hi_open=True)
        check_number("FilterNoise.max_rejections", self.max_rejections, 1, integer=True)
        floors = tuple(self.min_prior_sigmas)
        if len(floors) != 2:
            raise ValueError(
                f"FilterNoise.min_prior_sigmas must be (position_m, rotation_rad), got {floors!r}"
            )
        for k, x in enumerate(floors):
            check_number(f"FilterNoise.min_prior_sigmas[{k}]", x, 0, lo_open=True)
        if min(self.gnss_white_sigma) <= 0 or min(self.attitude_white_sigma) <= 0:
            raise ValueError(
                "FilterNoise: the white-noise sigmas must be positive (a reading is never exact), "
                f"got gnss {self.gnss_white_sigma}, attitude {self.attitude_white_sigma}"
            )

    def gate(self, dof: int) -> float:
        """The chi-square gate of an update with ``dof`` degrees of freedom."""
        return chi2_quantile(self.gate_probability, dof)


@dataclass(frozen=True)
class Update:
    """The outcome of one measurement update.

    Attributes:
        kind: ``"pose"``, ``"gnss"`` or ``"attitude"``.
        accepted: the update was applied (NIS within the gate).
        nis: normalized innovation squared ``y^T S^-1 y`` (NaN when not computed).
        gate: the chi-square gate it was compared with.
        reason: why it was rejected (with the numbers), or why an inconsistent reading was
            fused anyway (``max_rejections``); None for a consistent accepted update.
    """

    kind: str
    accepted: bool
    nis: float
    gate: float
    reason: str | None = None


class PoseFilter:
    """Error-state Kalman filter of one camera's pose (module docstring).

    Args:
        noise: the :class:`FilterNoise` model (default: the ``gnss_ins`` sensor model's values).

    Raises:
        TypeError: if ``noise`` is not a :class:`FilterNoise`.
    """

    def __init__(self, noise: FilterNoise | None = None) -> None:
        noise = FilterNoise() if noise is None else noise
        if not isinstance(noise, FilterNoise):
            raise TypeError(f"noise must be a FilterNoise, got {type(noise).__name__}")
        self.noise = noise
        self._started = False
        self.position = np.zeros(3)
        self.rotation = np.eye(3)  # R_wc
        self.gnss_bias = np.zeros(3)
        self.attitude_bias = np.zeros(3)
        self.covariance = np.zeros((_N, _N))
        self._bias_scale = 1.0
        self._rejections = {"gnss": 0, "attitude": 0}

    # ------------------------------------------------------------------ state
    @property
    def started(self) -> bool:
        """True once :meth:`start` (or :meth:`reset_pose`) has set a pose."""
        return self._started

    @property
    def world_from_cam(self) -> NDArray[np.float64]:
        """(4, 4) the filtered ``world_from_cam``."""
        out = np.eye(4)
        out[:3, :3] = self.rotation
        out[:3, 3] = self.position
        return out

    @property
    def cam_from_world(self) -> NDArray[np.float64]:
        """(4, 4) the filtered ``cam_from_world``."""
        return invert(self.world_from_cam)

    @property
    def pose_covariance(self) -> NDArray[np.float64]:
        """(6, 6) covariance of the pose in the ``(C, dtheta)`` parameterization."""
        return self.covariance[:6, :6].copy()

    @property
    def pose_std(self) -> NDArray[np.float64]:
        """(6,) standard deviations of the pose: position x, y, z [m], rotation [rad]."""
        return np.sqrt(np.maximum(np.diag(self.covariance)[:6], 0.0))

    def prior_sigmas(self) -> PriorSigmas:
        """The pose's marginal sigmas as the association prior's, floored by ``min_prior_sigmas``."""
        std = self.pose_std
        pos_floor, rot_floor = self.noise.min_prior_sigmas
        return PriorSigmas(
            tuple(np.maximum(std[:3], pos_floor).tolist()), tuple(np.maximum(std[3:], rot_floor).tolist())
        )

    # ------------------------------------------------------------------ start
    def reset_pose(
        self, world_from_cam: ArrayLike, position_sigma: ArrayLike, rotation_sigma: ArrayLike
    ) -> None:
        """Set the pose with independent sigmas (m, rad); biases at zero with their model sigmas."""
        T = check_transform("world_from_cam", world_from_cam)
        pos_sig = np.broadcast_to(np.asarray(position_sigma, dtype=np.float64), (3,))
        rot_sig = np.broadcast_to(np.asarray(rotation_sigma, dtype=np.float64), (3,))
        if not (np.all(np.isfinite(pos_sig)) and np.all(pos_sig > 0) and np.all(np.isfinite(rot_sig))
                and np.all(rot_sig > 0)):
            raise ValueError(
                f"position_sigma and rotation_sigma must be positive and finite, got "
                f"{pos_sig.tolist()} and {rot_sig.tolist()}"
            )
        self.position = T[:3, 3].copy()
        self.rotation = T[:3, :3].copy()
        self.gnss_bias = np.zeros(3)
        self.attitude_bias = np.zeros(3)
        self._bias_scale = 1.0
        self._rejections = {"gnss": 0, "attitude": 0}
        n = self.noise
        self.covariance = np.diag(np.concatenate([
            pos_sig**2,
            rot_sig**2,
            np.square(n.gnss_bias_sigma) if n.estimate_gnss_bias else np.zeros(3),
            np.square(n.attitude_bias_sigma) if n.estimate_attitude_bias else np.zeros(3),
        ]))
        self._started = True

    def start(self, gnss: ArrayLike, attitude: ArrayLike, *, gnss_scale: float = 1.0) -> list[Update]:
        """Start from the first GNSS + attitude reading (a pose with the sensors' covariance).

        The pose is first set unknown (1 km, 1 rad) at the reading, then both readings are
        applied as updates, so the position error and the bias start correlated as they are.
        ``gnss`` may be None (no fix): the position then stays unknown until a fix or a pose.
        """
        att = self._vector("attitude", attitude)
        guess = world_from_cam_from_attitude(np.zeros(3) if gnss is None else self._vector("gnss", gnss), att)
        self.reset_pose(guess, _UNKNOWN_POSITION_M, _UNKNOWN_ROTATION_RAD)
        self._bias_scale = self._check_scale(gnss_scale)
        out = [self.update_attitude(att)]
        if gnss is not None:
            out.append(self.update_gnss(gnss, scale=gnss_scale))
        return out

    # ------------------------------------------------------------------ predict
    def predict(
        self,
        dt: float,
        displacement: ArrayLike | None = None,
        rotation: ArrayLike | None = None,
        *,
        gnss_scale: float | None = None,
    ) -> None:
        """Propagate over ``dt`` s with the motion input (world frame; zero when None).

        Args:
            dt: time step, s (>= 0).
            displacement: (3,) camera-centre displacement over the step, m, project frame.
            rotation: (3,) world-frame rotation vector of the step, rad (``R <- exp(rotation) R``).
            gnss_scale: the GNSS error factor (multipath) at the new position; None keeps it.
        """
        self._check_started()
        dt = check_number("dt", dt, 0)
        d = np.zeros(3) if displacement is None else self._vector("displacement", displacement)
        r = np.zeros(3) if rotation is None else self._vector("rotation", rotation)
        n = self.noise
        step_rot = so3_exp(r)
        F = np.eye(_N)
        F[_TH, _TH] = step_rot  # R' = exp(r) exp(dtheta) R_hat = exp(exp(r) dtheta) exp(r) R_hat
        Q = np.zeros((_N, _N))
        Q[_C, _C] = np.eye(3) * (n.velocity_sigma * dt) ** 2
        Q[_TH, _TH] = np.eye(3) * (n.angular_rate_sigma * dt) ** 2
        new_scale = self._bias_scale if gnss_scale is None else self._check_scale(gnss_scale)
        if n.estimate_gnss_bias:
            phi = math.exp(-dt / n.gnss_bias_tau)
            gain = phi * new_scale / self._bias_scale
            F[_BG, _BG] = np.eye(3) * gain
            self.gnss_bias = gain * self.gnss_bias
            Q[_BG, _BG] = np.diag((new_scale * np.asarray(n.gnss_bias_sigma)) ** 2 * (1.0 - phi * phi))
        self._bias_scale = new_scale
        self.position = self.position + d
        self.rotation = step_rot @ self.rotation
        self.covariance = F @ self.covariance @ F.T + Q
        self._symmetrize()

    # ------------------------------------------------------------------ updates
    def update_gnss(self, gnss: ArrayLike, *, scale: float = 1.0) -> Update:
        """Fuse one GNSS position (3,), m; ``scale`` multiplies its noise (multipath factor)."""
        self._check_started()
        z = self._vector("gnss", gnss)
        scale = self._check_scale(scale)
        n = self.noise
        H = np.zeros((3, _N))
        H[:, _C] = np.eye(3)
        var = (scale * np.asarray(n.gnss_white_sigma)) ** 2
        if n.estimate_gnss_bias:
            H[:, _BG] = np.eye(3)
        else:
            var = var + (scale * np.asarray(n.gnss_bias_sigma)) ** 2
        y = z - (self.position + self.gnss_bias)
        return self._update("gnss", y, H, np.diag(var))

    def update_attitude(self, attitude: ArrayLike) -> Update:
        """Fuse one (roll, pitch, yaw) reading, rad (:mod:`localization.geometry.attitude`)."""
        self._check_started()
        z = self._vector("attitude", attitude)
        _, est = attitude_of(self.world_from_cam)
        if abs(math.cos(est[1])) < _GIMBAL_LOCK_COS:
            return Update("attitude", False, float("nan"), self.noise.gate(3),
                          f"pitch {math.degrees(est[1]):.1f} deg is at gimbal lock: roll and yaw undefined")
        n = self.noise
        H = np.zeros((3, _N))
        H[:, _TH] = self._euler_jacobian(est)
        var = np.square(n.attitude_white_sigma)
        if n.estimate_attitude_bias:
            H[:, _BA] = np.eye(3)
        else:
            var = var + np.square(n.attitude_bias_sigma)
        y = _wrap(z - est - self.attitude_bias)
        return self._update("attitude", y, H, np.diag(var))

    def update_pose(self, cam_from_world: ArrayLike, covariance: ArrayLike) -> Update:
        """Fuse a visual fix: a ``cam_from_world`` (4, 4) with its (6, 6) ``(C, dtheta)`` covariance.

        Rejected (state unchanged) when its NIS against the prediction exceeds the 6-dof gate
        or its covariance is not finite and positive definite.
        """
        self._check_started()
        T = check_transform("cam_from_world", cam_from_world)
        cov = np.asarray(covariance, dtype=np.float64)
        if cov.shape != (6, 6):
            raise ValueError(f"covariance must have shape (6, 6), got {cov.shape}")
        gate = self.noise.gate(6)
        if not np.all(np.isfinite(cov)):
            return Update("pose", False, float("nan"), gate, "the fix's covariance is not finite")
        y = pose_difference(T, self.cam_from_world)
        H = np.zeros((6, _N))
        H[:, :6] = np.eye(6)
        return self._update("pose", y, H, 0.5 * (cov + cov.T))

    # ------------------------------------------------------------------ internals
    def _update(self, kind: str, y: NDArray, H: NDArray, R: NDArray) -> Update:
        P = self.covariance
        S = H @ P @ H.T + R
        gate = self.noise.gate(len(y))
        try:
            nis = float(y @ np.linalg.solve(S, y))
            K = np.linalg.solve(S, H @ P).T
        except np.linalg.LinAlgError:
            return Update(kind, False, float("nan"), gate, f"the {kind} innovation covariance is singular")
        if not np.isfinite(nis) or nis < 0:
            return Update(
                kind, False, nis, gate, f"the {kind} innovation covariance is not positive definite"
            )
        reason = None
        if nis > gate:
            reason = (f"{kind} inconsistent with the prediction: NIS {nis:.3g} > gate {gate:.3g} "
                      f"(chi-square {len(y)} dof, p = {self.noise.gate_probability})")
            streak = self._rejections.get(kind)
            if streak is None or streak < self.noise.max_rejections:
                if streak is not None:
                    self._rejections[kind] = streak + 1
                return Update(kind, False, nis, gate, reason)
            reason = f"fused after {streak} rejections in a row, the pose part it measures reset: {reason}"
            # the pose was wrong, not the sensor: what this sensor measures of the pose (position
            # or rotation) starts again unknown, so the reading sets it and the biases keep theirs
            dims = [d for d in range(6) if np.any(H[:, d])]
            P = self.covariance.copy()
            P[dims, :] = 0.0
            P[:, dims] = 0.0
            unknown = _UNKNOWN_POSITION_M if dims[0] < 3 else _UNKNOWN_ROTATION_RAD
            P[dims, dims] = unknown**2
            self.covariance = P
            S = H @ P @ H.T + R
            K = np.linalg.solve(S, H @ P).T
        if kind in self._rejections:
            self._rejections[kind] = 0
        else:  # an accepted visual fix confirms the filter: the sensors' streaks start again
            self._rejections = dict.fromkeys(self._rejections, 0)
        dx = K @ y
        I_KH = np.eye(_N) - K @ H
        self.covariance = I_KH @ P @ I_KH.T + K @ R @ K.T  # Joseph form
        self.position = self.position + dx[_C]
        self.rotation = so3_exp(dx[_TH]) @ self.rotation
        self.gnss_bias = self.gnss_bias + dx[_BG]
        self.attitude_bias = self.attitude_bias + dx[_BA]
        self._symmetrize()
        return Update(kind, True, nis, gate, reason)

    def _euler_jacobian(self, euler: NDArray[np.float64], h: float = 1e-6) -> NDArray[np.float64]:
        """Jacobian of ``euler(exp(dtheta) R)`` in ``dtheta`` at 0 (central differences)."""
        J = np.zeros((3, 3))
        T = self.world_from_cam
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            Tp, Tm = T.copy(), T.copy()
            Tp[:3, :3] = so3_exp(e) @ self.rotation
            Tm[:3, :3] = so3_exp(-e) @ self.rotation
            diff = attitude_of(Tp)[1] - attitude_of(Tm)[1]
            J[:, k] = _wrap(diff) / (2 * h)
        return J

    def _symmetrize(self) -> None:
        self.covariance = 0.5 * (self.covariance + self.covariance.T)

    def _check_started(self) -> None:
        if not self._started:
            raise RuntimeError("PoseFilter used before start() or reset_pose(): give it a first pose")

    @staticmethod
    def _check_scale(scale: float) -> float:
        return check_number("gnss_scale", scale, 0, lo_open=True)

    @staticmethod
    def _vector(name: str, value: ArrayLike) -> NDArray[np.float64]:
        try:
            arr = np.asarray(value, dtype=np.float64).reshape(3)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be three numbers, got {value!r}") from None
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite, got {arr.tolist()}")
        return arr
