"""A simulated quadrotor that speaks MAVLink 2 like PX4 SITL (v1.16 behaviour subset).

Protocol (what a bridge, MAVSDK or a ground station sees):
- HEARTBEAT 1 Hz: MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_PX4, base_mode flags and the PX4
  custom mode (main << 16 | sub << 24), MAV_STATE_STANDBY/ACTIVE;
- COMMAND_LONG -> COMMAND_ACK: COMPONENT_ARM_DISARM (400; disarm in the air only with
  the 21196 force code), DO_SET_MODE (176; OFFBOARD refused with TEMPORARILY_REJECTED
  unless a setpoint stream is alive: >= 2 setpoints in the last second and the newest
  younger than COM_OF_LOSS_T), SET_MESSAGE_INTERVAL (511), REQUEST_MESSAGE (512),
  REQUEST_AUTOPILOT_CAPABILITIES (520), NAV_TAKEOFF (22), NAV_LAND (21), NAV_RETURN (20);
  anything else MAV_RESULT_UNSUPPORTED;
- PARAM_REQUEST_READ / PARAM_REQUEST_LIST / PARAM_SET -> PARAM_VALUE (INT32 parameters
  byte-wise encoded as PX4 does);
- AUTOPILOT_VERSION (PX4 v1.16.0, MAVLink 2, offboard capabilities);
- telemetry at default or requested intervals: ATTITUDE, ATTITUDE_QUATERNION,
  LOCAL_POSITION_NED, GLOBAL_POSITION_INT, HIGHRES_IMU, ESC_STATUS, SYS_STATUS,
  EXTENDED_SYS_STATE, HOME_POSITION, ODOMETRY.

Behaviour:
- OFFBOARD accepts SET_POSITION_TARGET_LOCAL_NED (velocity, optional yaw rate,
  position; MAV_FRAME_LOCAL_NED, or MAV_FRAME_BODY_NED / BODY_FRD rotated by yaw only, as
  PX4 does) and SET_ATTITUDE_TARGET body rates + thrust (PX4 rate loop, P term only:
  tau = K_p (omega_sp - omega), unit quad-X allocation);
- offboard loss: no setpoint for COM_OF_LOSS_T -> COM_OBL_RC_ACT (0 Position, 1 Altitude,
  2 Manual, 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm);
- armed but no takeoff within COM_DISARM_PRFLT -> disarm; landed for COM_DISARM_LAND
  after a flight -> disarm;
- physics: seed 0 quadrotor (models/quadrotor.py, RK4 at ``physics_hz``) with the PX4-like
  cascaded controller (control/baseline.py) tracking the velocity setpoints of every
  mode (HOLD/POSCTL/ALTCTL hold position/altitude with a P loop, LAND descends at
  MPC_LAND_SPEED, RTL flies home then lands); flat ground at z = 0.

The vehicle is a polled object: ``step(now)`` advances physics to ``now`` (fixed steps),
serves the link and sends due telemetry. :meth:`SimVehicle.run_realtime` drives it from the
wall clock; tests may call ``step`` with a simulated clock (lock-step, faster than real time).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.io import frames
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.link import LinkConfig, MavlinkLink
from lpv_sysid.mavlink.telemetry import euler_to_quat
from lpv_sysid.validation import check_config_keys, is_finite_number

log = logging.getLogger(__name__)

MAV_TYPE_QUADROTOR = 2
MAV_AUTOPILOT_PX4 = 12
MAV_STATE_STANDBY, MAV_STATE_ACTIVE, MAV_STATE_CRITICAL = 3, 4, 5
MAV_RESULT_ACCEPTED, MAV_RESULT_TEMPORARILY_REJECTED, MAV_RESULT_DENIED = 0, 1, 2
MAV_RESULT_UNSUPPORTED, MAV_RESULT_FAILED = 3, 4
CMD_ARM_DISARM, CMD_DO_SET_MODE, CMD_SET_MESSAGE_INTERVAL = 400, 176, 511
CMD_REQUEST_MESSAGE, CMD_REQUEST_CAPABILITIES = 512, 520
CMD_NAV_TAKEOFF, CMD_NAV_LAND, CMD_NAV_RETURN = 22, 21, 20
FORCE_DISARM_MAGIC = 21196
MAV_LANDED_STATE_ON_GROUND, MAV_LANDED_STATE_IN_AIR = 1, 2

#: PX4 parameters served (name -> (value, MAV_PARAM_TYPE)); PX4 v1.16 defaults unless noted.
DEFAULT_PARAMS: dict[str, tuple[float, int]] = {
    "COM_OF_LOSS_T": (1.0, px4.MAV_PARAM_TYPE_REAL32),
    "COM_OBL_RC_ACT": (0, px4.MAV_PARAM_TYPE_INT32),
    "COM_DISARM_PRFLT": (10.0, px4.MAV_PARAM_TYPE_REAL32),
    "COM_DISARM_LAND": (2.0, px4.MAV_PARAM_TYPE_REAL32),
    "COM_RC_IN_MODE": (4, px4.MAV_PARAM_TYPE_INT32),       # SITL without RC (v1.16: 4 = disabled)
    "COM_RCL_EXCEPT": (4, px4.MAV_PARAM_TYPE_INT32),       # bit 2: ignore RC loss in offboard
    "NAV_DLL_ACT": (0, px4.MAV_PARAM_TYPE_INT32),
    "MPC_XY_VEL_MAX": (12.0, px4.MAV_PARAM_TYPE_REAL32),
    "MPC_Z_VEL_MAX_UP": (3.0, px4.MAV_PARAM_TYPE_REAL32),
    "MPC_Z_VEL_MAX_DN": (1.5, px4.MAV_PARAM_TYPE_REAL32),
    "MPC_LAND_SPEED": (0.7, px4.MAV_PARAM_TYPE_REAL32),
    "MIS_TAKEOFF_ALT": (2.5, px4.MAV_PARAM_TYPE_REAL32),
    "MC_ROLLRATE_P": (0.15, px4.MAV_PARAM_TYPE_REAL32),
    "MC_PITCHRATE_P": (0.15, px4.MAV_PARAM_TYPE_REAL32),
    "MC_YAWRATE_P": (0.2, px4.MAV_PARAM_TYPE_REAL32),
    "MAV_SYS_ID": (1, px4.MAV_PARAM_TYPE_INT32),
}

#: default stream rates [Hz] before any SET_MESSAGE_INTERVAL (PX4 "onboard" profile-like)
DEFAULT_RATES: dict[str, float] = {
    "ATTITUDE": 20.0, "ATTITUDE_QUATERNION": 50.0, "LOCAL_POSITION_NED": 30.0,
    "GLOBAL_POSITION_INT": 10.0, "HIGHRES_IMU": 50.0, "ESC_STATUS": 10.0, "SYS_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 1.0, "HOME_POSITION": 0.5, "ODOMETRY": 0.0,
}
HOME_LAT, HOME_LON, HOME_ALT = 47.397742, 8.545594, 488.0   # PX4 SITL default home


@dataclass(frozen=True)
class SimVehicleConfig:
    url: str = "udpout:127.0.0.1:14540"     # PX4 SITL sends to the offboard port 14540
    system_id: int = 1
    component_id: int = 1
    physics_hz: float = 250.0
    params: Mapping[str, float] = field(default_factory=dict)    # overrides of DEFAULT_PARAMS
    initial_mode: str = "HOLD"
    signing_key_file: str | None = None
    allow_unsigned: bool = False
    sensor_noise: bool = False
    seed: int = 0
    duplicate_acks: bool = False            # send every COMMAND_ACK twice (PX4 sometimes does)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SimVehicleConfig":
        check_config_keys(d, cls.__dataclass_fields__, "sim vehicle")
        cfg = cls(**dict(d))
        cfg.validate()
        return cfg

    def validate(self) -> None:
        if not isinstance(self.physics_hz, (int, float)) or isinstance(self.physics_hz, bool):
            raise ConfigError(f"sim vehicle physics_hz must be a number, got {self.physics_hz!r}")
        if not isinstance(self.params, Mapping):
            raise ConfigError("sim vehicle params must be a mapping NAME: value")
        if not (self.physics_hz >= 50.0 and math.isfinite(self.physics_hz)):
            raise ConfigError(f"sim vehicle physics_hz must be >= 50, got {self.physics_hz!r}")
        for k, v in self.params.items():
            if k not in DEFAULT_PARAMS:
                raise ConfigError(f"sim vehicle: unknown parameter {k!r}; known: {sorted(DEFAULT_PARAMS)}")
            if not is_finite_number(v):
                raise ConfigError(f"sim vehicle: parameter {k} must be a finite number, got {v!r}")
        if px4.mode_by_name(self.initial_mode) == px4.OFFBOARD:
            raise ConfigError("sim vehicle initial_mode cannot be OFFBOARD (PX4 needs a setpoint stream)")


@dataclass
class _Setpoint:
    kind: str                         # "velocity" | "position" | "rates"
    t: float
    v_ned: np.ndarray | None = None
    pos_ned: np.ndarray | None = None
    yaw_rate: float = 0.0
    rates: np.ndarray | None = None
    thrust: float = 0.0


class SimVehicle:
    """See module docstring."""

    def __init__(self, config: SimVehicleConfig | None = None, model: Any = None,
                 controller_factory: Callable[[], Any] | None = None,
                 link: MavlinkLink | None = None) -> None:
        self.config = config or SimVehicleConfig()
        self.config.validate()
        if model is None:
            from lpv_sysid.models.quadrotor import Quadrotor
            model = Quadrotor()
        if controller_factory is None:
            from lpv_sysid.control.baseline import BaselineController, BaselineGains

            arm = float(getattr(getattr(model, "params", None), "arm_length", 0.225))
            controller_factory = lambda: BaselineController(BaselineGains(arm_length=arm))  # noqa: E731
        self.model = model
        self._controller_factory = controller_factory
        self.ctrl = controller_factory()
        self.params: dict[str, tuple[float, int]] = dict(DEFAULT_PARAMS)
        for k, v in self.config.params.items():
            self.params[k] = (v, DEFAULT_PARAMS[k][1])
        self.link = link or MavlinkLink(LinkConfig(
            url=self.config.url, source_system=self.config.system_id,
            source_component=self.config.component_id, streams=(),
            signing_key_file=self.config.signing_key_file, allow_unsigned=self.config.allow_unsigned,
            mav_type=MAV_TYPE_QUADROTOR))
        self._rng = np.random.default_rng(self.config.seed)
        self.dt = 1.0 / self.config.physics_hz
        self.t = 0.0                      # simulated time since boot [s]
        self.x = np.zeros(16)             # FULL_STATE_NAMES, on the ground, motors off
        self.u = np.zeros(4)
        self.armed = False
        self.mode = px4.mode_by_name(self.config.initial_mode)
        self.landed = True
        self.took_off = False
        self.t_armed = 0.0
        self.t_landed = 0.0
        self.hold_pos = np.zeros(3)
        self.setpoint: _Setpoint | None = None
        self._sp_times: list[float] = []
        self.setpoints_received = 0
        self.mode_log: list[tuple[float, str, str]] = []   # (t, mode name, reason)
        self.failsafe_reason = ""
        self.gcs_last_heartbeat: float | None = None
        self.intervals: dict[int, float] = {}
        self._next_send: dict[int, float] = {}
        self._next_hb = 0.0
        self._opened = False
        mod = px4.dialect_module(px4.DEFAULT_DIALECT)
        self._mod = mod
        self._stream_ids = {name: (px4.MAVLINK_MSG_ID_ESC_STATUS if name == "ESC_STATUS"
                                   else getattr(mod, f"MAVLINK_MSG_ID_{name}"))
                            for name in DEFAULT_RATES}
        for name, rate in DEFAULT_RATES.items():
            self.intervals[self._stream_ids[name]] = 1.0 / rate if rate > 0 else -1.0
        self._esc_cls = px4.esc_status_class(px4.DEFAULT_DIALECT)

    # ------------------------------------------------------------- lifecycle
    def open(self) -> None:
        self.link.open(self.t)
        self._opened = True

    def close(self) -> None:
        self.link.close()
        self._opened = False

    def param(self, name: str) -> float:
        return float(self.params[name][0])

    # ------------------------------------------------------------------ loop
    def step(self, now: float) -> None:
        """Advance to ``now`` (seconds since boot): physics, messages, telemetry."""
        if self._opened:
            for msg in self.link.poll(now):
                self._handle(msg, now)
        while self.t + self.dt <= now + 1e-9:
            self._physics_step()
            self._supervise(self.t)
        if self._opened:
            self._send_telemetry(now)

    def run_realtime(self, duration: float | None = None, stop: Callable[[], bool] | None = None,
                     period: float = 0.002, speed: float = 1.0) -> None:
        """Drive :meth:`step` from the wall clock (bounded by ``duration`` simulated seconds).

        ``speed`` > 1 runs faster than real time (simulated time = speed x wall time); the
        peers then see a vehicle whose clock runs fast, which is fine for protocol tests.
        """
        if not (speed > 0 and math.isfinite(speed)):
            raise ConfigError(f"sim vehicle speed must be positive, got {speed!r}")
        w0 = time.monotonic()
        s0 = self.t
        while True:
            w = time.monotonic()
            now = s0 + (w - w0) * speed
            if duration is not None and now >= duration:
                break
            if stop is not None and stop():
                break
            self.step(now)
            time.sleep(max(0.0, period - (time.monotonic() - w)))

    # --------------------------------------------------------------- physics
    def _physics_step(self) -> None:
        dt = self.dt
        x = self.x
        if not self.armed:
            self.u = np.zeros(4)
            x[12:16] = 0.0
            if self.landed:
                self.t += dt
                return
        else:
            self.u = self._control()
        u = self.u.tolist()
        f = self.model.derivatives_list
        xl = x.tolist()
        k1 = f(xl, u)
        k2 = f([a + 0.5 * dt * b for a, b in zip(xl, k1)], u)
        k3 = f([a + 0.5 * dt * b for a, b in zip(xl, k2)], u)
        k4 = f([a + dt * b for a, b in zip(xl, k3)], u)
        xn = np.array([a + dt / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4)
                       for a, b1, b2, b3, b4 in zip(xl, k1, k2, k3, k4)])
        if not self.armed:
            xn[12:16] = 0.0
        self.t += dt
        # flat ground at z = 0 (NED): no penetration, no bounce, level on contact
        if xn[2] >= 0.0:
            v_ned = self._R(xn) @ xn[6:9]
            if v_ned[2] >= 0.0:
                xn[2] = 0.0
                xn[3:5] = 0.0
                xn[6:12] = 0.0
                if not self.landed:
                    self.landed, self.t_landed = True, self.t
        elif xn[2] < -0.1:
            if self.landed and self.armed:
                self.took_off = True
            self.landed = False
        self.x = xn

    @staticmethod
    def _R(x: np.ndarray) -> np.ndarray:
        """R_IB of seed 0 Eq. (1) (ZYX Euler), via io/frames."""
        return frames.rotation_from_euler(x[3:6])

    def _yaw_R(self) -> np.ndarray:
        c, s = math.cos(self.x[5]), math.sin(self.x[5])
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def _control(self) -> np.ndarray:
        """Virtual actuator command for the current mode (PX4 flight-task stand-in)."""
        x = self.x
        sp = self.setpoint
        if self.mode == px4.OFFBOARD and sp is not None and sp.kind == "rates":
            return self._rate_mode(sp)
        v_ned, yaw_rate = self._velocity_setpoint()
        if self.landed and v_ned[2] > -0.2:
            self.ctrl.reset()                       # PX4 keeps idle and resets integrators on ground
            return self.model.mix @ np.full(4, 0.1)
        v_body = self._R(x).T @ v_ned
        x12 = np.concatenate([x[3:5], x[6:12], np.zeros(4)])
        return np.asarray(self.ctrl.step(self.t, x12, v_body, yaw_rate), dtype=float)

    def _velocity_setpoint(self) -> tuple[np.ndarray, float]:
        x = self.x
        pos = x[0:3]
        m = self.mode
        if m == px4.OFFBOARD and self.setpoint is not None:
            sp = self.setpoint
            if sp.kind == "velocity":
                return sp.v_ned.copy(), sp.yaw_rate
            if sp.kind == "position":
                v = 1.0 * (sp.pos_ned - pos) + (sp.v_ned if sp.v_ned is not None else 0.0)
                return _clip_norm(v, 5.0), sp.yaw_rate
        if m == px4.LAND:
            v = _clip_norm(1.0 * (self.hold_pos - pos), 2.0)
            v[2] = self.param("MPC_LAND_SPEED")
            return v, 0.0
        if m == px4.RTL:
            d = -pos
            d[2] = 0.0
            if np.linalg.norm(d) > 0.5:
                v = _clip_norm(1.0 * d, 3.0)
                v[2] = 0.0
                return v, 0.0
            v = np.array([0.0, 0.0, self.param("MPC_LAND_SPEED")])
            return v, 0.0
        if m == px4.TAKEOFF:
            target = self.hold_pos.copy()
            target[2] = -self.param("MIS_TAKEOFF_ALT")
            if abs(pos[2] - target[2]) < 0.1:
                self._set_mode(px4.HOLD, self.t, "takeoff complete")
            return _clip_norm(1.0 * (target - pos), 2.0), 0.0
        # HOLD, POSCTL (no sticks), ALTCTL, MANUAL, STABILIZED, OFFBOARD without setpoint
        v = _clip_norm(1.0 * (self.hold_pos - pos), 3.0)
        if m in (px4.ALTCTL, px4.MANUAL, px4.STABILIZED):
            v[0:2] = 0.0
        return v, 0.0

    def _rate_mode(self, sp: _Setpoint) -> np.ndarray:
        """PX4 rate loop, P term: tau = K_p (omega_sp - omega); unit quad-X allocation."""
        kp = np.array([self.param("MC_ROLLRATE_P"), self.param("MC_PITCHRATE_P"), self.param("MC_YAWRATE_P")])
        tau = kp * (sp.rates - self.x[9:12])
        alloc = np.array([[1.0, -1.0, 1.0, 1.0], [1.0, 1.0, -1.0, 1.0],
                          [1.0, 1.0, 1.0, -1.0], [1.0, -1.0, -1.0, -1.0]])
        u_esc = np.clip(alloc @ np.r_[sp.thrust, tau], 0.0, 1.0)
        return self.model.mix @ u_esc

    # ------------------------------------------------------------ supervision
    def _supervise(self, t: float) -> None:
        if self.mode == px4.OFFBOARD:
            last = self.setpoint.t if self.setpoint is not None else -math.inf
            if t - last > self.param("COM_OF_LOSS_T"):
                self._offboard_lost(t)
        if self.armed and self.landed:
            if not self.took_off and t - self.t_armed > self.param("COM_DISARM_PRFLT"):
                self._disarm(t, "no takeoff within COM_DISARM_PRFLT")
            elif self.took_off and t - self.t_landed > self.param("COM_DISARM_LAND"):
                self._disarm(t, "landed (COM_DISARM_LAND)")

    def _offboard_lost(self, t: float) -> None:
        act = int(self.param("COM_OBL_RC_ACT"))
        reason = f"offboard lost for > COM_OF_LOSS_T = {self.param('COM_OF_LOSS_T')} s (COM_OBL_RC_ACT={act})"
        self.failsafe_reason = reason
        log.warning(reason)
        target = {0: px4.POSCTL, 1: px4.ALTCTL, 2: px4.MANUAL, 3: px4.RTL, 4: px4.LAND,
                  5: px4.HOLD}.get(act)
        if target is not None:
            self._set_mode(target, t, reason)
        else:                                         # 6 terminate, 7 disarm
            self._set_mode(px4.HOLD, t, reason)
            self._disarm(t, reason)

    def _set_mode(self, mode: px4.Px4Mode, t: float, reason: str) -> None:
        if mode != self.mode:
            self.mode_log.append((t, mode.name, reason))
        self.mode = mode
        self.hold_pos = self.x[0:3].copy()
        if self.landed:
            self.hold_pos[2] = 0.0

    def _arm(self, t: float) -> None:
        self.armed, self.t_armed, self.took_off = True, t, False
        self.ctrl = self._controller_factory()
        self.hold_pos = self.x[0:3].copy()

    def _disarm(self, t: float, reason: str) -> None:
        if self.armed:
            self.mode_log.append((t, "DISARMED", reason))
        self.armed = False
        self.x[12:16] = 0.0

    # ------------------------------------------------------------- messages
    def _handle(self, m: Any, now: float) -> None:
        mt = m.get_type()
        if mt == "HEARTBEAT":
            self.gcs_last_heartbeat = now
            return
        tgt = getattr(m, "target_system", None)
        if tgt not in (None, 0, self.config.system_id):
            return
        if mt == "COMMAND_LONG":
            self._command(m, now)
        elif mt == "SET_POSITION_TARGET_LOCAL_NED":
            self._position_target(m, now)
        elif mt == "SET_ATTITUDE_TARGET":
            self._attitude_target(m, now)
        elif mt == "PARAM_REQUEST_READ":
            name = px4.param_id_str(m.param_id)
            if m.param_index >= 0:
                names = list(self.params)
                if m.param_index < len(names):
                    self._send_param(names[m.param_index])
            elif name in self.params:
                self._send_param(name)
        elif mt == "PARAM_REQUEST_LIST":
            for name in self.params:
                self._send_param(name)
        elif mt == "PARAM_SET":
            name = px4.param_id_str(m.param_id)
            if name in self.params:
                ptype = self.params[name][1]
                self.params[name] = (px4.param_from_wire(m.param_value, ptype), ptype)
                self._send_param(name)

    def _send_param(self, name: str) -> None:
        names = list(self.params)
        value, ptype = self.params[name]
        self.link.send(self.link.codec.param_value_encode(
            name.encode("ascii"), px4.param_to_wire(value, ptype), ptype, len(names), names.index(name)))

    def _ack(self, cmd: int, result: int) -> None:
        for _ in range(2 if self.config.duplicate_acks else 1):
            self.link.send(self.link.codec.command_ack_encode(cmd, result, 0, 0, 0, 0))

    def _command(self, m: Any, now: float) -> None:
        c = m.command
        if c == CMD_ARM_DISARM:
            if m.param1 >= 0.5:
                if self.armed:
                    return self._ack(c, MAV_RESULT_ACCEPTED)
                if not self.landed or self.mode in (px4.LAND, px4.RTL):
                    return self._ack(c, MAV_RESULT_DENIED)
                if self.mode == px4.OFFBOARD and not self._stream_alive(now):
                    return self._ack(c, MAV_RESULT_DENIED)
                self._arm(self.t)
                return self._ack(c, MAV_RESULT_ACCEPTED)
            if self.landed or int(round(m.param2)) == FORCE_DISARM_MAGIC:
                self._disarm(self.t, "disarm command")
                return self._ack(c, MAV_RESULT_ACCEPTED)
            return self._ack(c, MAV_RESULT_DENIED)
        if c == CMD_DO_SET_MODE:
            if not int(m.param1) & px4.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return self._ack(c, MAV_RESULT_UNSUPPORTED)
            mode = px4.Px4Mode(int(m.param2), int(m.param3))
            if mode.main == px4.MAIN_AUTO and mode.sub == 0:
                mode = px4.HOLD
            if mode.name.startswith("UNKNOWN"):
                return self._ack(c, MAV_RESULT_UNSUPPORTED)
            if mode == px4.OFFBOARD and not self._stream_alive(now):
                return self._ack(c, MAV_RESULT_TEMPORARILY_REJECTED)
            self._set_mode(mode, self.t, "DO_SET_MODE")
            return self._ack(c, MAV_RESULT_ACCEPTED)
        if c == CMD_SET_MESSAGE_INTERVAL:
            mid, interval = int(m.param1), m.param2
            if mid not in self._stream_ids.values():
                return self._ack(c, MAV_RESULT_UNSUPPORTED)
            default = DEFAULT_RATES[next(k for k, v in self._stream_ids.items() if v == mid)]
            if interval < 0:
                self.intervals[mid] = -1.0
            elif interval == 0:
                self.intervals[mid] = 1.0 / default if default > 0 else -1.0
            else:
                self.intervals[mid] = max(interval * 1e-6, 1.0 / 400.0)
            self._next_send[mid] = now
            return self._ack(c, MAV_RESULT_ACCEPTED)
        if c in (CMD_REQUEST_MESSAGE, CMD_REQUEST_CAPABILITIES):
            mid = 148 if c == CMD_REQUEST_CAPABILITIES else int(m.param1)
            if mid == 148:
                self._ack(c, MAV_RESULT_ACCEPTED)
                return self._send_autopilot_version()
            if mid in self._stream_ids.values():
                self._ack(c, MAV_RESULT_ACCEPTED)
                return self._send_stream(mid, now)
            return self._ack(c, MAV_RESULT_UNSUPPORTED)
        if c == CMD_NAV_TAKEOFF:
            if not self.armed:
                return self._ack(c, MAV_RESULT_DENIED)
            self._set_mode(px4.TAKEOFF, self.t, "NAV_TAKEOFF")
            return self._ack(c, MAV_RESULT_ACCEPTED)
        if c in (CMD_NAV_LAND, CMD_NAV_RETURN):
            self._set_mode(px4.LAND if c == CMD_NAV_LAND else px4.RTL, self.t, "command")
            return self._ack(c, MAV_RESULT_ACCEPTED)
        return self._ack(c, MAV_RESULT_UNSUPPORTED)

    def _stream_alive(self, now: float) -> bool:
        self._sp_times = [t for t in self._sp_times if now - t <= 1.0]
        return (len(self._sp_times) >= 2 and self.setpoint is not None
                and now - self._sp_times[-1] <= self.param("COM_OF_LOSS_T"))

    def _sp_received(self, now: float, sp: _Setpoint) -> None:
        self.setpoint = sp
        self.setpoints_received += 1
        self._sp_times.append(now)
        if len(self._sp_times) > 200:
            self._sp_times = self._sp_times[-100:]

    def _position_target(self, m: Any, now: float) -> None:
        mask = m.type_mask
        frame = m.coordinate_frame
        if frame in (8, 12):           # BODY_NED / BODY_FRD: PX4 rotates by yaw only
            R = self._yaw_R()
        elif frame == 1:
            R = np.eye(3)
        else:
            return
        use_pos = not (mask & 0x7)
        use_vel = not (mask & 0x38)
        yaw_rate = 0.0 if mask & 0x800 else float(m.yaw_rate)
        vel = R @ np.array([m.vx, m.vy, m.vz], dtype=float)
        if not np.isfinite(vel).all() or not math.isfinite(yaw_rate):
            return
        if use_pos:
            pos = np.array([m.x, m.y, m.z], dtype=float)
            pos = (R @ pos + self.x[0:3]) if frame in (8, 12) else pos
            sp = _Setpoint("position", self.t, v_ned=vel if use_vel else None, pos_ned=pos, yaw_rate=yaw_rate)
        elif use_vel:
            sp = _Setpoint("velocity", self.t, v_ned=vel, yaw_rate=yaw_rate)
        else:
            return
        sp.t = now
        self._sp_received(now, sp)

    def _attitude_target(self, m: Any, now: float) -> None:
        if not m.type_mask & 128:     # attitude quaternion setpoints: not modelled
            return
        rates = np.array([m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate], dtype=float)
        if not np.isfinite(rates).all() or not math.isfinite(m.thrust):
            return
        self._sp_received(now, _Setpoint("rates", now, rates=rates, thrust=float(m.thrust)))

    # ------------------------------------------------------------ telemetry
    def _send_telemetry(self, now: float) -> None:
        if now >= self._next_hb:
            self._next_hb = now + 1.0
            self._heartbeat()
        for mid, interval in self.intervals.items():
            if interval <= 0:
                continue
            nxt = self._next_send.get(mid, 0.0)
            if now >= nxt:
                self._next_send[mid] = nxt + interval if now - nxt < interval else now + interval
                self._send_stream(mid, now)

    def _heartbeat(self) -> None:
        state = MAV_STATE_ACTIVE if self.armed else MAV_STATE_STANDBY
        if self.failsafe_reason and self.armed:
            state = MAV_STATE_CRITICAL
        self.link.send(self.link.codec.heartbeat_encode(
            MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_PX4, px4.base_mode_flags(self.mode, self.armed),
            self.mode.custom_mode, state))

    def _send_autopilot_version(self) -> None:
        mod = self._mod
        caps = 0
        for name in ("MISSION_FLOAT", "PARAM_FLOAT", "MISSION_INT", "COMMAND_INT",
                     "PARAM_ENCODE_BYTEWISE", "SET_ATTITUDE_TARGET",
                     "SET_POSITION_TARGET_LOCAL_NED", "MAVLINK2"):
            caps |= int(getattr(mod, f"MAV_PROTOCOL_CAPABILITY_{name}"))
        self.link.send(self.link.codec.autopilot_version_encode(
            caps, px4.encode_flight_sw_version(1, 16, 0), 0, 0, 0,
            b"\0" * 8, b"\0" * 8, b"\0" * 8, 0, 0, 0x1234ABCD, [0] * 18))

    def _send_stream(self, mid: int, now: float) -> None:
        c = self.link.codec
        x = self.x
        ms = int(self.t * 1000) & 0xFFFFFFFF
        us = int(self.t * 1e6)
        noise = self.config.sensor_noise
        rn = (lambda s, n=3: self._rng.normal(0.0, s, n)) if noise else (lambda s, n=3: np.zeros(n))
        R = self._R(x)
        v_ned = R @ x[6:9]
        sid = self._stream_ids
        if mid == sid["ATTITUDE_QUATERNION"]:
            q = euler_to_quat(*x[3:6])
            w = x[9:12] + rn(0.005)
            c_msg = c.attitude_quaternion_encode(ms, *[float(v) for v in q], *[float(v) for v in w], [0.0] * 4)
        elif mid == sid["ATTITUDE"]:
            w = x[9:12] + rn(0.005)
            c_msg = c.attitude_encode(ms, *[float(v) for v in x[3:6]], *[float(v) for v in w])
        elif mid == sid["LOCAL_POSITION_NED"]:
            p = x[0:3] + rn(0.01)
            v = v_ned + rn(0.02)
            c_msg = c.local_position_ned_encode(ms, *[float(a) for a in p], *[float(a) for a in v])
        elif mid == sid["GLOBAL_POSITION_INT"]:
            lat = HOME_LAT + x[0] / 111319.5
            lon = HOME_LON + x[1] / (111319.5 * math.cos(math.radians(HOME_LAT)))
            hdg = int(math.degrees(x[5]) % 360 * 100)
            c_msg = c.global_position_int_encode(ms, int(lat * 1e7), int(lon * 1e7),
                                                 int((HOME_ALT - x[2]) * 1000), int(-x[2] * 1000),
                                                 *[int(v * 100) for v in v_ned], hdg)
        elif mid == sid["HIGHRES_IMU"]:
            if self.armed and not self.landed:
                acc = np.asarray(self.model.specific_force(x, self.u), dtype=float)
            else:
                acc = R.T @ np.array([0.0, 0.0, -9.80665])
            acc = acc + rn(0.05)
            gyr = x[9:12] + rn(0.005)
            c_msg = c.highres_imu_encode(us, *[float(a) for a in acc], *[float(a) for a in gyr],
                                         0.2, 0.0, 0.4, 1013.0, 0.0, float(-x[2]), 25.0, 0x1FF, 0)
        elif mid == sid["ESC_STATUS"]:
            rpm = [int(round(o * 60.0 / (2 * math.pi))) for o in x[12:16]]
            c_msg = self._esc_cls(0, us, rpm, [16.0] * 4, [0.0] * 4)
        elif mid == sid["SYS_STATUS"]:
            sensors = 0x3FFF
            c_msg = c.sys_status_encode(sensors, sensors, sensors, 100, 16000, 500, 80, 0, 0, 0, 0, 0, 0)
        elif mid == sid["EXTENDED_SYS_STATE"]:
            c_msg = c.extended_sys_state_encode(0, MAV_LANDED_STATE_ON_GROUND if self.landed
                                                else MAV_LANDED_STATE_IN_AIR)
        elif mid == sid["HOME_POSITION"]:
            c_msg = c.home_position_encode(int(HOME_LAT * 1e7), int(HOME_LON * 1e7), int(HOME_ALT * 1000),
                                           0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, us)
        elif mid == sid["ODOMETRY"]:
            q = euler_to_quat(*x[3:6])
            c_msg = c.odometry_encode(us, 1, 12, *[float(a) for a in x[0:3]], [float(a) for a in q],
                                      *[float(a) for a in x[6:9]], *[float(a) for a in x[9:12]],
                                      [float("nan")] * 21, [float("nan")] * 21, 0, 0, 100)
        else:
            return
        self.link.send(c_msg)


def _clip_norm(v: np.ndarray, vmax: float) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v * (vmax / n) if n > vmax else v
