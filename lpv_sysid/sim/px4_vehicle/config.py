"""Options of the simulated PX4 vehicle (:class:`SimVehicleConfig`) and the PX4 tables they
are checked against: the served parameters (:data:`PARAMS`) and the telemetry streams with
their default rates (:data:`DEFAULT_RATES`);
the behaviour is described in :mod:`lpv_sysid.sim.px4_vehicle.vehicle`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from lpv_sysid.configuration.fields import check_config_keys, is_finite_number
from lpv_sysid.errors import ConfigError
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.link import parse_url


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
    """Options of the simulated vehicle (``config/sim_vehicle_px4.yaml``; what they select:
    :mod:`lpv_sysid.sim.px4_vehicle.vehicle`)."""

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
        from lpv_sysid.io.files import read_yaml_mapping

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
