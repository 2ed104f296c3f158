"""The preflight checks on MAVROS's evidence (transport mavros with mavros_msgs).

The bridge cannot open its own MAVLink link next to MAVROS, so the facts of
:func:`~lpv_sysid.mavlink.preflight.judge` come from MAVROS (the rules are unchanged,
:mod:`lpv_sysid.mavlink.preflight`):

===========================  ==========================================================
preflight fact               MAVROS source
===========================  ==========================================================
HEARTBEAT                    ``/mavros/state`` (mode, armed) + ``vehicle_info_get``
                             (autopilot, MAV_TYPE, system id)
AUTOPILOT_VERSION            ``vehicle_info_get`` (``flight_sw_version``,
                             ``capabilities``; MAVROS requests it on connection, a
                             few times only: while ``flight_sw_version`` is 0 the
                             bridge asks PX4 for it through ``cmd/command``,
                             MAV_CMD_REQUEST_MESSAGE)
PARAM_VALUE                  the FCU parameters MAVROS's param plugin mirrors as ROS
                             parameters of ``<ns>/param`` (``get_parameters``)
RC_CHANNELS                  ``/mavros/rc/in`` (channel count, RSSI)
telemetry streams            ``local_position/odom`` (ODOMETRY), ``imu/data``
                             (HIGHRES_IMU), ``esc_status/status`` (ESC_STATUS), ``rc/out``
                             (SERVO_OUTPUT_RAW, port 0)
battery (SYS_STATUS          ``battery`` (sensor_msgs/BatteryState): ``percentage`` x 100
battery fields)              -> ``battery_remaining``, unknown when NaN or negative
                             (MAVROS sends PX4's -1 as -0.01); ``voltage`` -> mV
GPS_RAW_INT                  ``gpsstatus/gps1/raw`` (mavros_msgs/GPSRAW: ``fix_type``,
                             ``satellites_visible``); without it
                             ``global_position/raw/fix`` (NavSatFix: STATUS_FIX, sent by
                             MAVROS for ``fix_type`` > 2, -> fix type 3; else 1;
                             satellites unknown)
ESTIMATOR_STATUS             ``estimator_status`` (mavros_msgs/EstimatorStatus): the
                             ``*_status_flag`` booleans -> ``flags`` bits
                             (:data:`~lpv_sysid.io.messages.mavros.ESTIMATOR_FLAG_FIELDS`)
HOME_POSITION                ``home_position/home`` (mavros_msgs/HomePosition ``geo``:
                             degrees -> degE7, metres -> mm)
===========================  ==========================================================

These facts are judged by :mod:`~lpv_sysid.mavlink.preflight.health` with the rules and
verdicts of the MAVLink transport (without a plan: the battery reserve alone).

Health evidence expires: each fact carries the time it arrived (:meth:`MavrosEvidence.put`),
and the preflight judges :meth:`MavrosEvidence.fresh` -- a battery, GPS, EKF, RC, motor
output, home or stream fact older than ``max_age`` counts as missing (the verdict of a fact
never received), so a topic MAVROS stopped publishing while it stays connected (a sensor or
plugin gone silent, PX4 no longer sending the message) cannot keep a GO. The mode and
armed state come from ``/mavros/state`` only while it is fresh (the link's
``state_timeout``).

SYS_STATUS (PX4's own stick verdict) is not used: stick input is decided from
COM_RC_IN_MODE and RC_CHANNELS as on a link without SYS_STATUS. A fact MAVROS has not
delivered yet is missing, with the verdict the MAVLink preflight gives it (NO-GO for the
HEARTBEAT, the firmware and COM_OF_LOSS_T / COM_OBL_RC_ACT) and its check marked
``missing``. A VehicleInfo answered before MAVROS had PX4's AUTOPILOT_VERSION carries the
HEARTBEAT fields and ``flight_sw_version`` 0: the firmware stays missing
(:meth:`MavrosEvidence.firmware_known`) until a later answer has it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.preflight.checks import judge
from lpv_sysid.mavlink.preflight.gather import INFO_PARAMS, REQUIRED_PARAMS, Facts
from lpv_sysid.mavlink.preflight.report import NOGO, Check
from lpv_sysid.mavlink.telemetry import RotorEstimateConfig

#: the PX4 parameters the checks read (asked from MAVROS's param node)
PARAMS = REQUIRED_PARAMS + INFO_PARAMS


@dataclass
class MavrosEvidence:
    """What MAVROS delivered so far (filled by the bridge runtime)."""

    mode: px4.Px4Mode | None = None  # latest /mavros/state while connected
    armed: bool = False
    vehicle: Any = None  # mavros_msgs/VehicleInfo of the target (duck-typed)
    params: dict[str, float | int] = field(default_factory=dict)
    seen: set[str] = field(default_factory=set)  # MAVLink names of the streams seen
    rc_in: tuple[int, int] | None = None  # (channel count, RSSI) of /mavros/rc/in
    servo_raw: list[int] | None = None  # newest /mavros/rc/out channels
    battery: tuple[float | None, float] | None = None  # (remaining % or None, V) of battery
    gps_raw: tuple[int, int] | None = None  # (fix_type, satellites) of gpsstatus/gps1/raw
    gps_fix: tuple[int, int] | None = None  # the same implied by global_position/raw/fix
    estimator_flags: int | None = None  # ESTIMATOR_STATUS flags of estimator_status
    home: tuple[float, float, float] | None = None  # (lat deg, lon deg, alt m) of home
    #: receive time [s] of each health fact (field name, or ``seen:<stream>``)
    stamps: dict[str, float] = field(default_factory=dict)

    #: the facts that expire (:meth:`fresh`); the mode / armed state is the link's
    EXPIRING = ("rc_in", "servo_raw", "battery", "gps_raw", "gps_fix", "estimator_flags", "home")

    def missing_params(self) -> list[str]:
        return [p for p in PARAMS if p not in self.params]

    def firmware_known(self) -> bool:
        """MAVROS's VehicleInfo holds PX4's AUTOPILOT_VERSION
        (:func:`~lpv_sysid.io.messages.autopilot_version_known`)."""
        from lpv_sysid.io.messages import autopilot_version_known

        return self.vehicle is not None and autopilot_version_known(self.vehicle)

    def put(self, name: str, value: Any, now: float) -> None:
        """Fact ``name`` (a field of :data:`EXPIRING`) received at ``now``."""
        if name not in self.EXPIRING:
            raise ValueError(f"{name!r} is not an expiring MAVROS fact")
        setattr(self, name, value)
        self.stamps[name] = now

    def saw(self, stream: str, now: float) -> None:
        """A message of MAVLink stream ``stream`` (``ODOMETRY``, ...) arrived at ``now``."""
        self.seen.add(stream)
        self.stamps["seen:" + stream] = now

    def fresh(self, now: float, max_age: float) -> "MavrosEvidence":
        """A copy without the facts (and streams) older than ``max_age`` s at ``now``; a
        fact set without a stamp (built in code) is kept."""

        def old(key: str) -> bool:
            return key in self.stamps and now - self.stamps[key] > max_age

        out = dataclasses.replace(
            self,
            params=dict(self.params),
            seen={s for s in self.seen if not old("seen:" + s)},
            stamps=dict(self.stamps),
        )
        for k in self.EXPIRING:
            if old(k):
                setattr(out, k, None)
        return out

    def stale(self, now: float, max_age: float) -> list[str]:
        """The facts and streams older than ``max_age`` s at ``now`` (with their ages)."""
        return [
            f"{k.removeprefix('seen:')} {now - t:.1f} s old"
            for k, t in sorted(self.stamps.items())
            if now - t > max_age
        ]


class _Heartbeat:
    """The HEARTBEAT fields judge() reads, from /mavros/state and VehicleInfo."""

    def __init__(self, vehicle: Any, mode: px4.Px4Mode, armed: bool) -> None:
        self.autopilot = int(vehicle.autopilot)
        self.type = int(vehicle.type)
        self.custom_mode = mode.custom_mode
        self.base_mode = px4.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
            px4.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
        )
        self._sysid = int(vehicle.sysid)

    def get_srcSystem(self) -> int:  # noqa: N802 (pymavlink's name)
        return self._sysid


@dataclass(frozen=True)
class _Version:
    flight_sw_version: int
    capabilities: int


@dataclass(frozen=True)
class _RcChannels:
    chancount: int
    rssi: int


class _ServoOutputRaw:
    def __init__(self, channels: list[int]) -> None:
        self.port = 0
        for k in range(16):
            setattr(self, f"servo{k + 1}_raw", int(channels[k]) if k < len(channels) else 0)


@dataclass(frozen=True)
class _Battery:
    battery_remaining: int  # %, -1 unknown (SYS_STATUS)
    voltage_battery: float  # mV


@dataclass(frozen=True)
class _Gps:
    fix_type: int
    satellites_visible: int


@dataclass(frozen=True)
class _Estimator:
    flags: int


@dataclass(frozen=True)
class _Home:
    latitude: int  # degE7
    longitude: int  # degE7
    altitude: int  # mm


def facts_from_mavros(ev: MavrosEvidence) -> Facts:
    """The preflight :class:`~lpv_sysid.mavlink.preflight.Facts` of MAVROS's evidence."""
    v = ev.vehicle
    hb = _Heartbeat(v, ev.mode, ev.armed) if v is not None and ev.mode is not None else None
    version = None
    if ev.firmware_known():
        version = _Version(int(v.flight_sw_version), int(v.capabilities))
    facts = Facts(hb=hb, version=version, params=dict(ev.params), seen=set(ev.seen))
    if ev.rc_in is not None:
        facts.rc_channels = _RcChannels(*ev.rc_in)
    if ev.servo_raw is not None:
        facts.motor_outputs["SERVO_OUTPUT_RAW"] = _ServoOutputRaw(ev.servo_raw)
        facts.seen.add("SERVO_OUTPUT_RAW")
    if ev.battery is not None:
        pct, volts = ev.battery
        # PX4's battery_remaining is an integer %; MAVROS divided it by 100 in float32
        remaining = -1 if pct is None else int(round(pct))
        facts.battery = _Battery(remaining, 1000.0 * volts)
    gps = ev.gps_raw if ev.gps_raw is not None else ev.gps_fix
    if gps is not None:
        facts.gps = _Gps(*gps)
    if ev.estimator_flags is not None:
        facts.estimator = _Estimator(ev.estimator_flags)
    if ev.home is not None:
        lat, lon, alt = ev.home
        facts.home = _Home(round(lat * 1e7), round(lon * 1e7), round(alt * 1e3))
    return facts


def mavros_checks(
    ev: MavrosEvidence, rotor_estimate: RotorEstimateConfig | None = None, namespace: str = ""
) -> list[Check]:
    """The preflight checks of the MAVLink transport on MAVROS's evidence."""
    f = facts_from_mavros(ev)
    out: list[Check] = []
    if ev.vehicle is None:
        out.append(
            Check(
                "vehicle info",
                f"no answer from {namespace}/vehicle_info_get",
                "autopilot, type, firmware",
                NOGO,
                missing=True,
            )
        )
    return out + judge(
        f.hb, f.version, f.params, f.seen, None, facts=f, rotor_estimate=rotor_estimate
    )
