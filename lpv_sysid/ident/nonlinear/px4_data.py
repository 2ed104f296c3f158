"""Flight records for the PX4 variant of seed 0 Eq. (6)
(:mod:`~lpv_sysid.ident.nonlinear.px4_model`): states, IMU specific force and the motor
commands recovered from ``rotor_speeds``.

A PX4 vehicle without ESC telemetry (SIH, plain PWM ESCs) gives no rotor speeds. The bridge
publishes ``rotor_speeds`` *estimated* from PX4's motor outputs (ACTUATOR_OUTPUT_STATUS,
``mavlink/telemetry/rotor_estimate.py``) through the first-order motor model of seed 0
Eq. (8) with the airframe's ``a_Omega``, ``b_Omega`` (``config/quadrotor.yaml``)::

    Omega_hat' = -a_Omega Omega_hat + b_Omega m,      m = normalised motor output in [0, 1]

so ``x = (a_Omega / b_Omega) Omega_hat`` is the motor output ``m`` through a lag of time
constant ``1 / a_Omega``. The model needs ``m`` through the *vehicle's* motor lag ``tau``
(identified, :func:`motor_lag`): ``(1 + s / a_Omega) / (1 + tau s)`` applied to ``x``, i.e.
``c x + (1 - c) lag_tau(x)`` with ``c = 1 / (a_Omega tau)`` -- no derivative of ``x``.

Records are made from bags by ``ident.dataprep.px4_record``: one uniform grid (cubic
spline), the specific force from the ``imu`` topic (FRD, through ``io.messages``), the
angular acceleration from the global Fourier derivative of the body rates; every regressor
is smoothed by the same filter (``ident.derivatives``: the filtered equation holds exactly).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

import numpy as np

from lpv_sysid.errors import ConfigError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Px4Record:
    """One flight on a uniform grid (NED/FRD, SI); ``keep`` drops the filter edges."""

    name: str
    t: np.ndarray  # (N,) s from the record's origin
    v: np.ndarray  # (N, 3) body velocity
    omega: np.ndarray  # (N, 3) body rates
    x_motor: np.ndarray  # (N, 4) a/b Omega_hat: motor outputs through the 1/a_Omega lag
    f: np.ndarray  # (N, 3) specific force (IMU), smoothed
    omega_dot: np.ndarray  # (N, 3) angular acceleration, smoothed derivative
    a_omega: float  # 1/s of the estimator that made rotor_speeds
    smoother: Callable[[np.ndarray], np.ndarray]
    keep: slice
    at_limit: float  # fraction of samples with a rotor at the estimator's clip
    motor_period: float = 0.02  # s, median interval of the rotor_speeds stream

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])


def motor_lag(x: np.ndarray, a_omega: float, tau: float, dt: float) -> np.ndarray:
    """Motor outputs through a first-order lag ``tau`` from ``x`` (the outputs through
    ``1 / a_Omega``): ``c x + (1 - c) lag_tau(x)``, ``c = 1 / (a_Omega tau)``; the lag is
    the exact solution for ``x`` linear between samples, started in steady state.

    >>> import numpy as np
    >>> x = np.ones((5, 1)) * 0.5
    >>> bool(np.allclose(motor_lag(x, 12.0, 0.05, 0.01), 0.5))
    True
    """
    from scipy.signal import lfilter

    if not (tau > 0 and a_omega > 0 and dt > 0):
        raise ConfigError(f"motor lag: tau {tau}, a_Omega {a_omega}, dt {dt} must be > 0")
    x = np.asarray(x, dtype=float)
    al = float(np.exp(-dt / tau))
    b0 = 1.0 - tau * (1.0 - al) / dt
    b1 = (1.0 - al) - b0
    zi = (1.0 - b0) * x[0]  # steady state y = x[0] (direct form II transposed)
    lagged = lfilter([b0, b1], [1.0, -al], x, axis=0, zi=zi[None, :])[0]
    c = 1.0 / (a_omega * tau)
    return c * x + (1.0 - c) * lagged
