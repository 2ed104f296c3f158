"""A simulated quadrotor that speaks MAVLink 2 like PX4 SITL (v1.16 behaviour subset).

Protocol (what a bridge, MAVSDK or a ground station sees):
- HEARTBEAT 1 Hz: MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_PX4, base_mode flags and the PX4
  custom mode (main << 16 | sub << 24), MAV_STATE_STANDBY/ACTIVE/CRITICAL (failsafe);
- COMMAND_LONG -> COMMAND_ACK. DO_SET_MODE (176) is answered twice as PX4 v1.16 does
  (``double_ack``, :data:`lpv_sysid.mavlink.px4.DOUBLE_ACK_COMMANDS`): ACCEPTED at once
  (PX4's MAVLink receiver), then the commander's verdict ``verdict_delay_s`` later
  (simulated time); only the verdict changes the mode. Commander rules (v1.16
  UserModeIntention, measured on SIH SITL): while disarmed every known mode is accepted;
  while armed a mode that cannot run is TEMPORARILY_REJECTED and the mode stays: OFFBOARD
  without a live setpoint stream (>= 2 setpoints in the last second, the newest younger
  than COM_OF_LOSS_T), and POSCTL, ALTCTL, MANUAL, STABILIZED, ACRO (``px4.STICK_MODES``)
  without stick input (``rc_present`` false, the default, and no MAVLink joystick, or
  COM_RC_IN_MODE excluding them). COMPONENT_ARM_DISARM (400), answered once (after
  ``verdict_delay_s``): DENIED in the air or in LAND/RTL, TEMPORARILY_REJECTED ("Resolve
  system health failures") when the current mode cannot run; disarming in the air only
  with the 21196 force code. Also answered: SET_MESSAGE_INTERVAL (511), REQUEST_MESSAGE
  (512), REQUEST_AUTOPILOT_CAPABILITIES (520), NAV_TAKEOFF (22), NAV_LAND (21), NAV_RETURN
  (20); anything else MAV_RESULT_UNSUPPORTED;
- PARAM_REQUEST_READ / PARAM_REQUEST_LIST / PARAM_SET -> PARAM_VALUE (INT32 parameters
  byte-wise encoded as PX4 does). A PARAM_SET value that is NaN, infinite, not an allowed
  enum value or outside the parameter's range (:data:`PARAMS`) is refused: the value stays,
  and PARAM_VALUE answers with the old one;
- MAVLink 2 signing (``signing_key_file``): unsigned or wrongly signed messages of any
  kind (PARAM_SET, COMMAND_LONG, setpoints) are dropped by the link unless
  ``allow_unsigned``;
- AUTOPILOT_VERSION (PX4 v1.16.0, MAVLink 2, offboard capabilities);
- telemetry at PX4's "onboard" link rates (:data:`DEFAULT_RATES`, ``stream_rates``
  overrides, SET_MESSAGE_INTERVAL at run time): ATTITUDE and ATTITUDE_QUATERNION (both),
  LOCAL_POSITION_NED, ODOMETRY (pose and velocity in MAV_FRAME_LOCAL_NED as EKF2 publishes
  them; ``time_usec`` is the estimator's IMU sample time, ``odometry_lag_s`` before the
  ATTITUDE_QUATERNION / LOCAL_POSITION_NED stamps of the same state, so a decoder that
  orders all streams by time sees ODOMETRY out of order, as with PX4), GLOBAL_POSITION_INT,
  HIGHRES_IMU, ESC_STATUS (only with ``esc_telemetry``; SIH and PWM ESCs have none: the
  stream can be configured but never sends), SERVO_OUTPUT_RAW (16 outputs, PWM us: motors
  1000 + 1000 u_ESC, disarmed and unused outputs 900, as SIH's pwm_out_sim) and
  ACTUATOR_OUTPUT_STATUS (``active`` 16, the same PWM values, or u_ESC in [0, 1] for the
  motors and 0 elsewhere with ``actuator_output_scale: normalized``; off by default as in
  PX4, SET_MESSAGE_INTERVAL enables it), RC_CHANNELS (only with an RC), SYS_STATUS
  (RC_RECEIVER present/healthy while stick input is valid), EXTENDED_SYS_STATE,
  HOME_POSITION.

Behaviour:
- OFFBOARD accepts SET_POSITION_TARGET_LOCAL_NED (velocity, optional yaw rate,
  position; MAV_FRAME_LOCAL_NED, or MAV_FRAME_BODY_NED / BODY_FRD rotated by yaw only, as
  PX4 does) and SET_ATTITUDE_TARGET body rates + thrust (PX4 rate loop, P term only:
  tau = K_p (omega_sp - omega), unit quad-X allocation);
- offboard loss while armed (no setpoint for COM_OF_LOSS_T) -> failsafe COM_OBL_RC_ACT
  (``px4.OBL_ACTION_MODES``: 0 Position, 1 Altitude, 2 Stabilized, 3 Return, 4 Land,
  5 Hold; 6 Terminate and 7 Disarm stop the motors); the HEARTBEAT shows the failsafe
  mode and MAV_STATE_CRITICAL. A stick mode (0, 1, 2) without stick input cannot run: the
  vehicle logs "Matching flight task was not able to run, Nav state: N" and flies PX4's
  emergency Descend task (FlightTaskDescend: level attitude, vertical speed
  MPC_LAND_SPEED, no horizontal position or velocity control) down to the ground. The
  failsafe ends when the user selects a mode or on disarm (PX4's OnModeChangeOrDisarm);
  the mode shown is then the user's last choice again (e.g. OFFBOARD after a failsafe
  descent and "Disarmed by landing", as PX4 v1.16 SIH does);
- armed but no takeoff within COM_DISARM_PRFLT -> disarm; landed for COM_DISARM_LAND
  after a flight -> disarm. Disarming does not change the user's mode: the HEARTBEAT
  keeps showing it (e.g. OFFBOARD) until someone changes it, and no failsafe acts while
  disarmed;
- physics: seed 0 quadrotor (models/quadrotor.py, RK4 at ``physics_hz``; rotor speeds
  follow the first-order motor model of seed 0 Eq. 8, ESC_STATUS reports them) with the
  PX4-like cascaded controller (control/baseline.py) tracking the velocity setpoints of
  every mode (HOLD/POSCTL/ALTCTL hold position/altitude with a P loop, LAND descends at
  MPC_LAND_SPEED, RTL flies home then lands); flat ground at z = 0.

Network exposure: a ``udpout`` URL (PX4 SITL style: send to the offboard port) binds its
socket explicitly before the first datagram, to ``bind`` or, by default, to the local
interface that routes to the destination (127.0.0.1 for a loopback destination), never
to all interfaces; ``udpin:0.0.0.0`` and similar all-interface URLs are logged as a risk.

The vehicle is a polled object: ``step(now)`` advances physics to ``now`` (fixed steps),
serves the link and sends due telemetry. :meth:`SimVehicle.run_realtime` drives it from the
wall clock; tests may call ``step`` with a simulated clock (lock-step, faster than real time).
"""

from __future__ import annotations

import logging
import math
import socket
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.io import frames
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.link import LinkConfig, MavlinkLink, parse_url, warn_if_all_interfaces
from lpv_sysid.mavlink.telemetry import euler_to_quat
from lpv_sysid.config_fields import check_config_keys, is_finite_number

log = logging.getLogger(__name__)

MAV_TYPE_QUADROTOR = 2
MAV_AUTOPILOT_PX4 = 12
MAV_STATE_STANDBY, MAV_STATE_ACTIVE, MAV_STATE_CRITICAL = 3, 4, 5
MAV_LANDED_STATE_ON_GROUND, MAV_LANDED_STATE_IN_AIR = 1, 2
MAV_FRAME_LOCAL_NED = 1
MAV_ESTIMATOR_TYPE_AUTOPILOT = 8
MAV_SYS_STATUS_SENSOR_RC_RECEIVER = 0x10000
SENSORS_BASE = 0x3FFF  # gyro .. motor outputs, all present/enabled/healthy
MANUAL_CONTROL_TIMEOUT_S = 0.5  # a MAVLink joystick counts this long after its last message
N_OUTPUTS = 16  # actuator outputs PX4 SIH reports (ACTUATOR_OUTPUT_STATUS.active)


@dataclass(frozen=True)
class ParamSpec:
    """A served PX4 parameter: default (PX4 v1.16 unless noted), MAV_PARAM_TYPE, range."""

    default: float
    ptype: int
    lo: float
    hi: float
    values: frozenset[int] | None = None  # enum parameters: the allowed values

    def check(self, name: str, value: float | int) -> str | None:
        """Why ``value`` is refused (None: accepted)."""
        if isinstance(value, bool) or not is_finite_number(value):
            return f"{name} = {value!r} is not a finite number"
        if self.ptype == px4.MAV_PARAM_TYPE_INT32 and float(value) != int(value):
            return f"{name} is an integer parameter, got {value!r}"
        if self.values is not None and int(value) not in self.values:
            return f"{name} = {value!r} is not one of {sorted(self.values)}"
        if not self.lo <= float(value) <= self.hi:
            return f"{name} = {value!r} is outside [{self.lo:g}, {self.hi:g}]"
        return None


_R32, _I32 = px4.MAV_PARAM_TYPE_REAL32, px4.MAV_PARAM_TYPE_INT32
#: PX4 parameters served. Ranges: the @min/@max or @value lists of PX4 v1.16's parameter
#: metadata; where PX4 declares none (COM_DISARM_*, MIS_TAKEOFF_ALT) a plausibility bound.
PARAMS: dict[str, ParamSpec] = {
    "COM_OF_LOSS_T": ParamSpec(1.0, _R32, 0.0, 60.0),
    "COM_OBL_RC_ACT": ParamSpec(0, _I32, 0, 7, frozenset(range(8))),
    "COM_DISARM_PRFLT": ParamSpec(10.0, _R32, -1.0, 3600.0),
    "COM_DISARM_LAND": ParamSpec(2.0, _R32, -1.0, 3600.0),
    "COM_RC_IN_MODE": ParamSpec(
        1, _I32, 0, 4, frozenset(range(5))
    ),  # v1.16 SIH SITL: 1 joystick only
    "COM_RC_LOSS_T": ParamSpec(0.5, _R32, 0.0, 35.0),
    "COM_RCL_EXCEPT": ParamSpec(4, _I32, 0, 15),  # bit 2: ignore RC loss in offboard (sim default)
    "NAV_DLL_ACT": ParamSpec(0, _I32, 0, 6, frozenset({0, 1, 2, 3, 5, 6})),
    "MPC_XY_VEL_MAX": ParamSpec(12.0, _R32, 0.0, 20.0),
    "MPC_Z_VEL_MAX_UP": ParamSpec(3.0, _R32, 0.5, 8.0),
    "MPC_Z_VEL_MAX_DN": ParamSpec(1.5, _R32, 0.5, 4.0),
    "MPC_LAND_SPEED": ParamSpec(0.7, _R32, 0.6, 4.0),
    "MIS_TAKEOFF_ALT": ParamSpec(2.5, _R32, 0.0, 1000.0),
    "MC_ROLLRATE_P": ParamSpec(0.15, _R32, 0.01, 0.5),
    "MC_PITCHRATE_P": ParamSpec(0.15, _R32, 0.01, 0.6),
    "MC_YAWRATE_P": ParamSpec(0.2, _R32, 0.0, 0.6),
    "MAV_SYS_ID": ParamSpec(1, _I32, 1, 250),
}
#: name -> (default, MAV_PARAM_TYPE)
DEFAULT_PARAMS: dict[str, tuple[float, int]] = {k: (v.default, v.ptype) for k, v in PARAMS.items()}

#: default stream rates [Hz] before any SET_MESSAGE_INTERVAL: PX4 v1.16 mavlink_main.cpp,
#: MAVLINK_MODE_ONBOARD (the SITL offboard link); 0 = off until requested
DEFAULT_RATES: dict[str, float] = {
    "ATTITUDE": 100.0,
    "ATTITUDE_QUATERNION": 50.0,
    "LOCAL_POSITION_NED": 30.0,
    "ODOMETRY": 30.0,
    "GLOBAL_POSITION_INT": 50.0,
    "HIGHRES_IMU": 50.0,
    "ESC_STATUS": 10.0,
    "SERVO_OUTPUT_RAW": 10.0,
    "ACTUATOR_OUTPUT_STATUS": 0.0,
    "RC_CHANNELS": 20.0,
    "SYS_STATUS": 5.0,
    "EXTENDED_SYS_STATE": 5.0,
    "HOME_POSITION": 0.5,
}
HOME_LAT, HOME_LON, HOME_ALT = 47.397742, 8.545594, 488.0  # PX4 SITL default home
ACTUATOR_OUTPUT_SCALES = ("pwm", "normalized")


def parse_hostport(text: str, what: str) -> tuple[str, int]:
    """``HOST`` or ``HOST:PORT`` -> (host, port); port 0 = any free port."""
    if not isinstance(text, str) or not text.strip():
        raise ConfigError(f"{what} must be HOST or HOST:PORT, got {text!r}")
    host, sep, port = text.strip().rpartition(":")
    if not sep:
        host, port = text.strip(), "0"
    try:
        p = int(port)
    except ValueError:
        raise ConfigError(f"{what} {text!r}: port {port!r} is not an integer") from None
    if not 0 <= p < 65536:
        raise ConfigError(f"{what} {text!r}: port {p} out of range")
    return host, p


@dataclass(frozen=True)
class SimVehicleConfig:
    """Options of the simulated vehicle (``config/sim_vehicle_px4.yaml``, module docstring)."""

    url: str = "udpout:127.0.0.1:14540"  # PX4 SITL sends to the offboard port 14540
    bind: str | None = None  # udpout: local HOST[:PORT]; None: route to url's host
    system_id: int = 1
    component_id: int = 1
    physics_hz: float = 250.0
    params: Mapping[str, float] = field(default_factory=dict)  # overrides of PARAMS defaults
    initial_mode: str = "HOLD"
    signing_key_file: str | None = None
    allow_unsigned: bool = False
    sensor_noise: bool = False
    seed: int = 0
    rc_present: bool = False  # an RC transmitter is bound (sticks centred)
    esc_telemetry: bool = True  # ESC_STATUS (False: SIH / PWM ESCs)
    actuator_output_scale: str = "pwm"  # ACTUATOR_OUTPUT_STATUS values: pwm | normalized
    stream_rates: Mapping[str, float] = field(default_factory=dict)  # overrides of DEFAULT_RATES
    double_ack: bool = True  # PX4 v1.16: DO_SET_MODE ACCEPTED, then the verdict
    verdict_delay_s: float = 0.01  # commander verdict after the first ACK (0-15 ms measured)
    odometry_lag_s: float = 0.004  # ODOMETRY time_usec behind the other stamps
    duplicate_acks: bool = False  # additionally send every COMMAND_ACK twice

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SimVehicleConfig":
        check_config_keys(d, cls.__dataclass_fields__, "sim vehicle")
        kw = dict(d)
        for k in ("params", "stream_rates"):
            if kw.get(k) is None:
                kw.pop(k, None)
        cfg = cls(**kw)
        cfg.validate()
        return cfg

    @classmethod
    def load(cls, path: str) -> "SimVehicleConfig":
        from lpv_sysid.io.yaml_file import read_yaml_mapping

        d = read_yaml_mapping(path, f"sim vehicle config {path}")
        try:
            return cls.from_dict(d)
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from None

    def validate(self) -> None:
        if not isinstance(self.url, str):
            raise ConfigError(f"sim vehicle url must be a string, got {self.url!r}")
        parse_url(self.url)
        if self.bind is not None:
            parse_hostport(self.bind, "sim vehicle bind")
        if not isinstance(self.physics_hz, (int, float)) or isinstance(self.physics_hz, bool):
            raise ConfigError(f"sim vehicle physics_hz must be a number, got {self.physics_hz!r}")
        from lpv_sysid.sim.vehicle import MAX_PHYSICS_HZ

        if not (50.0 <= self.physics_hz <= MAX_PHYSICS_HZ):  # NaN fails too
            raise ConfigError(
                f"sim vehicle physics_hz must be in [50, {MAX_PHYSICS_HZ:g}] Hz, got "
                f"{self.physics_hz!r}"
            )
        for name in ("system_id", "component_id"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 255:
                raise ConfigError(f"sim vehicle {name} must be an integer 1..255, got {v!r}")
        if not isinstance(self.params, Mapping):
            raise ConfigError("sim vehicle params must be a mapping NAME: value")
        for k, v in self.params.items():
            if k not in PARAMS:
                raise ConfigError(f"sim vehicle: unknown parameter {k!r}; known: {sorted(PARAMS)}")
            err = PARAMS[k].check(k, v)
            if err is not None:
                raise ConfigError(f"sim vehicle: parameter {err}")
        if not isinstance(self.stream_rates, Mapping):
            raise ConfigError("sim vehicle stream_rates must be a mapping MESSAGE: rate_hz")
        for k, v in self.stream_rates.items():
            if k not in DEFAULT_RATES:
                raise ConfigError(
                    f"sim vehicle stream_rates: unknown stream {k!r}; known: "
                    f"{sorted(DEFAULT_RATES)}"
                )
            if not (is_finite_number(v) and 0 <= v <= 1000):
                raise ConfigError(
                    f"sim vehicle stream_rates.{k} must be a rate in [0, 1000] Hz, got {v!r}"
                )
        for name in (
            "allow_unsigned",
            "sensor_noise",
            "rc_present",
            "esc_telemetry",
            "double_ack",
            "duplicate_acks",
        ):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(
                    f"sim vehicle {name} must be true or false, got {getattr(self, name)!r}"
                )
        if self.actuator_output_scale not in ACTUATOR_OUTPUT_SCALES:
            raise ConfigError(
                f"sim vehicle actuator_output_scale must be one of {ACTUATOR_OUTPUT_SCALES}, "
                f"got {self.actuator_output_scale!r}"
            )
        for name, hi in (("verdict_delay_s", 1.0), ("odometry_lag_s", 0.1)):
            v = getattr(self, name)
            if not (is_finite_number(v) and 0 <= v <= hi):
                raise ConfigError(f"sim vehicle {name} must be in [0, {hi}] s, got {v!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(
                f"sim vehicle seed must be a non-negative integer, got {self.seed!r}"
            )
        if px4.mode_by_name(self.initial_mode) == px4.OFFBOARD:
            raise ConfigError(
                "sim vehicle initial_mode cannot be OFFBOARD (PX4 needs a setpoint stream)"
            )


@dataclass
class _Setpoint:
    kind: str  # "velocity" | "position" | "rates"
    t: float
    v_ned: np.ndarray | None = None
    pos_ned: np.ndarray | None = None
    yaw_rate: float = 0.0
    rates: np.ndarray | None = None
    thrust: float = 0.0


class SimVehicle:
    """See module docstring."""

    def __init__(
        self,
        config: SimVehicleConfig | None = None,
        model: Any = None,
        controller_factory: Callable[[], Any] | None = None,
        link: MavlinkLink | None = None,
    ) -> None:
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
            self.params[k] = (v, PARAMS[k].ptype)
        self.link = link or MavlinkLink(
            LinkConfig(
                url=self.config.url,
                source_system=self.config.system_id,
                source_component=self.config.component_id,
                streams=(),
                signing_key_file=self.config.signing_key_file,
                allow_unsigned=self.config.allow_unsigned,
                mav_type=MAV_TYPE_QUADROTOR,
            )
        )
        self._rng = np.random.default_rng(self.config.seed)
        self.dt = 1.0 / self.config.physics_hz
        self.t = 0.0  # simulated time since boot [s]
        self.x = np.zeros(16)  # FULL_STATE_NAMES, on the ground, motors off
        self.u = np.zeros(4)
        self.armed = False
        self.mode = px4.mode_by_name(self.config.initial_mode)  # what the HEARTBEAT shows
        self.user_mode = self.mode  # the mode last chosen by a user (PX4 user intention)
        self.failsafe_active = False
        self.landed = True
        self.took_off = False
        self.t_armed = 0.0
        self.t_landed = 0.0
        self.hold_pos = np.zeros(3)
        self.descending = False  # emergency Descend task (stick mode without sticks)
        self.setpoint: _Setpoint | None = None
        self._sp_times: list[float] = []
        self.setpoints_received = 0
        self.mode_log: list[tuple[float, str, str]] = []  # (t, mode name, reason)
        self.px4_log: list[tuple[float, str]] = []  # what PX4 would print (errors, warnings)
        self.acks_sent: list[tuple[float, int, int]] = []  # (t, command, result)
        self.param_rejections: list[tuple[float, str]] = []
        self.failsafe_reason = ""
        self.gcs_last_heartbeat: float | None = None
        self.local_address: tuple[str, int] | None = None
        self._t_joystick = -math.inf
        self._verdicts: list[tuple[float, int, Callable[[], int]]] = []
        self.intervals: dict[int, float] = {}
        self._next_send: dict[int, float] = {}
        self._next_hb = 0.0
        self._opened = False
        mod = px4.dialect_module(px4.DEFAULT_DIALECT)
        self._mod = mod
        self._stream_ids = {
            name: (
                px4.MAVLINK_MSG_ID_ESC_STATUS
                if name == "ESC_STATUS"
                else getattr(mod, f"MAVLINK_MSG_ID_{name}")
            )
            for name in DEFAULT_RATES
        }
        rates = {**DEFAULT_RATES, **dict(self.config.stream_rates)}
        for name, rate in rates.items():
            self.intervals[self._stream_ids[name]] = 1.0 / rate if rate > 0 else -1.0
        self._esc_cls = px4.esc_status_class(px4.DEFAULT_DIALECT)

    # ------------------------------------------------------------- lifecycle
    def open(self) -> None:
        self.link.open(self.t)
        self._opened = True
        self._bind_local()

    def close(self) -> None:
        self.link.close()
        self._opened = False

    def param(self, name: str) -> float:
        return float(self.params[name][0])

    def _bind_local(self) -> None:
        """Bind a udpout socket before its first datagram (else the OS binds 0.0.0.0)."""
        sock = getattr(self.link.conn, "port", None)
        if not isinstance(sock, socket.socket):
            return
        device, _ = parse_url(self.config.url)
        if device.startswith("udpout:"):
            _, dest_host, dest_port = device.split(":")
            if self.config.bind is not None:
                host, port = parse_hostport(self.config.bind, "sim vehicle bind")
            else:
                host, port = _route_source(dest_host, int(dest_port)), 0
            warn_if_all_interfaces(f"sim vehicle {self.config.url!r} (bind {host}:{port})", host)
            try:
                sock.bind((host, port))
            except OSError as exc:
                self.close()
                raise LpvSysidError(
                    f"sim vehicle: cannot bind {host}:{port} for {self.config.url!r}: "
                    f"{exc.strerror or exc}"
                ) from None
        try:
            name = sock.getsockname()
            self.local_address = (str(name[0]), int(name[1]))
        except OSError:
            self.local_address = None

    # ------------------------------------------------------------------ loop
    def step(self, now: float) -> None:
        """Advance to ``now`` (seconds since boot): physics, messages, telemetry."""
        if self._opened:
            for msg in self.link.poll(now):
                self._handle(msg, now)
        while self.t + self.dt <= now + 1e-9:
            self._physics_step()
            self._supervise(self.t)
            self._run_verdicts(self.t)
        self._run_verdicts(self.t)
        if self._opened:
            self._send_telemetry(now)

    def run_realtime(
        self,
        duration: float | None = None,
        stop: Callable[[], bool] | None = None,
        period: float = 0.002,
        speed: float = 1.0,
    ) -> None:
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
        xn = np.array(
            [
                a + dt / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4)
                for a, b1, b2, b3, b4 in zip(xl, k1, k2, k3, k4)
            ]
        )
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
            self.ctrl.reset()  # PX4 keeps idle and resets integrators on ground
            return self.model.mix @ np.full(4, 0.1)
        v_body = self._R(x).T @ v_ned
        # STATE_NAMES order: phi, theta, body velocity, body rates, delta (unused) = 0
        controller_state = np.concatenate([x[3:5], x[6:12], np.zeros(4)])
        return np.asarray(self.ctrl.step(self.t, controller_state, v_body, yaw_rate), dtype=float)

    def _velocity_setpoint(self) -> tuple[np.ndarray, float]:
        x = self.x
        pos = x[0:3]
        m = self.mode
        if self.descending:
            # FlightTaskDescend: vertical speed MPC_LAND_SPEED, zero horizontal acceleration
            # (the horizontal reference follows the vehicle: nothing holds or brakes it)
            v = self._R(x) @ x[6:9]
            return np.array([v[0], v[1], self.param("MPC_LAND_SPEED")]), 0.0
        if m == px4.OFFBOARD and self.setpoint is not None:
            sp = self.setpoint
            if sp.kind == "velocity" and sp.v_ned is not None:
                return sp.v_ned.copy(), sp.yaw_rate
            if sp.kind == "position" and sp.pos_ned is not None:
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
        # HOLD, POSCTL/ALTCTL/STABILIZED with centred sticks, OFFBOARD without setpoint
        v = _clip_norm(1.0 * (self.hold_pos - pos), 3.0)
        if m in (px4.ALTCTL, px4.MANUAL, px4.STABILIZED):
            v[0:2] = 0.0
        return v, 0.0

    def _rate_mode(self, sp: _Setpoint) -> np.ndarray:
        """PX4 rate loop, P term: tau = K_p (omega_sp - omega); unit quad-X allocation."""
        kp = np.array(
            [self.param("MC_ROLLRATE_P"), self.param("MC_PITCHRATE_P"), self.param("MC_YAWRATE_P")]
        )
        rates = sp.rates if sp.rates is not None else np.zeros(3)  # set with kind "rates"
        tau = kp * (rates - self.x[9:12])
        alloc = np.array(
            [
                [1.0, -1.0, 1.0, 1.0],
                [1.0, 1.0, -1.0, 1.0],
                [1.0, 1.0, 1.0, -1.0],
                [1.0, -1.0, -1.0, -1.0],
            ]
        )
        u_esc = np.clip(alloc @ np.r_[sp.thrust, tau], 0.0, 1.0)
        return self.model.mix @ u_esc

    # ------------------------------------------------------------ supervision
    def sticks_available(self, now: float | None = None) -> bool:
        """Manual control input as PX4 sees it (RC and/or MAVLink joystick, COM_RC_IN_MODE)."""
        t = self.t if now is None else now
        joystick = t - self._t_joystick <= MANUAL_CONTROL_TIMEOUT_S
        return px4.sticks_available(
            int(self.param("COM_RC_IN_MODE")), self.config.rc_present, joystick
        )

    def _supervise(self, t: float) -> None:
        if self.mode == px4.OFFBOARD and self.armed:  # PX4's failsafes act only while armed
            last = self.setpoint.t if self.setpoint is not None else -math.inf
            if t - last > self.param("COM_OF_LOSS_T"):
                self._offboard_lost(t)
        if self.armed and self.landed:
            prflt, land = self.param("COM_DISARM_PRFLT"), self.param("COM_DISARM_LAND")
            if not self.took_off and prflt > 0 and t - self.t_armed > prflt:
                self._disarm(t, "no takeoff within COM_DISARM_PRFLT")
            elif self.took_off and land > 0 and t - self.t_landed > land:
                self._disarm(t, "landed (COM_DISARM_LAND)")

    def _offboard_lost(self, t: float) -> None:
        act = int(self.param("COM_OBL_RC_ACT"))
        reason = (
            f"offboard lost for > COM_OF_LOSS_T = {self.param('COM_OF_LOSS_T')} s "
            f"(COM_OBL_RC_ACT={act})"
        )
        self.failsafe_reason = reason
        log.warning(reason)
        self.px4_log.append((t, "Failsafe activated"))
        target = next((mode for a, mode in px4.OBL_ACTION_MODES.items() if a == act), None)
        if target is None:  # 6 terminate, 7 disarm: motors off
            self.mode_log.append((t, self.mode.name, reason))
            self._disarm(t, reason)
            return
        self._set_mode(target, t, reason, failsafe=True)
        if target in px4.STICK_MODES and not self.sticks_available(t):
            msg = f"Matching flight task was not able to run, Nav state: {px4.NAV_STATES[target]}"
            log.error(msg)
            self.px4_log.append((t, msg))
            self.mode_log[-1] = (t, target.name, f"{reason}; {msg}: emergency descent")
            self.descending = True
            if hasattr(self.ctrl, "vel_int"):  # Descend task: no horizontal acceleration
                self.ctrl.vel_int[0] = self.ctrl.vel_int[1] = 0.0

    def _set_mode(self, mode: px4.Px4Mode, t: float, reason: str, failsafe: bool = False) -> None:
        """Enter ``mode``: a failsafe's (the user's choice is kept) or a user's (ends a
        failsafe)."""
        if mode != self.mode or self.descending:
            self.mode_log.append((t, mode.name, reason))
        self.mode = mode
        self.failsafe_active = failsafe
        if not failsafe:
            self.user_mode = mode
            self.failsafe_reason = ""
        self.descending = False
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
        if self.failsafe_active:  # cleared on disarm: the user's mode again
            self._set_mode(self.user_mode, t, "failsafe cleared on disarm")

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
        elif mt == "MANUAL_CONTROL":
            self._t_joystick = now
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
            self._param_set(m, now)

    def _param_set(self, m: Any, now: float) -> None:
        name = px4.param_id_str(m.param_id)
        if name not in self.params:
            return
        spec = PARAMS[name]
        value = px4.param_from_wire(m.param_value, spec.ptype)
        err = spec.check(name, value)
        if err is not None:
            log.warning(
                "PARAM_SET from %d/%d refused: %s; %s stays %g",
                m.get_srcSystem(),
                m.get_srcComponent(),
                err,
                name,
                self.param(name),
            )
            self.param_rejections.append((now, err))
        else:
            self.params[name] = (value, spec.ptype)
        self._send_param(name)

    def _send_param(self, name: str) -> None:
        names = list(self.params)
        value, ptype = self.params[name]
        self.link.send(
            self.link.codec.param_value_encode(
                name.encode("ascii"),
                px4.param_to_wire(value, ptype),
                ptype,
                len(names),
                names.index(name),
            )
        )

    def _ack(self, cmd: int, result: int) -> None:
        self.acks_sent.append((self.t, cmd, result))
        for _ in range(2 if self.config.duplicate_acks else 1):
            self.link.send(self.link.codec.command_ack_encode(cmd, result, 0, 0, 0, 0))

    def _commander(self, cmd: int, now: float, verdict: Callable[[], int]) -> None:
        """A command PX4's commander decides ``verdict_delay_s`` later; DOUBLE_ACK_COMMANDS
        are ACCEPTED at once by the MAVLink receiver as well (``double_ack``)."""
        if not self.config.double_ack:
            self._ack(cmd, verdict())
            return
        if cmd in px4.DOUBLE_ACK_COMMANDS:
            self._ack(cmd, px4.MAV_RESULT_ACCEPTED)
        self._verdicts.append((now + self.config.verdict_delay_s, cmd, verdict))

    def _run_verdicts(self, t: float) -> None:
        while self._verdicts and self._verdicts[0][0] <= t + 1e-9:
            _, cmd, verdict = self._verdicts.pop(0)
            self._ack(cmd, verdict())

    def _command(self, m: Any, now: float) -> None:
        c = m.command
        if c == px4.MAV_CMD_COMPONENT_ARM_DISARM:
            p1, p2 = float(m.param1), float(m.param2)
            return self._commander(c, now, lambda: self._arm_verdict(p1, p2))
        if c == px4.MAV_CMD_DO_SET_MODE:
            p1, p2, p3 = float(m.param1), float(m.param2), float(m.param3)
            return self._commander(c, now, lambda: self._set_mode_verdict(p1, p2, p3))
        if c == px4.MAV_CMD_SET_MESSAGE_INTERVAL:
            mid, interval = int(m.param1), m.param2
            if mid not in self._stream_ids.values():
                return self._ack(c, px4.MAV_RESULT_UNSUPPORTED)
            default = DEFAULT_RATES[next(k for k, v in self._stream_ids.items() if v == mid)]
            if interval < 0:
                self.intervals[mid] = -1.0
            elif interval == 0:
                self.intervals[mid] = 1.0 / default if default > 0 else -1.0
            else:
                self.intervals[mid] = max(interval * 1e-6, 1.0 / 400.0)
            self._next_send[mid] = now
            return self._ack(c, px4.MAV_RESULT_ACCEPTED)
        if c in (px4.MAV_CMD_REQUEST_MESSAGE, px4.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES):
            mid = 148 if c == px4.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES else int(m.param1)
            if mid == 148:
                self._ack(c, px4.MAV_RESULT_ACCEPTED)
                return self._send_autopilot_version()
            if mid in self._stream_ids.values():
                if not self._stream_has_data(mid):
                    return self._ack(c, px4.MAV_RESULT_FAILED)
                self._ack(c, px4.MAV_RESULT_ACCEPTED)
                return self._send_stream(mid, now)
            return self._ack(c, px4.MAV_RESULT_UNSUPPORTED)
        if c == px4.MAV_CMD_NAV_TAKEOFF:
            if not self.armed:
                return self._ack(c, px4.MAV_RESULT_DENIED)
            self._set_mode(px4.TAKEOFF, self.t, "NAV_TAKEOFF")
            return self._ack(c, px4.MAV_RESULT_ACCEPTED)
        if c in (px4.MAV_CMD_NAV_LAND, px4.MAV_CMD_NAV_RETURN_TO_LAUNCH):
            self._set_mode(px4.LAND if c == px4.MAV_CMD_NAV_LAND else px4.RTL, self.t, "command")
            return self._ack(c, px4.MAV_RESULT_ACCEPTED)
        return self._ack(c, px4.MAV_RESULT_UNSUPPORTED)

    def _can_run(self, mode: px4.Px4Mode) -> bool:
        """Whether the flight task of ``mode`` has what it needs (stream, stick input)."""
        if mode == px4.OFFBOARD:
            return self._stream_alive(self.t)
        if mode in px4.STICK_MODES:
            return self.sticks_available()
        return True

    def _arm_verdict(self, p1: float, p2: float) -> int:
        t = self.t
        if p1 >= 0.5:
            if self.armed:
                return px4.MAV_RESULT_ACCEPTED
            if not self.landed or self.mode in (px4.LAND, px4.RTL):
                return px4.MAV_RESULT_DENIED
            if not self._can_run(self.mode):
                msg = (
                    "Arming denied: Resolve system health failures first "
                    f"({self.mode.name} cannot run)"
                )
                log.warning(msg)
                self.px4_log.append((t, msg))
                return px4.MAV_RESULT_TEMPORARILY_REJECTED
            self._arm(t)
            return px4.MAV_RESULT_ACCEPTED
        if self.landed or int(round(p2)) == px4.FORCE_DISARM_MAGIC:
            self._disarm(t, "disarm command")
            return px4.MAV_RESULT_ACCEPTED
        return px4.MAV_RESULT_DENIED

    def _set_mode_verdict(self, p1: float, p2: float, p3: float) -> int:
        if not int(p1) & px4.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return px4.MAV_RESULT_UNSUPPORTED
        mode = px4.Px4Mode(int(p2), int(p3))
        if mode.main == px4.MAIN_AUTO and mode.sub == 0:
            mode = px4.HOLD
        if mode.name.startswith("UNKNOWN"):
            return px4.MAV_RESULT_UNSUPPORTED
        if self.armed and not self._can_run(mode):  # disarmed: PX4 always allows the change
            msg = f"Switching to {mode.name} is currently not possible"
            log.warning(msg)
            self.px4_log.append((self.t, msg))
            return px4.MAV_RESULT_TEMPORARILY_REJECTED
        self._set_mode(mode, self.t, "DO_SET_MODE")  # a user's choice also ends a failsafe
        return px4.MAV_RESULT_ACCEPTED

    def _stream_alive(self, now: float) -> bool:
        self._sp_times = [t for t in self._sp_times if now - t <= 1.0]
        return (
            len(self._sp_times) >= 2
            and self.setpoint is not None
            and now - self._sp_times[-1] <= self.param("COM_OF_LOSS_T")
        )

    def _sp_received(self, now: float, sp: _Setpoint) -> None:
        self.setpoint = sp
        self.setpoints_received += 1
        self._sp_times.append(now)
        if len(self._sp_times) > 200:
            self._sp_times = self._sp_times[-100:]

    def _position_target(self, m: Any, now: float) -> None:
        mask = m.type_mask
        frame = m.coordinate_frame
        if frame in (8, 12):  # BODY_NED / BODY_FRD: PX4 rotates by yaw only
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
            sp = _Setpoint(
                "position", self.t, v_ned=vel if use_vel else None, pos_ned=pos, yaw_rate=yaw_rate
            )
        elif use_vel:
            sp = _Setpoint("velocity", self.t, v_ned=vel, yaw_rate=yaw_rate)
        else:
            return
        sp.t = now
        self._sp_received(now, sp)

    def _attitude_target(self, m: Any, now: float) -> None:
        if not m.type_mask & 128:  # attitude quaternion setpoints: not modelled
            return
        rates = np.array([m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate], dtype=float)
        if not np.isfinite(rates).all() or not math.isfinite(m.thrust):
            return
        self._sp_received(now, _Setpoint("rates", now, rates=rates, thrust=float(m.thrust)))

    # ------------------------------------------------------------ telemetry
    def motor_outputs(self) -> tuple[np.ndarray, np.ndarray]:
        """(u_ESC in [0, 1], PWM us) of the motors as PX4 writes them (disarmed: 0, 900 us)."""
        if not self.armed:
            n = len(self.x[12:16])
            return np.zeros(n), np.full(n, px4.PWM_DISARMED_US)
        u_esc = np.asarray(self.model.u_esc(self.u), dtype=float)
        return u_esc, np.array([px4.pwm_from_u_esc(u) for u in u_esc])

    def _outputs16(self) -> tuple[list[float], list[float]]:
        """All 16 outputs (normalised, PWM): motors first, the unused ones idle at 0 / 900 us."""
        u_esc, pwm = self.motor_outputs()
        pad = N_OUTPUTS - len(pwm)
        return [float(u) for u in u_esc] + [0.0] * pad, [float(p) for p in pwm] + [
            px4.PWM_DISARMED_US
        ] * pad

    def _stream_has_data(self, mid: int) -> bool:
        sid = self._stream_ids
        if mid == sid["ESC_STATUS"]:
            return self.config.esc_telemetry
        if mid == sid["RC_CHANNELS"]:
            return self.config.rc_present
        return True

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
                if self._stream_has_data(mid):
                    self._send_stream(mid, now)

    def _heartbeat(self) -> None:
        state = MAV_STATE_ACTIVE if self.armed else MAV_STATE_STANDBY
        if self.failsafe_reason and self.armed:
            state = MAV_STATE_CRITICAL
        self.link.send(
            self.link.codec.heartbeat_encode(
                MAV_TYPE_QUADROTOR,
                MAV_AUTOPILOT_PX4,
                px4.base_mode_flags(self.mode, self.armed),
                self.mode.custom_mode,
                state,
            )
        )

    def _send_autopilot_version(self) -> None:
        mod = self._mod
        caps = 0
        for name in (
            "MISSION_FLOAT",
            "PARAM_FLOAT",
            "MISSION_INT",
            "COMMAND_INT",
            "PARAM_ENCODE_BYTEWISE",
            "SET_ATTITUDE_TARGET",
            "SET_POSITION_TARGET_LOCAL_NED",
            "MAVLINK2",
        ):
            caps |= int(getattr(mod, f"MAV_PROTOCOL_CAPABILITY_{name}"))
        self.link.send(
            self.link.codec.autopilot_version_encode(
                caps,
                px4.encode_flight_sw_version(1, 16, 0),
                0,
                0,
                0,
                b"\0" * 8,
                b"\0" * 8,
                b"\0" * 8,
                0,
                0,
                0x1234ABCD,
                [0] * 18,
            )
        )

    def _send_stream(self, mid: int, now: float) -> None:
        c = self.link.codec
        x = self.x
        ms = int(self.t * 1000) & 0xFFFFFFFF
        us = int(self.t * 1e6)
        noise = self.config.sensor_noise

        def rn(s: float, n: int = 3) -> np.ndarray:
            """Sensor noise of standard deviation ``s`` (zeros with sensor_noise off)."""
            return self._rng.normal(0.0, s, n) if noise else np.zeros(n)

        R = self._R(x)
        v_ned = R @ x[6:9]
        sid = self._stream_ids
        if mid == sid["ATTITUDE_QUATERNION"]:
            q = euler_to_quat(*x[3:6])
            w = x[9:12] + rn(0.005)
            c_msg = c.attitude_quaternion_encode(
                ms, *[float(v) for v in q], *[float(v) for v in w], [0.0] * 4
            )
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
            c_msg = c.global_position_int_encode(
                ms,
                int(lat * 1e7),
                int(lon * 1e7),
                int((HOME_ALT - x[2]) * 1000),
                int(-x[2] * 1000),
                *[int(v * 100) for v in v_ned],
                hdg,
            )
        elif mid == sid["HIGHRES_IMU"]:
            if self.armed and not self.landed:
                acc = np.asarray(self.model.specific_force(x, self.u), dtype=float)
            else:
                acc = R.T @ np.array([0.0, 0.0, -9.80665])
            acc = acc + rn(0.05)
            gyr = x[9:12] + rn(0.005)
            c_msg = c.highres_imu_encode(
                us,
                *[float(a) for a in acc],
                *[float(a) for a in gyr],
                0.2,
                0.0,
                0.4,
                1013.0,
                0.0,
                float(-x[2]),
                25.0,
                0x1FF,
                0,
            )
        elif mid == sid["ESC_STATUS"]:
            rpm = [int(round(o * 60.0 / (2 * math.pi))) for o in x[12:16]]
            c_msg = self._esc_cls(0, us, rpm, [16.0] * 4, [0.0] * 4)
        elif mid == sid["SERVO_OUTPUT_RAW"]:
            _, pwm = self._outputs16()
            c_msg = c.servo_output_raw_encode(us & 0xFFFFFFFF, 0, *[int(round(v)) for v in pwm])
        elif mid == sid["ACTUATOR_OUTPUT_STATUS"]:
            u16, pwm = self._outputs16()
            vals = pwm if self.config.actuator_output_scale == "pwm" else u16
            c_msg = c.actuator_output_status_encode(us, N_OUTPUTS, vals + [0.0] * (32 - N_OUTPUTS))
        elif mid == sid["RC_CHANNELS"]:
            chans = [1500, 1500, 1500, 1500, 1000, 1000, 1000, 1000] + [0] * 10  # sticks centred
            c_msg = c.rc_channels_encode(ms, 8, *chans, 200)
        elif mid == sid["SYS_STATUS"]:
            sensors = SENSORS_BASE | (
                MAV_SYS_STATUS_SENSOR_RC_RECEIVER if self.sticks_available(now) else 0
            )
            c_msg = c.sys_status_encode(
                sensors, sensors, sensors, 100, 16000, 500, 80, 0, 0, 0, 0, 0, 0
            )
        elif mid == sid["EXTENDED_SYS_STATE"]:
            c_msg = c.extended_sys_state_encode(
                0, MAV_LANDED_STATE_ON_GROUND if self.landed else MAV_LANDED_STATE_IN_AIR
            )
        elif mid == sid["HOME_POSITION"]:
            c_msg = c.home_position_encode(
                int(HOME_LAT * 1e7),
                int(HOME_LON * 1e7),
                int(HOME_ALT * 1000),
                0.0,
                0.0,
                0.0,
                [1.0, 0.0, 0.0, 0.0],
                0.0,
                0.0,
                0.0,
                us,
            )
        elif mid == sid["ODOMETRY"]:
            # EKF2 vehicle_odometry: timestamp_sample = IMU sample time (before the publish
            # time that stamps ATTITUDE_QUATERNION / LOCAL_POSITION_NED); pose and velocity NED
            q = euler_to_quat(*x[3:6])
            tv = max(self.t - self.config.odometry_lag_s, 0.0)
            nan = float("nan")
            pose_cov = [nan] * 21
            vel_cov = [nan] * 21
            for i, var in ((0, 1e-4), (6, 1e-4), (11, 1e-4), (15, 1e-6), (18, 1e-6), (20, 1e-6)):
                pose_cov[i] = var
            for i in (0, 6, 11):
                vel_cov[i] = 1e-4
            c_msg = c.odometry_encode(
                int(tv * 1e6),
                MAV_FRAME_LOCAL_NED,
                MAV_FRAME_LOCAL_NED,
                *[float(a) for a in x[0:3]],
                [float(a) for a in q],
                *[float(a) for a in v_ned],
                *[float(a) for a in x[9:12]],
                pose_cov,
                vel_cov,
                0,
                MAV_ESTIMATOR_TYPE_AUTOPILOT,
                0,
            )
        else:
            return
        self.link.send(c_msg)


def _route_source(host: str, port: int) -> str:
    """The local address the OS would send from to ``host`` (a UDP connect sends nothing)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.connect((host, port))
        return str(s.getsockname()[0])
    except OSError as exc:
        raise LpvSysidError(
            f"sim vehicle: no local interface routes to {host}:{port} ({exc}); "
            "give the local address with bind (--bind HOST[:PORT])"
        ) from None
    finally:
        s.close()


def _clip_norm(v: np.ndarray, vmax: float) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v * (vmax / n) if n > vmax else v
