"""Options of the simulated PX4 vehicle (:class:`SimVehicleConfig`) and the PX4 tables they
are checked against: the served parameters (:data:`PARAMS`) and the telemetry streams with
their default rates (:data:`DEFAULT_RATES`);
the behaviour is described in :mod:`lpv_sysid.sim.px4_vehicle.vehicle`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from lpv_sysid.configuration import fields as cf
from lpv_sysid.configuration.fields import is_finite_number
from lpv_sysid.errors import ConfigError
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.link import parse_url
from lpv_sysid.sim.vehicle import MAX_PHYSICS_HZ


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
    "MPC_TILTMAX_AIR": ParamSpec(45.0, _R32, 20.0, 89.0),  # served (preflight); not simulated
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
    # thrust + body-rate setpoints PX4 tracks (sent while a SET_ATTITUDE_TARGET rates setpoint
    # is flown in OFFBOARD: the echo of what arrived; the sim's own cascade has no rate stage)
    "ATTITUDE_TARGET": 10.0,
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
    :mod:`lpv_sysid.sim.px4_vehicle.vehicle`), checked by :meth:`validate` (also for a config
    built in code: the vehicle calls it)."""

    url: str = cf.text(
        "udpout:127.0.0.1:14540", "connection URL (PX4 SITL sends to the offboard port 14540)"
    )
    bind: str | None = cf.text(
        None,
        "udpout: local HOST[:PORT]; null: the interface routing to url's host",
        optional=True,
    )
    system_id: int = cf.count(1, "MAVLink system id", lo=1, hi=255)
    component_id: int = cf.count(1, "MAVLink component id", lo=1, hi=255)
    physics_hz: float = cf.number(
        250.0,
        f"RK4 physics and controller rate [Hz]; 50 .. {MAX_PHYSICS_HZ:g} Hz (every simulated "
        "second costs physics_hz steps)",
        lo=50.0,
        hi=MAX_PHYSICS_HZ,
        unit=" Hz",
    )
    params: Mapping[str, float] = cf.table(
        {},
        "overrides of the PX4 parameter defaults, NAME: value (ranges of PARAMS)",
        item=None,
        choices=tuple(PARAMS),
        nullable=True,
    )
    initial_mode: str = cf.choice(
        "HOLD", tuple(sorted(px4.MODES_BY_NAME)), "PX4 mode at start", fold_case=True
    )
    signing_key_file: str | None = cf.text(
        None,
        "32 raw bytes or 64 hex chars: unsigned messages are ignored; null or empty: unsigned",
        optional=True,
        nonempty=False,
    )
    allow_unsigned: bool = cf.flag(False, "with a signing key: still accept unsigned messages")
    sensor_noise: bool = cf.flag(False, "noisy sensors (seeded)")
    seed: int = cf.count(0, "noise seed")
    rc_present: bool = cf.flag(False, "an RC transmitter is bound (sticks centred)")
    esc_telemetry: bool = cf.flag(True, "ESC_STATUS (false: SIH / PWM ESCs)")
    actuator_output_scale: str = cf.choice(
        "pwm", ACTUATOR_OUTPUT_SCALES, "ACTUATOR_OUTPUT_STATUS values"
    )
    stream_rates: Mapping[str, float] = cf.table(
        {},
        "overrides of PX4's onboard-link stream rates, MESSAGE: Hz in [0, 1000]",
        item=cf.FieldSpec(cf.NUMBER, lo=0.0, hi=1000.0, unit=" Hz"),
        choices=tuple(DEFAULT_RATES),
        nullable=True,
    )
    double_ack: bool = cf.flag(True, "PX4 v1.16: DO_SET_MODE ACCEPTED, then the verdict")
    verdict_delay_s: float = cf.number(
        0.01,
        "commander verdict after the first ACK [s] (0-15 ms measured); at most 1 s",
        lo=0.0,
        hi=1.0,
        unit=" s",
    )
    odometry_lag_s: float = cf.number(
        0.004,
        "ODOMETRY time_usec behind the other stamps [s]; at most 0.1 s",
        lo=0.0,
        hi=0.1,
        unit=" s",
    )
    duplicate_acks: bool = cf.flag(False, "additionally send every COMMAND_ACK twice")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "sim_vehicle") -> "SimVehicleConfig":
        cfg = cls(**cf.parse_fields(cls, d, where))
        cfg.validate(where)
        return cfg

    @classmethod
    def load(cls, path: str) -> "SimVehicleConfig":
        from lpv_sysid.io.files import read_yaml_mapping

        return cls.from_dict(read_yaml_mapping(path, f"sim vehicle config {path}"), path)

    def validate(self, where: str = "sim_vehicle") -> None:
        """The declared fields, then: the URL and bind address, every PX4 parameter in its
        PX4 range, no start in OFFBOARD (PX4 needs a setpoint stream)."""
        cf.check_fields(self, where)
        cf.under(cf.join(where, "url"), parse_url, self.url)
        if self.bind is not None:
            parse_hostport(self.bind, cf.join(where, "bind"))
        for k, v in self.params.items():
            err = PARAMS[k].check(k, v)
            if err is not None:
                raise cf.error(where, f"params.{k}", err)
        if px4.mode_by_name(self.initial_mode) == px4.OFFBOARD:
            raise cf.error(
                where, "initial_mode", "cannot be OFFBOARD (PX4 needs a setpoint stream)"
            )
