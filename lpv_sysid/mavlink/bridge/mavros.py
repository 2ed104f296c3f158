"""MAVROS mode of the bridge with common_interfaces only (``mavros.interfaces: common``).

For vehicles already running MAVROS (ROS 2 ``mavros`` node talking MAVLink to PX4) the
``mavlink_bridge_node`` with ``transport: mavros`` does not open a MAVLink link; it
subscribes and publishes MAVROS's topics instead. With ``interfaces: mavros_msgs`` (or
``auto`` when mavros_msgs can be loaded) the full bridge core runs over MAVROS --
mode, arming, hand-back chain, rate setpoints, rotor speeds: see
:mod:`lpv_sysid.mavlink.bridge.mavros_link`. This module is the fallback without
mavros_msgs: only common_interfaces types are used (docs/DESIGN.md, Conventions), which
fixes what is possible:

======================================  ==============================  ======================
MAVROS topic                            type                            used
======================================  ==============================  ======================
``/mavros/local_position/odom``         nav_msgs/Odometry               in: ENU ``map`` pose,
                                                                        twist in ``base_link``
                                                                        (FLU) -> ``state``
``/mavros/imu/data``                    sensor_msgs/Imu                 in -> ``imu``
``/mavros/setpoint_velocity/cmd_vel``   geometry_msgs/TwistStamped      out: local ENU velocity
                                                                        + yaw rate (ENU z)
``/diagnostics`` (``mavros: Heartbeat``  diagnostic_msgs/DiagnosticArray in (optional, read-only):
key ``Mode``)                                                           the PX4 mode string
``/mavros/state``                       mavros_msgs/State               only mavros_link
``/mavros/set_mode``, ``cmd/arming``    mavros_msgs/srv/*               only mavros_link
``/mavros/esc_status``                  mavros_msgs/ESCStatus           only mavros_link
======================================  ==============================  ======================

Consequences (docs/px4_transport.md, "MAVROS mode"): the core streams the setpoint but
never claims mode control -- switching to OFFBOARD, arming and the hand-back mode switch
are the operator's (RC / GCS / ``ros2 service call /mavros/set_mode ...``). "Hand back"
here means: **stop streaming**. If the vehicle is in OFFBOARD, PX4's offboard-loss
failsafe (``COM_OF_LOSS_T`` -> ``COM_OBL_RC_ACT``) then takes over, exactly as it does
when the MAVLink bridge's hand-back command is lost. No ``rotor_speeds`` are published.

Setpoint frame. MAVROS's ``setpoint_velocity`` plugin (default ``mav_frame`` LOCAL_NED)
reads ``cmd_vel.twist.linear`` as a *local ENU* velocity and ``twist.angular.z`` as the
ENU yaw rate (sent to PX4 negated, as the NED yaw rate ``psi_dot``). The body reference
of the seed, ``v_d`` FRD (seed 0 Eq. 14 scheduling variable), is therefore rotated by the
full attitude of the latest odometry at *every* send, ``v_NED = R_IB v_d`` (seed 0
Eq. 1a) and ``v_ENU = T_NED_ENU v_NED`` (io/frames); the yaw-rate reference ``r_d`` (FRD
body rate) becomes ``psi_dot = (sin(phi) q + cos(phi) r) / cos(theta)`` with ``p = q = 0``
(seed 0 Eq. 2). The alternative -- ``mav_frame: BODY_NED`` / ``cmd_vel_unstamped`` -- is
rotated by PX4 by the yaw only (docs/px4_transport.md, "Velocity frames") and is not used.

The core is pure (no rclpy): ``now`` is always passed in; inputs are the parsed samples
of :mod:`lpv_sysid.io.messages`; outputs are :class:`CmdVel` setpoints and
:class:`~lpv_sysid.mavlink.offboard.StatusEvent` transitions. :func:`cmd_vel_msg` builds
the MAVROS setpoint message through a :class:`~lpv_sysid.io.messages.MsgFactory`.
"""

from __future__ import annotations

import enum
import logging
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.io import frames, messages
from lpv_sysid.mavlink.offboard import StatusEvent

log = logging.getLogger(__name__)

#: MAVROS topic (relative to ``MavrosConfig.namespace``) -> (type, QoS kind); MAVROS
#: publishes odom and imu with SensorDataQoS and subscribes cmd_vel reliable (depth 10).
TOPICS = {
    "odom": ("local_position/odom", "nav_msgs/msg/Odometry", "sensor"),
    "imu": ("imu/data", "sensor_msgs/msg/Imu", "sensor"),
    "cmd_vel": ("setpoint_velocity/cmd_vel", "geometry_msgs/msg/TwistStamped", "reliable"),
}
#: diagnostic_updater's global topic; MAVROS's "<node>: Heartbeat" status carries "Mode".
DIAGNOSTICS_TOPIC = "/diagnostics"
HEARTBEAT_STATUS_SUFFIX = ": Heartbeat"
OFFBOARD_MODE = "OFFBOARD"
#: ``MavrosConfig.interfaces``: which MAVROS types the bridge uses
INTERFACES = ("auto", "mavros_msgs", "common")
MODE_CONTROL = (
    "none: mavros_msgs is not a dependency (switch OFFBOARD / arm / hand back "
    "with RC, GCS or `ros2 service call /mavros/set_mode mavros_msgs/srv/SetMode`)"
)


class MavrosState(enum.Enum):
    IDLE = "IDLE"
    PRESTREAM = "PRESTREAM"  # zero-velocity stream, waiting for the first reference
    STREAMING = "STREAMING"  # forwarding the body reference rotated to local ENU
    DONE = "DONE"  # stream stopped on request (abort / shutdown)
    FAILED = "FAILED"  # stream stopped by a fault (stale input / attitude, pilot)


STREAMING_STATES = (MavrosState.PRESTREAM, MavrosState.STREAMING)


@dataclass(frozen=True)
class MavrosConfig:
    """MAVROS-mode parameters (node parameters ``mavros.*`` plus the shared ones), checked
    by :meth:`validate` (also for a config built in code: :class:`MavrosCore` calls it)."""

    namespace: str = cf.text("/mavros", "MAVROS node namespace, an absolute ROS name")
    odom_frame_id: str = cf.text("map", "frame_id of MAVROS local_position/odom")
    base_frame_id: str = cf.text("base_link", "MAVROS body frame (odom child, imu)")
    setpoint_rate_hz: float = cf.number(
        20.0,
        "setpoint stream rate [Hz]; PX4 needs > 2 Hz (COM_OF_LOSS_T), at most 1000 Hz",
        lo=2.0,
        lo_open=True,
        hi=1000.0,
        unit=" Hz",
    )
    input_timeout: float = cf.number(
        0.5,
        "no velocity_reference for this long -> stop [s]; 0.01 .. 2 s: the last reference is "
        "streamed meanwhile (PX4's own offboard-loss time COM_OF_LOSS_T is 1 s)",
        lo=0.01,
        hi=2.0,
        unit=" s",
    )
    prestream_timeout: float = cf.number(
        30.0,
        "zero-velocity stream without any reference -> stop [s]; > 1 s (PX4's pre-stream), "
        "at most 300 s: the operator switches to OFFBOARD within minutes or not at all",
        lo=1.0,
        lo_open=True,
        hi=300.0,
        unit=" s",
    )
    telemetry_max_age: float = cf.number(
        0.5,
        "odometry older than this cannot rotate the reference [s]; 0.01 .. 1 s: an older "
        "attitude turns the setpoint by whatever the vehicle yawed since",
        lo=0.01,
        hi=1.0,
        unit=" s",
    )
    send_on_command: bool = cf.flag(True, "forward each new reference at once (latency)")
    auto_start: bool = cf.flag(False, "start streaming on the first reference")
    use_diagnostics: bool = cf.flag(True, "observe the PX4 mode on /diagnostics (read-only)")
    command: str = cf.text(
        "velocity", "setpoint kind; with interfaces common MAVROS mode streams velocity only"
    )
    interfaces: str = cf.choice(
        "auto",
        INTERFACES,
        "mavros_msgs: mode, arming, hand-back, rate setpoints and rotor speeds through "
        "mavros_msgs (mavlink/bridge/mavros_link.py); common: common_interfaces only (this "
        "module); auto: mavros_msgs when its types can be loaded",
    )
    rc_out_rate_hz: float = cf.number(
        50.0,
        "interfaces mavros_msgs: SERVO_OUTPUT_RAW rate asked of PX4 through "
        "<ns>/set_message_interval, the rate of /mavros/rc/out and so of the estimated "
        "rotor_speeds (PX4's onboard link: 10 Hz); 0: not asked, at most 400 Hz",
        lo=0.0,
        hi=400.0,
        unit=" Hz",
    )
    preflight: bool = cf.flag(
        True,
        "interfaces mavros_msgs: start is refused unless the preflight checks on MAVROS's "
        "evidence (mavlink/preflight/mavros.py) find no NO-GO",
    )
    state_timeout: float = cf.number(
        3.0,
        "interfaces mavros_msgs: no /mavros/state for this long -> no mode evidence, link "
        "down [s]; 1.5 .. 30 s (MAVROS publishes it with every 1 Hz HEARTBEAT)",
        lo=1.5,
        hi=30.0,
        unit=" s",
    )
    health_max_age: float = cf.number(
        10.0,
        "interfaces mavros_msgs: preflight health evidence (battery, GPS, EKF, RC, motor "
        "outputs, home, telemetry streams) older than this counts as missing at start [s]; "
        "3 .. 120 s (PX4 sends HOME_POSITION at 0.5 Hz, the others faster)",
        lo=3.0,
        hi=120.0,
        unit=" s",
    )

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "mavros") -> "MavrosConfig":
        cfg = cls(**cf.parse_fields(cls, d, where))
        cfg.validate(where)
        return cfg

    def validate(self, where: str = "mavros") -> None:
        """The declared fields, then: the namespace is an absolute name, the command is
        velocity (the only setpoint of common_interfaces)."""
        cf.check_fields(self, where)
        ns = self.namespace
        if not ns.startswith("/") or ns.endswith("/") or "//" in ns:
            raise cf.error(
                where, "namespace", f"must be an absolute name like '/mavros', got {ns!r}"
            )
        if self.command != "velocity" and self.interfaces == "common":
            raise cf.error(
                where,
                "command",
                f"{self.command!r} is not available with transport mavros: MAVROS's "
                "attitude/actuator setpoints need mavros_msgs; use command velocity, "
                "interfaces mavros_msgs or transport mavlink",
            )

    def topic(self, key: str) -> str:
        """Absolute MAVROS topic name of ``odom`` / ``imu`` / ``cmd_vel``."""
        return f"{self.namespace}/{TOPICS[key][0]}"


@dataclass(frozen=True)
class CmdVel:
    """A MAVROS velocity setpoint: local ENU velocity [m/s] and ENU yaw rate [rad/s]
    (``= -psi_dot`` of NED), with the body reference it came from."""

    t: float
    v_enu: np.ndarray
    yaw_rate_enu: float
    v_frd: np.ndarray
    r_frd: float


@dataclass
class MavrosOutput:
    setpoints: list[CmdVel] = field(default_factory=list)
    events: list[StatusEvent] = field(default_factory=list)


def body_reference_to_local_enu(v_frd, r_frd: float, euler) -> tuple[np.ndarray, float]:
    """``(v_ENU, yaw_rate_ENU)`` of the body reference ``v_d`` FRD and ``r_d`` at attitude
    ``euler = [phi, theta, psi]`` (NED/FRD): ``v_ENU = T_NED_ENU R_IB v_d`` (seed 0 Eq. 1a)
    and ``yaw_rate_ENU = -psi_dot``, ``psi_dot`` from seed 0 Eq. (2) with ``p = q = 0``."""
    v_ned = frames.body_to_world(v_frd, euler)
    psi_dot = frames.euler_rates(euler, [0.0, 0.0, float(r_frd)])[2]
    return frames.ned_to_enu(v_ned), float(-psi_dot)


def cmd_vel_msg(f: messages.MsgFactory, stamp_ns: int, sp: CmdVel, frame_id: str = "map"):
    """``geometry_msgs/TwistStamped`` for ``/mavros/setpoint_velocity/cmd_vel``: linear =
    local ENU velocity, angular = (0, 0, ENU yaw rate); ``frame_id`` names the local ENU
    frame (MAVROS reads only the stamp)."""
    return messages.enu_velocity_setpoint_msg(f, stamp_ns, sp.v_enu, sp.yaw_rate_enu, frame_id)


def vehicle_mode_from_statuses(statuses: Sequence[Any]) -> str | None:
    """PX4 mode string (``OFFBOARD``, ``AUTO.LOITER``, ...) of MAVROS's ``<node>: Heartbeat``
    diagnostic status (:class:`lpv_sysid.io.messages.StatusSample` list), else None."""
    for s in statuses:
        if str(s.name).endswith(HEARTBEAT_STATUS_SUFFIX) and "Mode" in s.values:
            return str(s.values["Mode"]).strip()
    return None


class MavrosCore:
    """Streams ``/mavros/setpoint_velocity/cmd_vel`` from body velocity references with
    the stale-input / abort safety of the MAVLink bridge (module docstring).

    Same shell-facing surface as :class:`lpv_sysid.mavlink.bridge.BridgeCore`:
    ``start``/``abort``/``shutdown`` return status events, ``status(now)`` key/values,
    ``state``; plus ``on_odometry``, ``on_imu``, ``on_diagnostics``,
    ``on_velocity_reference`` and the periodic ``step(now)``.
    """

    def __init__(self, config: MavrosConfig) -> None:
        config.validate()
        self.config = config
        self.state = MavrosState.IDLE
        self.reason = ""
        self.vehicle_mode: str | None = None
        self.setpoints_sent = 0
        self.rejected_inputs = 0
        self.out_of_order = 0
        self._t_state = 0.0
        self._t_start = -math.inf
        self._next_sp = 0.0
        self._cmd: tuple[np.ndarray, float] | None = None
        self._t_cmd = -math.inf
        self._last_ref_stamp = -math.inf
        self._att: np.ndarray | None = None  # latest Euler [phi, theta, psi] NED/FRD
        self._t_att = -math.inf  # its receive time
        self._last_odom_stamp = -1
        self._last_imu_stamp = -1
        self._t_imu = -math.inf
        self._saw_offboard = False
        self._pending: list[StatusEvent] = []

    # -------------------------------------------------------------- telemetry in
    def on_odometry(self, now: float, s: messages.StateSample) -> messages.StateSample | None:
        """A parsed ``/mavros/local_position/odom`` sample; returns it for the ``state``
        topic, or None when its stamp is not newer than the previous one (dropped)."""
        if s.stamp_ns <= self._last_odom_stamp:
            self.out_of_order += 1
            return None
        self._last_odom_stamp = s.stamp_ns
        self._att, self._t_att = np.asarray(s.euler, dtype=float), now
        return s

    def on_imu(self, now: float, s: messages.ImuSample) -> messages.ImuSample | None:
        """A parsed ``/mavros/imu/data`` sample; returned for the ``imu`` topic unless out of
        order."""
        if s.stamp_ns <= self._last_imu_stamp:
            self.out_of_order += 1
            return None
        self._last_imu_stamp, self._t_imu = s.stamp_ns, now
        return s

    def on_diagnostics(self, now: float, statuses: Sequence[Any]) -> None:
        """MAVROS ``/diagnostics`` statuses: remember the PX4 mode (read-only)."""
        if not self.config.use_diagnostics:
            return
        mode = vehicle_mode_from_statuses(statuses)
        if mode is None:
            return
        self.vehicle_mode = mode
        if self.state in STREAMING_STATES:
            if mode == OFFBOARD_MODE:
                self._saw_offboard = True
            elif self._saw_offboard:
                self._pending += self._stop(
                    now,
                    MavrosState.FAILED,
                    f"vehicle left OFFBOARD (now {mode}); setpoint stream "
                    "stopped, control stays with PX4/pilot",
                    "warn",
                )

    def reject(self, now: float, reason: str) -> None:
        """An input the shell could not parse (named by ``reason``); counted and reported."""
        self.rejected_inputs += 1
        log.warning(reason)
        self._pending.append(StatusEvent(now, self.state.value, self.state.value, reason, "error"))

    # ---------------------------------------------------------------- command in
    def on_velocity_reference(
        self, now: float, v_frd: Any, yaw_rate: float = 0.0, stamp: float | None = None
    ) -> MavrosOutput:
        """Body velocity reference ``v_d`` FRD [m/s] and yaw-rate reference ``r_d`` [rad/s]."""
        out = MavrosOutput()
        try:
            v = np.asarray(v_frd, dtype=float)
            r = float(yaw_rate)
        except (TypeError, ValueError):
            self.reject(now, f"velocity reference rejected: not numeric ({v_frd!r}, {yaw_rate!r})")
            return self._flush(out)
        if v.shape != (3,) or not np.isfinite(v).all() or not math.isfinite(r):
            self.reject(
                now,
                f"velocity reference rejected: needs 3 finite values and a finite yaw "
                f"rate, got {v.tolist()!r}, {yaw_rate!r}",
            )
            return self._flush(out)
        if stamp is not None:
            if stamp < self._last_ref_stamp:
                self.reject(
                    now,
                    f"out-of-order velocity reference (stamp {stamp:.6f} < "
                    f"{self._last_ref_stamp:.6f})",
                )
                return self._flush(out)
            self._last_ref_stamp = stamp
        self._cmd, self._t_cmd = (v, r), now
        if self.config.auto_start and self.state == MavrosState.IDLE:
            out.events += self.start(now)
        elif self.state == MavrosState.PRESTREAM:
            out.events += self._go(now, MavrosState.STREAMING, "first velocity reference received")
        if self.state == MavrosState.STREAMING and self.config.send_on_command:
            self._emit(now, out)
        return self._flush(out)

    # ----------------------------------------------------------------- lifecycle
    def start(self, now: float) -> list[StatusEvent]:
        """Begin streaming (service ``start``); returns the events it caused."""
        if self.state in STREAMING_STATES:
            return []
        self._t_start, self._next_sp, self._saw_offboard = now, now, False
        fresh = self._cmd is not None and now - self._t_cmd <= self.config.input_timeout
        if fresh:
            return self._go(
                now,
                MavrosState.STREAMING,
                "start requested (reference is live); "
                "switch to OFFBOARD from RC/GCS: this node has no mode control",
            )
        return self._go(
            now,
            MavrosState.PRESTREAM,
            "start requested: streaming zero velocity "
            "until the first reference; OFFBOARD/arming are the operator's",
        )

    def abort(self, now: float, reason: str = "abort requested") -> list[StatusEvent]:
        if self.state in STREAMING_STATES:
            return self._stop(now, MavrosState.DONE, self._stopped_text(reason), "info")
        if self.state == MavrosState.IDLE:
            return self._go(now, MavrosState.DONE, reason)
        return []

    def shutdown(self, now: float) -> list[StatusEvent]:
        events = self.abort(now, "shutdown")
        events, self._pending = self._pending + events, []
        return events

    def close(self) -> None:
        """Nothing to release (MAVROS owns the link); symmetric with BridgeCore."""

    # ---------------------------------------------------------------------- step
    def step(self, now: float) -> MavrosOutput:
        """Periodic work: safety checks first, then one setpoint when one is due."""
        out = MavrosOutput()
        cfg = self.config
        st = self.state
        if st == MavrosState.PRESTREAM and now - self._t_start > cfg.prestream_timeout:
            out.events += self._stop(
                now,
                MavrosState.FAILED,
                f"no velocity_reference within prestream_timeout "
                f"{cfg.prestream_timeout} s; stream stopped",
                "warn",
            )
        elif st == MavrosState.STREAMING and now - self._t_cmd > cfg.input_timeout:
            out.events += self._stop(
                now,
                MavrosState.FAILED,
                self._stopped_text(
                    f"stale input: no velocity_reference for {now - self._t_cmd:.3f} s "
                    f"(> {cfg.input_timeout} s)"
                ),
                "warn",
            )
        elif st == MavrosState.STREAMING and now - self._t_att > cfg.telemetry_max_age:
            age = now - self._t_att
            out.events += self._stop(
                now,
                MavrosState.FAILED,
                self._stopped_text(
                    f"no fresh {cfg.topic('odom')} for {age:.3f} s (> {cfg.telemetry_max_age} s): "
                    "the body reference cannot be rotated to local ENU"
                ),
                "error",
            )
        elif st in STREAMING_STATES and now >= self._next_sp:
            self._emit(now, out)
        return self._flush(out)

    # -------------------------------------------------------------------- status
    def status(self, now: float) -> dict[str, str]:
        def age(t: float) -> str:
            return f"{now - t:.3f}" if math.isfinite(t) else "inf"

        return {
            "transport": "mavros",
            "state": self.state.value,
            "state_age_s": f"{now - self._t_state:.3f}",
            "reason": self.reason,
            "mode_control": MODE_CONTROL,
            "vehicle_mode": self.vehicle_mode or "unknown",
            "vehicle_mode_source": "/diagnostics (read-only)"
            if self.config.use_diagnostics
            else "none",
            "armed": "unknown (mavros_msgs/State not used)",
            "streaming": str(self.state in STREAMING_STATES),
            "setpoint_topic": self.config.topic("cmd_vel"),
            "setpoints_sent": str(self.setpoints_sent),
            "input_age_s": age(self._t_cmd),
            "age_odom_s": age(self._t_att),
            "age_imu_s": age(self._t_imu),
            "rejected_inputs": str(self.rejected_inputs),
            "out_of_order": str(self.out_of_order),
        }

    # ----------------------------------------------------------------- internals
    def _emit(self, now: float, out: MavrosOutput) -> None:
        if self.state == MavrosState.PRESTREAM or self._cmd is None:
            v, r = np.zeros(3), 0.0
            v_enu, yr = np.zeros(3), 0.0  # zero is zero in every frame
        else:
            v, r = self._cmd
            if self._att is None or now - self._t_att > self.config.telemetry_max_age:
                return  # step() stops the stream on its next call
            v_enu, yr = body_reference_to_local_enu(v, r, self._att)
        out.setpoints.append(CmdVel(now, v_enu, yr, v.copy(), r))
        self.setpoints_sent += 1
        period = 1.0 / self.config.setpoint_rate_hz
        self._next_sp = (
            self._next_sp + period if 0.0 <= now - self._next_sp < period else now + period
        )

    def _stopped_text(self, reason: str) -> str:
        return (
            f"{reason}; setpoint stream stopped (no mode command: mavros_msgs not used) - "
            "if the vehicle is in OFFBOARD, PX4's offboard-loss failsafe COM_OBL_RC_ACT "
            "takes over after COM_OF_LOSS_T"
        )

    def _go(
        self, now: float, new: MavrosState, reason: str, level: str = "info"
    ) -> list[StatusEvent]:
        prev, self.state, self.reason, self._t_state = self.state, new, reason, now
        return [StatusEvent(now, prev.value, new.value, reason, level)]

    def _stop(self, now: float, new: MavrosState, reason: str, level: str) -> list[StatusEvent]:
        self._cmd, self._t_cmd = None, -math.inf  # a restart needs a new reference
        return self._go(now, new, reason, level)

    def _flush(self, out: MavrosOutput) -> MavrosOutput:
        out.events[:0] = self._pending
        self._pending = []
        return out
