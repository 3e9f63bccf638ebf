"""``PreintegrationParams``: IMU noise, gravity, sensor pose and Coriolis (GTSAM's
``PreintegrationParams`` / ``PreintegrationCombinedParams`` in one frozen dataclass).

Noise is given as continuous-time densities (GTSAM's covariances are their squares; a
covariance ``S`` adds ``S / dt`` per sample for white noise, ``S dt`` for random walks).
``make_u`` / ``make_d`` take the square roots: ``gyro_sigma`` (rad/s/sqrt(Hz)),
``accel_sigma`` (m/s^2/sqrt(Hz)), ``integration_sigma`` (m/sqrt(s): position uncertainty added
by integrating, ``S dt``), ``bias_acc_rw_sigma`` ((m/s^2)/sqrt(s)) and ``bias_gyro_rw_sigma``
((rad/s)/sqrt(s)), the bias random walks. A scalar is isotropic, three numbers are per axis; a
full 3x3 covariance can be given instead with the ``*_covariance`` argument of the same
quantity. The dataclass fields are the covariances, with GTSAM's names
(``gyroscope_covariance = gyro_sigma**2 I`` ...).

``error_mode`` selects the IMU factors' residual chart as GTSAM 4.3's ``ImuFactorErrorMode``:
``"logmap"`` (default; the SE_2(3) logarithm of ``X_j^-1 X_predicted``) or
``"component_wise"`` (GTSAM <= 4.2: ``X_j.localCoordinates(X_predicted)``). Both have the same
first-order behaviour; they differ at second order in the rotation error.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import DimensionMismatchError, FgoptError, NonFiniteError, NotPositiveDefiniteError
from ..manifolds import SE3

ERROR_MODES = ("logmap", "component_wise")


def _covariance(value: Any, name: str, definite: bool) -> np.ndarray:
    """A symmetric PSD (``definite``: PD) 3x3 read-only copy, or a clear error."""
    try:
        m = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DimensionMismatchError(f"PreintegrationParams.{name}: expected a 3x3 matrix, "
                                     f"got {value!r}") from exc
    if m.shape != (3, 3):
        raise DimensionMismatchError(f"PreintegrationParams.{name}: expected a 3x3 matrix, "
                                     f"got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise NonFiniteError(f"PreintegrationParams.{name} has NaN/inf: {m.tolist()}")
    if np.max(np.abs(m - m.T)) > 1e-12 * max(1.0, float(np.max(np.abs(m)))):
        raise NotPositiveDefiniteError(f"PreintegrationParams.{name} is not symmetric: "
                                       f"{m.tolist()}")
    m = 0.5 * (m + m.T)
    lo = float(np.min(np.linalg.eigvalsh(m)))
    if (lo <= 0.0) if definite else (lo < -1e-12 * max(1.0, float(np.max(np.abs(m))))):
        kind = "positive definite" if definite else "positive semi-definite"
        raise NotPositiveDefiniteError(
            f"PreintegrationParams.{name} must be {kind} (smallest eigenvalue {lo:.3g}); "
            "give sigmas > 0 or a valid covariance")
    m.flags.writeable = False
    return m


def _from_sigma(sigma: Any, covariance: Any, name: str, sigma_name: str,
                default: Any) -> Any:
    if sigma is not None and covariance is not None:
        raise FgoptError(f"give {sigma_name} or {name}, not both")
    if covariance is not None:
        return covariance
    if sigma is None:
        return default
    s = np.array(sigma, dtype=float).reshape(-1)
    if s.shape[0] not in (1, 3):
        raise DimensionMismatchError(f"{sigma_name}: expected 1 or 3 numbers, got {s.shape[0]}")
    if not np.all(np.isfinite(s)):
        raise NonFiniteError(f"{sigma_name} has NaN/inf: {s.tolist()}")
    if np.any(s < 0):
        raise NotPositiveDefiniteError(f"{sigma_name} must be >= 0, got {s.tolist()}")
    return np.diag(np.broadcast_to(s * s, (3,)))


@dataclass(frozen=True, eq=False)
class PreintegrationParams:
    """IMU preintegration parameters (module docstring). Use :meth:`make_u` / :meth:`make_d`.

    Example:

    >>> from fgopt.navigation import PreintegrationParams
    >>> p = PreintegrationParams.make_u(9.81, accel_sigma=0.01, gyro_sigma=1e-3)
    >>> p.n_gravity
    array([ 0.  ,  0.  , -9.81])
    """

    n_gravity: np.ndarray
    """Gravity in the navigation frame (m/s^2), e.g. ``[0, 0, -9.81]`` for Z up."""
    accelerometer_covariance: Any = field(default_factory=lambda: np.eye(3))
    """Continuous-time accelerometer white-noise covariance ((m/s^2)^2/Hz); GTSAM default I."""
    gyroscope_covariance: Any = field(default_factory=lambda: np.eye(3))
    """Continuous-time gyroscope white-noise covariance ((rad/s)^2/Hz); GTSAM default I."""
    integration_covariance: Any = field(default_factory=lambda: np.eye(3))
    """Position-integration uncertainty (m^2/s, added as ``Si dt``); GTSAM default I."""
    bias_acc_covariance: Any = None
    """Accelerometer bias random walk ((m/s^2)^2/s); needed by the combined factor."""
    bias_omega_covariance: Any = None
    """Gyroscope bias random walk ((rad/s)^2/s); needed by the combined factor."""
    body_P_sensor: SE3 | None = None
    """Pose of the IMU in the body frame (``None``: the IMU frame is the body frame)."""
    omega_coriolis: Any = None
    """Angular velocity of the navigation frame (rad/s, in that frame), e.g. Earth rate; the
    prediction uses the exact rotating-frame dynamics (as GTSAM 4.3)."""
    error_mode: str = "logmap"
    """``"logmap"`` (GTSAM 4.3 default) or ``"component_wise"``; see the module docstring."""

    def __post_init__(self) -> None:
        g = np.array(self.n_gravity, dtype=float).reshape(-1)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise DimensionMismatchError(f"PreintegrationParams.n_gravity: expected 3 finite "
                                         f"numbers, got {self.n_gravity!r}")
        g.flags.writeable = False
        set_ = object.__setattr__
        set_(self, "n_gravity", g)
        set_(self, "accelerometer_covariance",
             _covariance(self.accelerometer_covariance, "accelerometer_covariance", True))
        set_(self, "gyroscope_covariance",
             _covariance(self.gyroscope_covariance, "gyroscope_covariance", True))
        set_(self, "integration_covariance",
             _covariance(self.integration_covariance, "integration_covariance", False))
        for name in ("bias_acc_covariance", "bias_omega_covariance"):
            v = getattr(self, name)
            if v is not None:
                set_(self, name, _covariance(v, name, False))
        if self.body_P_sensor is not None and not isinstance(self.body_P_sensor, SE3):
            raise FgoptError(f"PreintegrationParams.body_P_sensor: expected an fgopt SE3, got "
                             f"{type(self.body_P_sensor).__name__}")
        if self.omega_coriolis is not None:
            w = np.array(self.omega_coriolis, dtype=float).reshape(-1)
            if w.shape != (3,) or not np.all(np.isfinite(w)):
                raise DimensionMismatchError(f"PreintegrationParams.omega_coriolis: expected 3 "
                                             f"finite numbers, got {self.omega_coriolis!r}")
            w.flags.writeable = False
            set_(self, "omega_coriolis", w)
        if self.error_mode not in ERROR_MODES:
            raise FgoptError(f"PreintegrationParams.error_mode must be one of {ERROR_MODES}, "
                             f"got {self.error_mode!r}")

    @classmethod
    def make_u(cls, g: float = 9.81, **kwargs: Any) -> PreintegrationParams:
        """Z-up navigation frame (ENU-like): gravity ``[0, 0, -g]``. Keyword arguments as
        :meth:`make`."""
        return cls.make([0.0, 0.0, -float(g)], **kwargs)

    @classmethod
    def make_d(cls, g: float = 9.81, **kwargs: Any) -> PreintegrationParams:
        """Z-down navigation frame (NED): gravity ``[0, 0, g]``. Keyword arguments as
        :meth:`make`."""
        return cls.make([0.0, 0.0, float(g)], **kwargs)

    @classmethod
    def make(cls, n_gravity: Any, *, gyro_sigma: Any = None, accel_sigma: Any = None,
             integration_sigma: Any = None, bias_acc_rw_sigma: Any = None,
             bias_gyro_rw_sigma: Any = None, gyroscope_covariance: Any = None,
             accelerometer_covariance: Any = None, integration_covariance: Any = None,
             bias_acc_covariance: Any = None, bias_omega_covariance: Any = None,
             body_P_sensor: SE3 | None = None, omega_coriolis: Any = None,
             error_mode: str = "logmap") -> PreintegrationParams:
        """Parameters from noise densities (sigmas; scalar or per axis) or covariances.

        Unset accelerometer / gyroscope / integration noise keeps GTSAM's default (identity
        covariance); unset bias random walks stay ``None`` (only the combined factor needs them).
        """
        eye = np.eye(3)
        return cls(
            n_gravity=n_gravity,
            accelerometer_covariance=_from_sigma(accel_sigma, accelerometer_covariance,
                                                 "accelerometer_covariance", "accel_sigma", eye),
            gyroscope_covariance=_from_sigma(gyro_sigma, gyroscope_covariance,
                                             "gyroscope_covariance", "gyro_sigma", eye),
            integration_covariance=_from_sigma(integration_sigma, integration_covariance,
                                               "integration_covariance", "integration_sigma", eye),
            bias_acc_covariance=_from_sigma(bias_acc_rw_sigma, bias_acc_covariance,
                                            "bias_acc_covariance", "bias_acc_rw_sigma", None),
            bias_omega_covariance=_from_sigma(bias_gyro_rw_sigma, bias_omega_covariance,
                                              "bias_omega_covariance", "bias_gyro_rw_sigma", None),
            body_P_sensor=body_P_sensor, omega_coriolis=omega_coriolis, error_mode=error_mode)

    def replace(self, **changes: Any) -> PreintegrationParams:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)

    def __repr__(self) -> str:
        def sig(m: Any) -> str:
            if m is None:
                return "None"
            d = np.sqrt(np.diag(m))
            return f"{d[0]:.3g}" if np.allclose(m, d[0] ** 2 * np.eye(3)) else \
                "[" + ", ".join(f"{x:.3g}" for x in d) + "]"
        parts = [f"n_gravity={self.n_gravity.tolist()}",
                 f"accel_sigma={sig(self.accelerometer_covariance)}",
                 f"gyro_sigma={sig(self.gyroscope_covariance)}",
                 f"integration_sigma={sig(self.integration_covariance)}",
                 f"bias_acc_rw_sigma={sig(self.bias_acc_covariance)}",
                 f"bias_gyro_rw_sigma={sig(self.bias_omega_covariance)}"]
        if self.body_P_sensor is not None:
            parts.append(f"body_P_sensor={self.body_P_sensor!r}")
        if self.omega_coriolis is not None:
            parts.append(f"omega_coriolis={self.omega_coriolis.tolist()}")
        parts.append(f"error_mode={self.error_mode!r}")
        return "PreintegrationParams(" + ", ".join(parts) + ")"
