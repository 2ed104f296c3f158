"""The telemetry decoder (:class:`TelemetryDecoder`): PX4 messages -> state, IMU and rotor
samples in core frames; the method is the :mod:`lpv_sysid.mavlink.telemetry` docstring."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.io import frames
from lpv_sysid.mavlink.telemetry.clock import VehicleClock
from lpv_sysid.mavlink.telemetry.rotor_estimate import (
    ESC,
    ESTIMATED,
    RotorEstimateConfig,
    RotorSpeedEstimator,
)
from lpv_sysid.mavlink.telemetry.samples import (
    ATTITUDE_SOURCES,
    MOTOR_OUTPUT_SOURCES,
    POSITION_SOURCES,
    ImuSample,
    RotorSample,
    StateSample,
    euler_to_quat,
    quat_to_dcm,
)

RPM_TO_RAD_S = 2.0 * math.pi / 60.0
REBOOT_JUMP_S = 10.0  # vehicle time more than this far back: reboot, accept
_U32_US = 2**32  # SERVO_OUTPUT_RAW.time_usec is uint32 (wraps after 71.6 min)


@dataclass
class TelemetryStats:
    decoded: int = 0
    out_of_order: int = 0
    invalid: int = 0
    foreign: int = 0  # telemetry from a source other than the target
    untargeted: int = 0  # telemetry before the target was known
    esc_zero_while_running: int = 0


@dataclass
class _Latest:
    t: float = -math.inf  # receive time
    tv: float = -math.inf  # vehicle time
    value: Any = None


#: staleness keys: what reached the decoder, per quantity (newest of its sources)
STREAMS = ("attitude", "position", "imu", "rotors", "esc", "motor_outputs")
_SLOTS = (
    "ATTITUDE_QUATERNION",
    "ATTITUDE",
    "LOCAL_POSITION_NED",
    "ODOMETRY",
    "HIGHRES_IMU",
    "ESC_STATUS",
    "ACTUATOR_OUTPUT_STATUS",
    "SERVO_OUTPUT_RAW",
    "rotors",
)


class TelemetryDecoder:
    """Turns MAVLink messages into :class:`StateSample`, :class:`ImuSample`, :class:`RotorSample`.

    ``on_message(msg, now)`` returns the new samples (possibly empty). A
    :class:`StateSample` is produced on every update of the selected attitude or position
    source (module docstring) once both are known and neither is older than ``max_age``.
    ``rotor_estimate``: estimate rotor speeds from the motor outputs (None: ESC only).
    ``source_filter``: decode only messages from :attr:`target` ``(system, component)``.
    """

    def __init__(
        self,
        n_rotors: int = 4,
        max_age: float = 0.5,
        rotor_estimate: RotorEstimateConfig | None = None,
        source_filter: bool = False,
        target: tuple[int, int] | None = None,
        clock: VehicleClock | None = None,
    ) -> None:
        self.n_rotors = n_rotors
        self.max_age = max_age
        self.stats = TelemetryStats()
        #: the vehicle's clock on the caller's: samples carry their sample time (clock.py;
        #: a ReceiverClock for stamps already on the caller's clock)
        self.clock = clock if clock is not None else VehicleClock()
        self.source_filter = source_filter
        self.target = target
        self.foreign_sources: dict[tuple[int, int], int] = {}
        self._latest = {k: _Latest() for k in _SLOTS}
        self._rotors = np.full(n_rotors, np.nan)
        self._esc_valid_t = -math.inf
        self._servo_wraps = 0
        self.rotor_config = (
            rotor_estimate if rotor_estimate is not None and rotor_estimate.enabled else None
        )
        self.estimator: RotorSpeedEstimator | None = None
        if self.rotor_config is not None:
            if len(self.rotor_config.motor_outputs) != n_rotors:
                raise ConfigError(
                    f"rotor_estimate.motor_outputs lists {len(self.rotor_config.motor_outputs)} "
                    f"channels for {n_rotors} rotors"
                )
            self.estimator = RotorSpeedEstimator.from_config(self.rotor_config)
        self._motor_source: str | None = None
        self.rotor_source: str | None = None  # source of the newest RotorSample
        self._handlers = {
            "ATTITUDE_QUATERNION": self._attitude_quaternion,
            "ATTITUDE": self._attitude_euler,
            "LOCAL_POSITION_NED": self._local_position,
            "ODOMETRY": self._odometry,
            "HIGHRES_IMU": self._highres_imu,
            "ESC_STATUS": self._esc_status,
            "ACTUATOR_OUTPUT_STATUS": self._actuator_output_status,
            "SERVO_OUTPUT_RAW": self._servo_output_raw,
        }

    # ------------------------------------------------------------------ API
    def on_message(self, msg: Any, now: float) -> list[Any]:
        mtype = msg.get_type()
        h = self._handlers.get(mtype)
        if h is None:
            return []
        if self.source_filter:
            src = (msg.get_srcSystem(), msg.get_srcComponent())
            if self.target is None:
                self.stats.untargeted += 1
                return []
            if src != self.target:
                self.stats.foreign += 1
                self.foreign_sources[src] = self.foreign_sources.get(src, 0) + 1
                return []
        try:
            out = h(msg, now)
        except (ValueError, ArithmeticError, TypeError, IndexError):
            self.stats.invalid += 1
            return []
        if out is not None:
            self.stats.decoded += 1
        return out or []

    def staleness(self, now: float) -> dict[str, float]:
        """Age [s] of the newest message of each stream (inf if never received)."""
        L = self._latest

        def age(*slots: str) -> float:
            return now - max(L[s].t for s in slots)

        return {
            "attitude": age(*ATTITUDE_SOURCES),
            "position": age(*POSITION_SOURCES),
            "imu": age("HIGHRES_IMU"),
            "rotors": age("rotors"),
            "esc": age("ESC_STATUS"),
            "motor_outputs": age(*MOTOR_OUTPUT_SOURCES),
        }

    def latest_state(self, now: float) -> StateSample | None:
        return self._state(now, emit=False)

    def attitude_source(self, now: float) -> str | None:
        """Message type feeding the attitude of ``state`` now (None: none fresh)."""
        return self._selected(ATTITUDE_SOURCES, now)

    def position_source(self, now: float) -> str | None:
        """Message type feeding position/velocity of ``state`` now (None: none fresh)."""
        return self._selected(POSITION_SOURCES, now)

    def esc_fresh(self, now: float) -> bool:
        """Measured rotor speeds (ESC_STATUS with rpm) younger than the ESC timeout."""
        timeout = self.rotor_config.esc_timeout if self.rotor_config is not None else math.inf
        return now - self._esc_valid_t <= timeout

    # ------------------------------------------------------------- handlers
    def _accept(self, slot: str, tv: float, now: float, value: Any) -> bool:
        lat = self._latest[slot]
        if tv < lat.tv and lat.tv - tv < REBOOT_JUMP_S:
            self.stats.out_of_order += 1
            return False
        lat.t, lat.tv, lat.value = now, tv, value
        if slot != "SERVO_OUTPUT_RAW":  # its uint32 microseconds may have wrapped
            self.clock.observe(now, tv)
        return True

    def _selected(self, sources: tuple[str, ...], now: float) -> str | None:
        for s in sources:
            lat = self._latest[s]
            if lat.value is not None and now - lat.t <= self.max_age:
                return s
        return None

    def _on_state_source(self, slot: str, now: float) -> list[Any]:
        sa, sp = self._selected(ATTITUDE_SOURCES, now), self._selected(POSITION_SOURCES, now)
        if slot in (sa, sp):
            s = self._state(now, sa, sp)
            return [s] if s is not None else []
        return []

    def _attitude_quaternion(self, m: Any, now: float) -> list[Any] | None:
        n = math.sqrt(m.q1 * m.q1 + m.q2 * m.q2 + m.q3 * m.q3 + m.q4 * m.q4)
        if not math.isfinite(n) or n < 0.5:
            raise ValueError("invalid quaternion")
        q = np.array([m.q1 / n, m.q2 / n, m.q3 / n, m.q4 / n])
        omega = np.array([m.rollspeed, m.pitchspeed, m.yawspeed], dtype=float)
        if not (
            math.isfinite(m.rollspeed)
            and math.isfinite(m.pitchspeed)
            and math.isfinite(m.yawspeed)
        ):
            raise ValueError("invalid rates")
        if not self._accept("ATTITUDE_QUATERNION", m.time_boot_ms * 1e-3, now, (q, omega)):
            return None
        return self._on_state_source("ATTITUDE_QUATERNION", now)

    def _attitude_euler(self, m: Any, now: float) -> list[Any] | None:
        e = (m.roll, m.pitch, m.yaw, m.rollspeed, m.pitchspeed, m.yawspeed)
        if not all(math.isfinite(v) for v in e):
            raise ValueError("invalid euler")
        q = euler_to_quat(m.roll, m.pitch, m.yaw)
        omega = np.array([m.rollspeed, m.pitchspeed, m.yawspeed], dtype=float)
        if not self._accept("ATTITUDE", m.time_boot_ms * 1e-3, now, (q, omega)):
            return None
        return self._on_state_source("ATTITUDE", now)

    def _local_position(self, m: Any, now: float) -> list[Any] | None:
        if not all(math.isfinite(v) for v in (m.x, m.y, m.z, m.vx, m.vy, m.vz)):
            raise ValueError("invalid position")
        pos = np.array([m.x, m.y, m.z], dtype=float)
        vel = np.array([m.vx, m.vy, m.vz], dtype=float)
        if not self._accept("LOCAL_POSITION_NED", m.time_boot_ms * 1e-3, now, (pos, vel)):
            return None
        return self._on_state_source("LOCAL_POSITION_NED", now)

    def _odometry(self, m: Any, now: float) -> list[Any] | None:
        # pose frame_id MAV_FRAME_LOCAL_NED = 1; velocity frame child_frame_id: BODY_FRD = 12
        # (or BODY_NED = 8, same meaning for velocities) else the local frame of the pose
        q = np.array(m.q, dtype=float)
        pos = np.array([m.x, m.y, m.z], dtype=float)
        v = np.array([m.vx, m.vy, m.vz], dtype=float)
        omega = np.array([m.rollspeed, m.pitchspeed, m.yawspeed], dtype=float)
        if not (np.isfinite(q).all() and np.linalg.norm(q) >= 0.5):
            raise ValueError("invalid quaternion")
        if not (np.isfinite(pos).all() and np.isfinite(v).all() and np.isfinite(omega).all()):
            raise ValueError("invalid odometry")
        q /= np.linalg.norm(q)
        vel_ned = quat_to_dcm(q) @ v if m.child_frame_id in (8, 12) else v
        # the message feeds both quantities: one slot, one ordering, (q, omega, pos, vel)
        if not self._accept("ODOMETRY", m.time_usec * 1e-6, now, (q, omega, pos, vel_ned)):
            return None
        return self._on_state_source("ODOMETRY", now)

    def _highres_imu(self, m: Any, now: float) -> list[Any] | None:
        v = (
            float(m.xacc),
            float(m.yacc),
            float(m.zacc),
            float(m.xgyro),
            float(m.ygyro),
            float(m.zgyro),
        )
        if not all(map(math.isfinite, v)):
            raise ValueError("invalid imu")
        acc = np.array(v[0:3])
        gyr = np.array(v[3:6])
        tv = m.time_usec * 1e-6
        if not self._accept("HIGHRES_IMU", tv, now, None):
            return None
        return [ImuSample(self.clock.local(tv, now, "imu"), tv, acc, gyr)]

    def _esc_status(self, m: Any, now: float) -> list[Any] | None:
        tv = m.time_usec * 1e-6
        base = int(m.index)
        esc = self._latest["ESC_STATUS"]
        if base == 0:
            if tv < esc.tv and esc.tv - tv < REBOOT_JUMP_S:
                self.stats.out_of_order += 1
                return None
            esc.tv = tv
        esc.t = now
        for i, rpm in enumerate(m.rpm):
            k = base + i
            if k < self.n_rotors:
                self._rotors[k] = abs(float(rpm)) * RPM_TO_RAD_S
        if base + len(m.rpm) < self.n_rotors or np.isnan(self._rotors).any():
            return None  # wait for the rest of the ESCs
        est = self.estimator.omega if self.estimator is not None else None
        cfg = self.rotor_config
        if (
            not self._rotors.any()
            and est is not None
            and cfg is not None
            and est.any()
            and now - self._latest_motor_t() <= cfg.max_gap
        ):
            self.stats.esc_zero_while_running += 1  # no rpm telemetry: not a measurement
            return None
        self._esc_valid_t = now
        lat = self._latest["rotors"]
        lat.t, lat.tv, lat.value = now, tv, ESC
        self.rotor_source = ESC
        return [RotorSample(self.clock.local(tv, now, "rotors"), tv, self._rotors.copy(), ESC)]

    def _latest_motor_t(self) -> float:
        return max(self._latest[s].t for s in MOTOR_OUTPUT_SOURCES)

    def _actuator_output_status(self, m: Any, now: float) -> list[Any] | None:
        estimator, cfg = self.estimator, self.rotor_config
        if estimator is None or cfg is None or cfg.source == "servo_output_raw":
            self._latest["ACTUATOR_OUTPUT_STATUS"].t = now  # seen (staleness), not used
            return None
        act = list(m.actuator)
        n_active = int(m.active)
        chans = cfg.motor_outputs
        if max(chans) > min(n_active, len(act)):
            raise ValueError(f"motor output {max(chans)} not among the {n_active} active outputs")
        outputs = [float(act[c - 1]) for c in chans]
        return self._motor_outputs(
            estimator, "ACTUATOR_OUTPUT_STATUS", m.time_usec * 1e-6, outputs, now
        )

    def _servo_output_raw(self, m: Any, now: float) -> list[Any] | None:
        estimator, cfg = self.estimator, self.rotor_config
        if (
            estimator is None
            or cfg is None
            or cfg.source == "actuator_output_status"
            or int(m.port) != cfg.servo_port
        ):
            self._latest["SERVO_OUTPUT_RAW"].t = now  # seen (staleness), not used
            return None
        if cfg.source == "auto" and now - self._latest["ACTUATOR_OUTPUT_STATUS"].t <= cfg.max_gap:
            return None  # ACTUATOR_OUTPUT_STATUS is streamed: one source only
        us = int(m.time_usec) + self._servo_wraps * _U32_US
        last = self._latest["SERVO_OUTPUT_RAW"].tv
        if math.isfinite(last) and last * 1e6 - us > _U32_US / 2:
            self._servo_wraps += 1  # uint32 microseconds wrapped
            us += _U32_US
        raw = [getattr(m, f"servo{c}_raw") for c in cfg.motor_outputs]
        outputs = [float(x) for x in raw]
        return self._motor_outputs(estimator, "SERVO_OUTPUT_RAW", us * 1e-6, outputs, now)

    def _motor_outputs(
        self,
        estimator: RotorSpeedEstimator,
        slot: str,
        tv: float,
        outputs: list[float],
        now: float,
    ) -> list[Any] | None:
        if not self._accept(slot, tv, now, outputs):
            return None
        if slot != self._motor_source:
            estimator.reset()  # other source, other clock: restart
            self._motor_source = slot
        omega = estimator.update(tv, outputs)
        if self.esc_fresh(now):
            return None  # measured speeds win
        lat = self._latest["rotors"]
        lat.t, lat.tv, lat.value = now, tv, ESTIMATED
        self.rotor_source = ESTIMATED
        return [RotorSample(self.clock.local(tv, now, "rotors"), tv, omega, ESTIMATED)]

    # -------------------------------------------------------------- state
    def _state(
        self, now: float, sa: str | None = None, sp: str | None = None, emit: bool = True
    ) -> StateSample | None:
        if sa is None or sp is None:  # the caller may pass the selected sources
            sa, sp = self._selected(ATTITUDE_SOURCES, now), self._selected(POSITION_SOURCES, now)
        if sa is None or sp is None:
            return None
        a, p = self._latest[sa], self._latest[sp]
        q, omega = a.value[0], a.value[1]
        pos, vel = (p.value[2], p.value[3]) if sp == "ODOMETRY" else p.value
        R, euler = frames.rotation_euler_from_quaternion_scalar(
            float(q[0]), float(q[1]), float(q[2]), float(q[3])
        )
        vn, ve, vd = float(vel[0]), float(vel[1]), float(vel[2])
        v_body = np.array(
            [
                R[0][0] * vn + R[1][0] * ve + R[2][0] * vd,  # R_IB^T v_ned
                R[0][1] * vn + R[1][1] * ve + R[2][1] * vd,
                R[0][2] * vn + R[1][2] * ve + R[2][2] * vd,
            ]
        )
        tv = max(a.tv, p.tv)
        t = self.clock.local(tv, now, "state" if emit else None)
        return StateSample(t, tv, pos, vel, q, euler, v_body, omega, abs(a.tv - p.tv))

    def _state_list(self, now: float) -> list[Any]:
        s = self._state(now)
        return [s] if s is not None else []
