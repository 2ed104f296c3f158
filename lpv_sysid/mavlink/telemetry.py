"""Decode PX4 telemetry into core samples (SI units, NED world, FRD body).

MAVLink sources (PX4 sends all of them in NED/FRD):
- ATTITUDE_QUATERNION: q = (w, x, y, z) rotating FRD into NED, body rates p, q, r [rad/s]
- ATTITUDE: Euler angles (fallback when ATTITUDE_QUATERNION is not streamed)
- LOCAL_POSITION_NED: position and velocity in NED [m, m/s]
- ODOMETRY: position, quaternion, velocity (frame given by ``child_frame_id``), rates
- HIGHRES_IMU: specific force [m/s^2] and rates [rad/s] in FRD
- ESC_STATUS: motor speeds [rpm] -> Omega [rad/s] = |rpm| * 2 pi / 60 (PX4 numbering:
  ESC i drives rotor i of the quad-X of DESIGN.md; the seed's Omega is a speed magnitude)

The body velocity of seed 0 (u, v, w) is ``R_IB^T v_ned`` (seed 0 Eq. 1, R_IB maps FRD
into NED); rotations and quaternion conventions come from ``lpv_sysid.io.frames``. Each sample carries the receive time ``t`` (the caller's clock) and the
vehicle's own timestamp ``t_vehicle``; messages whose vehicle timestamp goes backwards
are dropped and counted (``out_of_order``), and :meth:`TelemetryDecoder.staleness`
reports the age of every stream.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from lpv_sysid.io import frames

RPM_TO_RAD_S = 2.0 * math.pi / 60.0


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
    v_body: np.ndarray          # (u, v, w) FRD
    omega: np.ndarray           # (p, q, r) FRD
    skew: float = 0.0           # |vehicle time of attitude - vehicle time of velocity| [s]


@dataclass(frozen=True)
class ImuSample:
    t: float
    t_vehicle: float
    accel_frd: np.ndarray       # specific force [m/s^2]
    gyro_frd: np.ndarray        # [rad/s]


@dataclass(frozen=True)
class RotorSample:
    t: float
    t_vehicle: float
    omega: np.ndarray           # rotor speeds rad/s, PX4 motor numbering 1..n


@dataclass
class TelemetryStats:
    decoded: int = 0
    out_of_order: int = 0
    invalid: int = 0


@dataclass
class _Latest:
    t: float = -math.inf            # receive time
    tv: float = -math.inf           # vehicle time
    value: Any = None


STREAMS = ("attitude", "position", "imu", "rotors")


class TelemetryDecoder:
    """Turns MAVLink messages into :class:`StateSample`, :class:`ImuSample`, :class:`RotorSample`.

    ``on_message(msg, now)`` returns the new samples (possibly empty). A
    :class:`StateSample` is produced on every attitude or velocity update once both are
    known and neither is older than ``max_age`` seconds.
    """

    def __init__(self, n_rotors: int = 4, max_age: float = 0.5) -> None:
        self.n_rotors = n_rotors
        self.max_age = max_age
        self.stats = TelemetryStats()
        self._latest = {k: _Latest() for k in STREAMS}
        self._rotors = np.full(n_rotors, np.nan)
        self._handlers = {
            "ATTITUDE_QUATERNION": self._attitude_quaternion,
            "ATTITUDE": self._attitude_euler,
            "LOCAL_POSITION_NED": self._local_position,
            "ODOMETRY": self._odometry,
            "HIGHRES_IMU": self._highres_imu,
            "ESC_STATUS": self._esc_status,
        }

    # ------------------------------------------------------------------ API
    def on_message(self, msg: Any, now: float) -> list[Any]:
        h = self._handlers.get(msg.get_type())
        if h is None:
            return []
        try:
            out = h(msg, now)
        except (ValueError, ArithmeticError, TypeError):
            self.stats.invalid += 1
            return []
        if out is not None:
            self.stats.decoded += 1
        return out or []

    def staleness(self, now: float) -> dict[str, float]:
        """Age [s] of the newest message of each stream (inf if never received)."""
        return {k: now - v.t for k, v in self._latest.items()}

    def latest_state(self, now: float) -> StateSample | None:
        return self._state(now)

    # ------------------------------------------------------------- handlers
    def _accept(self, stream: str, tv: float, now: float, value: Any) -> bool:
        lat = self._latest[stream]
        if tv < lat.tv and lat.tv - tv < 10.0:     # > 10 s back: vehicle reboot, accept
            self.stats.out_of_order += 1
            return False
        lat.t, lat.tv, lat.value = now, tv, value
        return True

    def _attitude_quaternion(self, m: Any, now: float) -> list[Any] | None:
        n = math.sqrt(m.q1 * m.q1 + m.q2 * m.q2 + m.q3 * m.q3 + m.q4 * m.q4)
        if not math.isfinite(n) or n < 0.5:
            raise ValueError("invalid quaternion")
        q = np.array([m.q1 / n, m.q2 / n, m.q3 / n, m.q4 / n])
        omega = np.array([m.rollspeed, m.pitchspeed, m.yawspeed], dtype=float)
        if not (math.isfinite(m.rollspeed) and math.isfinite(m.pitchspeed) and math.isfinite(m.yawspeed)):
            raise ValueError("invalid rates")
        if not self._accept("attitude", m.time_boot_ms * 1e-3, now, (q, omega)):
            return None
        return self._state_list(now)

    def _attitude_euler(self, m: Any, now: float) -> list[Any] | None:
        e = (m.roll, m.pitch, m.yaw)
        if not all(math.isfinite(v) for v in e):
            raise ValueError("invalid euler")
        q = euler_to_quat(*e)
        omega = np.array([m.rollspeed, m.pitchspeed, m.yawspeed], dtype=float)
        if not self._accept("attitude", m.time_boot_ms * 1e-3, now, (q, omega)):
            return None
        return self._state_list(now)

    def _local_position(self, m: Any, now: float) -> list[Any] | None:
        if not all(math.isfinite(v) for v in (m.x, m.y, m.z, m.vx, m.vy, m.vz)):
            raise ValueError("invalid position")
        pos = np.array([m.x, m.y, m.z], dtype=float)
        vel = np.array([m.vx, m.vy, m.vz], dtype=float)
        if not self._accept("position", m.time_boot_ms * 1e-3, now, (pos, vel)):
            return None
        return self._state_list(now)

    def _odometry(self, m: Any, now: float) -> list[Any] | None:
        # MAV_FRAME_LOCAL_NED=1 pose; velocity frame child_frame_id: BODY_FRD=12 or LOCAL_NED=1
        q = np.array(m.q, dtype=float)
        if not np.isfinite(q).all() or np.linalg.norm(q) < 0.5:
            raise ValueError("invalid quaternion")
        q /= np.linalg.norm(q)
        v = np.array([m.vx, m.vy, m.vz], dtype=float)
        vel_ned = quat_to_dcm(q) @ v if m.child_frame_id in (8, 12) else v
        tv = m.time_usec * 1e-6
        omega = np.array([m.rollspeed, m.pitchspeed, m.yawspeed], dtype=float)
        ok_a = self._accept("attitude", tv, now, (q, omega))
        ok_p = self._accept("position", tv, now, (np.array([m.x, m.y, m.z], dtype=float), vel_ned))
        return self._state_list(now) if (ok_a or ok_p) else None

    def _highres_imu(self, m: Any, now: float) -> list[Any] | None:
        acc = np.array([m.xacc, m.yacc, m.zacc], dtype=float)
        gyr = np.array([m.xgyro, m.ygyro, m.zgyro], dtype=float)
        if not (np.isfinite(acc).all() and np.isfinite(gyr).all()):
            raise ValueError("invalid imu")
        tv = m.time_usec * 1e-6
        if not self._accept("imu", tv, now, None):
            return None
        return [ImuSample(now, tv, acc, gyr)]

    def _esc_status(self, m: Any, now: float) -> list[Any] | None:
        tv = m.time_usec * 1e-6
        base = int(m.index)
        for i, rpm in enumerate(m.rpm):
            k = base + i
            if k < self.n_rotors:
                self._rotors[k] = abs(float(rpm)) * RPM_TO_RAD_S
        if base + len(m.rpm) < self.n_rotors or np.isnan(self._rotors).any():
            return None      # wait for the rest of the ESCs
        lat = self._latest["rotors"]
        if tv < lat.tv and lat.tv - tv < 10.0 and base == 0:
            self.stats.out_of_order += 1
            return None
        lat.t, lat.tv = now, tv
        return [RotorSample(now, tv, self._rotors.copy())]

    # -------------------------------------------------------------- state
    def _state(self, now: float) -> StateSample | None:
        a, p = self._latest["attitude"], self._latest["position"]
        if a.value is None or p.value is None:
            return None
        if now - a.t > self.max_age or now - p.t > self.max_age:
            return None
        q, omega = a.value
        pos, vel = p.value
        R, euler = frames.rotation_euler_from_quaternion_scalar(float(q[0]), float(q[1]), float(q[2]), float(q[3]))
        vn, ve, vd = float(vel[0]), float(vel[1]), float(vel[2])
        v_body = np.array([R[0][0] * vn + R[1][0] * ve + R[2][0] * vd,      # R_IB^T v_ned
                           R[0][1] * vn + R[1][1] * ve + R[2][1] * vd,
                           R[0][2] * vn + R[1][2] * ve + R[2][2] * vd])
        return StateSample(now, max(a.tv, p.tv), pos, vel, q, euler, v_body, omega, abs(a.tv - p.tv))

    def _state_list(self, now: float) -> list[Any]:
        s = self._state(now)
        return [s] if s is not None else []
