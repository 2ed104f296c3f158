"""Telemetry samples of the bridge (SI units, NED world, FRD body), the MAVLink sources
of each quantity in order of preference, and the quaternion helpers (via io/frames).

What :class:`lpv_sysid.mavlink.telemetry.TelemetryDecoder` produces and the bridge, the
nodes and the simulated vehicle consume (decoding rules: :mod:`lpv_sysid.mavlink.telemetry`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lpv_sysid.io import frames
from lpv_sysid.mavlink.telemetry.rotor_estimate import ESC

#: attitude / position sources in order of preference (message types)
ATTITUDE_SOURCES = ("ATTITUDE_QUATERNION", "ATTITUDE", "ODOMETRY")
POSITION_SOURCES = ("LOCAL_POSITION_NED", "ODOMETRY")
MOTOR_OUTPUT_SOURCES = ("ACTUATOR_OUTPUT_STATUS", "SERVO_OUTPUT_RAW")


def quat_to_dcm(q_wxyz: np.ndarray) -> np.ndarray:
    """R_IB (seed 0 Eq. 1) from the MAVLink quaternion (w, x, y, z), via io/frames."""
    return frames.rotation_from_quaternion(q_wxyz)


def quat_to_euler(q_wxyz: np.ndarray) -> np.ndarray:
    """(phi, theta, psi) of seed 0 Eq. (1), via io/frames."""
    return frames.euler_from_quaternion(q_wxyz)


def euler_to_quat(phi: float, theta: float, psi: float) -> np.ndarray:
    """Quaternion (w, x, y, z) of R_IB(phi, theta, psi), via io/frames."""
    return frames.quaternion_from_euler(np.array([phi, theta, psi], dtype=float))


@dataclass(frozen=True)
class StateSample:
    """Vehicle state in NED/FRD: what the ``state`` topic carries (after io/frames)."""

    t: float
    t_vehicle: float
    pos_ned: np.ndarray
    vel_ned: np.ndarray
    q_wxyz: np.ndarray
    euler: np.ndarray
    v_body: np.ndarray  # (u, v, w) FRD
    omega: np.ndarray  # (p, q, r) FRD
    skew: float = 0.0  # |vehicle time of attitude - vehicle time of velocity| [s]


@dataclass(frozen=True)
class ImuSample:
    t: float
    t_vehicle: float
    accel_frd: np.ndarray  # specific force [m/s^2]
    gyro_frd: np.ndarray  # [rad/s]


@dataclass(frozen=True)
class RotorSample:
    t: float
    t_vehicle: float
    omega: np.ndarray  # rotor speeds rad/s, PX4 motor numbering 1..n
    source: str = ESC  # "esc" (ESC_STATUS) | "estimated" (motor outputs, Eq. 8)
