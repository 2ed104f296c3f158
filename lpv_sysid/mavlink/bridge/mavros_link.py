"""MAVROS with mavros_msgs as the link of :class:`~lpv_sysid.mavlink.bridge.BridgeCore`.

With ``mavros.interfaces: mavros_msgs`` the bridge runs the *same* core as over its own
MAVLink link -- offboard machine (:mod:`lpv_sysid.mavlink.offboard`: pre-stream, OFFBOARD
switch, arming, hand-back chain and their truth rules), envelope, telemetry decoder and
rotor-speed estimate, setpoint transports -- and :class:`MavrosLink` stands in for
:class:`~lpv_sysid.mavlink.link.MavlinkLink`: it turns MAVROS's messages into the
MAVLink-shaped evidence the core already judges, and the core's sends into MAVROS
messages and service calls. Nothing is decided here.

=================================  ==========================  ===========================
MAVROS (namespace ``/mavros``)     mavros_msgs / std type      becomes (core input/output)
=================================  ==========================  ===========================
``state``                          State                       HEARTBEAT (mode, armed) --
                                                               only while ``connected``;
                                                               none for ``state_timeout``
                                                               s: link down (no evidence);
                                                               armed with ``system_status``
                                                               CRITICAL / EMERGENCY /
                                                               FLIGHT_TERMINATION (a PX4
                                                               failsafe): mode unknown
``set_mode`` (service)             SetMode                     <- DO_SET_MODE (custom_mode
                                                               = MAVROS mode name);
                                                               ``mode_sent`` -> COMMAND_ACK
                                                               ACCEPTED / DENIED
``cmd/arming`` (service)           CommandBool                 <- ARM_DISARM; ``success`` /
                                                               ``result`` -> COMMAND_ACK
``local_position/odom``            nav_msgs/Odometry           ODOMETRY (NED, FRD)
``imu/data``                       sensor_msgs/Imu             HIGHRES_IMU
``esc_status/status``              ESCStatus                   ESC_STATUS (rpm; extras)
``rc/out``                         RCOut                       SERVO_OUTPUT_RAW (PWM): the
                                                               rotor estimate (seed 0
                                                               Eq. 8) without ESC rpm
``home_position/home``             HomePosition                HOME_POSITION (envelope;
                                                               the preflight's home is
                                                               kept by the runtime)
``setpoint_raw/local``             PositionTarget              <- SET_POSITION_TARGET_LOCAL_
                                                               NED (velocity, phase 1)
``setpoint_raw/attitude``          AttitudeTarget              <- SET_ATTITUDE_TARGET (body
                                                               rates + thrust, phase 2)
``setpoint_raw/target_attitude``   AttitudeTarget              ATTITUDE_TARGET (PX4's echo,
                                                               ``rate_setpoint`` topic)
=================================  ==========================  ===========================

The truth rule is unchanged: a step counts only when, after the service's final answer
and ``ack_settle_s`` of quiet, a ``/mavros/state`` received after the request shows the
requested mode (or arming state). MAVROS answers ``set_mode`` with ``mode_sent = true``
as soon as it *sent* SET_MODE (mavros sys_status plugin), so for a mode the state is the
only evidence; a rejected mode is never shown and runs into ``mode_confirm_timeout`` (the
next mode of the hand-back chain, then FAILED). ``/mavros/state`` with
``connected = false`` (MAVROS lost the autopilot's HEARTBEAT) is no evidence; neither is
silence: after ``state_timeout`` s without a State the link counts as down, which hands
control back while streaming (the machine's link-loss rule) and lets nothing be confirmed.

A mode a PX4 failsafe entered looks on ``/mavros/state`` like a requested one (MAVROS's
``set_mode`` never reports PX4's verdict), except for ``system_status``: PX4 sends
MAV_STATE_CRITICAL in its HEARTBEAT while armed with a failsafe active (``vehicle_status.
failsafe``; EMERGENCY and FLIGHT_TERMINATION are worse). Such a state is passed on with
the mode *unknown* (:data:`UNKNOWN_MODE`) and reported once (event ``px4_failsafe``,
status ``px4_failsafe``): it confirms no step, so the bridge concludes what it can prove --
in OFFBOARD_ACTIVE "vehicle left OFFBOARD" (FAILED, the failsafe keeps control, no mode is
commanded), in the hand-back the requested mode is not confirmed by the failsafe's Hold or
Land (the chain moves on; DONE only once PX4 shows a chain mode outside the failsafe, else
FAILED "hand-back NOT confirmed ... PX4 failsafe in charge").

Outgoing requests are :class:`ServiceRequest` (``key`` ``set_mode`` / ``arming`` and the
request fields); setpoints are :class:`VelocityTarget` / :class:`RateTarget` (MAVLink
meaning: NED/FRD) that :mod:`lpv_sysid.io.messages` turns into MAVROS's ENU/FLU messages.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from lpv_sysid.io import frames, messages
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.link import LinkEvent

#: MAVROS's PX4 mode names (mavros ``px4_custom_mode``, wiki "CustomModes")
MAVROS_MODE_NAMES = {
    px4.MANUAL: "MANUAL",
    px4.ALTCTL: "ALTCTL",
    px4.POSCTL: "POSCTL",
    px4.OFFBOARD: "OFFBOARD",
    px4.STABILIZED: "STABILIZED",
    px4.ACRO: "ACRO",
    px4.HOLD: "AUTO.LOITER",
    px4.LAND: "AUTO.LAND",
    px4.RTL: "AUTO.RTL",
    px4.TAKEOFF: "AUTO.TAKEOFF",
    px4.MISSION: "AUTO.MISSION",
    px4.AUTO_READY: "AUTO.READY",
}
MODES_BY_MAVROS_NAME = {v: k for k, v in MAVROS_MODE_NAMES.items()}
#: a mode MAVROS names but this package does not (shown as UNKNOWN, never confirms a step)
UNKNOWN_MODE = px4.Px4Mode(0, 0)

MAV_AUTOPILOT_PX4 = 12
MAV_RESULT_FAILED = px4.MAV_RESULT_FAILED
MAV_RESULT_DENIED = px4.MAV_RESULT_DENIED
MAV_FRAME_BODY_FRD = 12  # ODOMETRY.child_frame_id: velocity in the body frame
#: HEARTBEAT.system_status (MAV_STATE) values PX4 sends while a failsafe is active
FAILSAFE_SYSTEM_STATUS = {
    5: "MAV_STATE_CRITICAL",
    6: "MAV_STATE_EMERGENCY",
    8: "MAV_STATE_FLIGHT_TERMINATION",
}


def mode_from_mavros(name: str) -> px4.Px4Mode:
    """The PX4 mode of a MAVROS mode string (``AUTO.LOITER`` -> HOLD); unknown names give
    :data:`UNKNOWN_MODE`."""
    return MODES_BY_MAVROS_NAME.get(str(name).strip().upper(), UNKNOWN_MODE)


def mavros_mode_name(mode: px4.Px4Mode) -> str:
    """MAVROS's ``custom_mode`` string of a PX4 mode (SetMode request)."""
    try:
        return MAVROS_MODE_NAMES[mode]
    except KeyError:
        raise ValueError(f"PX4 mode {mode.name} has no MAVROS name") from None


class _Msg:
    """A MAVLink-shaped message made from a MAVROS one: ``get_type()`` and the fields the
    core reads; its source is the autopilot MAVROS talks to (``tgt_system``)."""

    def __init__(self, mtype: str, **fields: Any) -> None:
        self._type = mtype
        self.__dict__.update(fields)

    def get_type(self) -> str:
        return self._type

    def get_srcSystem(self) -> int:  # noqa: N802 (pymavlink's name)
        return MavrosLink.TARGET[0]

    def get_srcComponent(self) -> int:  # noqa: N802 (pymavlink's name)
        return MavrosLink.TARGET[1]


@dataclass(frozen=True)
class ServiceRequest:
    """A MAVROS service call the shell makes: ``key`` ``set_mode`` | ``arming``,
    ``fields`` of the request, ``command`` the MAVLink command it stands for."""

    key: str
    fields: dict
    command: int


@dataclass(frozen=True)
class VelocityTarget:
    """SET_POSITION_TARGET_LOCAL_NED as the velocity transport encodes it."""

    frame: int
    type_mask: int
    v: np.ndarray  # FRD (BODY_NED) or NED (LOCAL_NED)
    yaw_rate: float  # NED/FRD


@dataclass(frozen=True)
class RateTarget:
    """SET_ATTITUDE_TARGET as the rate transports encode it."""

    type_mask: int
    rates_frd: np.ndarray
    thrust: float

    def get_type(self) -> str:
        """The MAVLink message this setpoint stands for (MAVROS sends it as one)."""
        return "SET_ATTITUDE_TARGET"


class CaptureCodec:
    """The two encoders the setpoint transports call, returning MAVROS-bound setpoints
    instead of MAVLink messages (same arguments as pymavlink's)."""

    def set_position_target_local_ned_encode(
        self, time_boot_ms, target_system, target_component, frame, type_mask, *a
    ) -> VelocityTarget:
        # a = x, y, z, vx, vy, vz, afx, afy, afz, yaw, yaw_rate
        return VelocityTarget(
            int(frame), int(type_mask), np.array(a[3:6], dtype=float), float(a[10])
        )

    def set_attitude_target_encode(
        self, time_boot_ms, target_system, target_component, type_mask, q, p, q_rate, r, thrust
    ) -> RateTarget:
        return RateTarget(int(type_mask), np.array([p, q_rate, r], dtype=float), float(thrust))


@dataclass
class MavrosLinkStats:
    states: int = 0
    disconnected_states: int = 0
    unknown_modes: int = 0
    failsafe_states: int = 0
    service_calls: int = 0
    service_answers: int = 0
    setpoints: int = 0
    rejected_inputs: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass
class _Clock:
    t_state: float = -math.inf
    connected: bool = False
    failsafe: str = ""  # "<mode> (<MAV_STATE>)" while PX4 reports a failsafe, else ""
    events: list[LinkEvent] = field(default_factory=list)


class MavrosLink:
    """The link interface :class:`~lpv_sysid.mavlink.bridge.BridgeCore` uses, over MAVROS
    (module docstring). ``state_timeout`` [s]: no ``/mavros/state`` for longer -> down."""

    #: (system, component) of the synthetic messages (MAVROS's target autopilot)
    TARGET = (1, 1)
    #: the telemetry's times are MAVROS's header stamps, ROS time -- the bridge's clock
    #: already (BridgeCore keeps them: telemetry.ReceiverClock)
    RECEIVER_CLOCK = True

    def __init__(self, state_timeout: float = 3.0, namespace: str = "/mavros") -> None:
        self.state_timeout = float(state_timeout)
        self.namespace = namespace
        self.codec = CaptureCodec()
        self.target_system, self.target_component = self.TARGET
        self.ambiguous_target = False
        self.stats = MavrosLinkStats()
        self.last_mode = ""
        self._clock = _Clock()
        self._inbox: list[_Msg] = []
        self._outbox: list[Any] = []

    # ------------------------------------------------------ MavlinkLink interface
    def open(self, now: float) -> None:
        """Nothing to open: MAVROS owns the link."""

    def close(self) -> None:
        """Nothing to release."""

    def poll(self, now: float) -> list[Any]:
        out, self._inbox = self._inbox, []
        return out

    def step(self, now: float) -> None:
        c = self._clock
        if c.connected and now - c.t_state > self.state_timeout:
            c.connected = False
            c.events.append(
                LinkEvent(
                    now,
                    "link_lost",
                    f"no {self.namespace}/state for {now - c.t_state:.2f} s "
                    f"(> state_timeout {self.state_timeout:g} s): no mode evidence",
                )
            )

    def events(self) -> list[LinkEvent]:
        out, self._clock.events = self._clock.events, []
        return out

    def link_up(self, now: float) -> bool:
        c = self._clock
        return c.connected and now - c.t_state <= self.state_timeout

    def from_autopilot(self, msg: Any) -> bool:
        return True  # every message here is MAVROS's view of its target autopilot

    def send(self, m: Any) -> None:
        self.stats.setpoints += 1
        self._outbox.append(m)

    def command_long(self, command: int, *params: float, confirmation: int = 0) -> None:
        if command == px4.MAV_CMD_DO_SET_MODE:
            mode = px4.Px4Mode(int(params[1]), int(params[2]))
            req = ServiceRequest(
                "set_mode", {"base_mode": 0, "custom_mode": mavros_mode_name(mode)}, command
            )
        elif command == px4.MAV_CMD_COMPONENT_ARM_DISARM:
            req = ServiceRequest("arming", {"value": bool(params[0] == 1.0)}, command)
        else:
            raise ValueError(f"command {command} has no MAVROS service here")
        self.stats.service_calls += 1
        self._outbox.append(req)

    def take_outbox(self) -> list[Any]:
        """Setpoints (:class:`VelocityTarget` / :class:`RateTarget`) and
        :class:`ServiceRequest` s to publish / call, oldest first."""
        out, self._outbox = self._outbox, []
        return out

    # ----------------------------------------------------------- MAVROS inputs
    def on_state(self, now: float, s: messages.MavrosVehicleState) -> None:
        """``/mavros/state``: a HEARTBEAT of the autopilot while ``connected``."""
        c = self._clock
        self.stats.states += 1
        if not s.connected:
            self.stats.disconnected_states += 1
            if c.connected:
                c.events.append(
                    LinkEvent(now, "link_lost", f"{self.namespace}/state: connected = false")
                )
            c.connected = False
            return
        mode = mode_from_mavros(s.mode)
        if mode == UNKNOWN_MODE:
            self.stats.unknown_modes += 1
        if not c.connected:
            c.events.append(LinkEvent(now, "link_up", f"{self.namespace}/state: {s.mode}"))
        c.connected, c.t_state = True, now
        failsafe = s.system_status in FAILSAFE_SYSTEM_STATUS and s.armed
        if failsafe:
            self.stats.failsafe_states += 1
            mode = UNKNOWN_MODE  # entered by PX4, not by a request: confirms nothing
            what = f"{s.mode} ({FAILSAFE_SYSTEM_STATUS[s.system_status]})"
            if c.failsafe != what:
                c.events.append(
                    LinkEvent(
                        now,
                        "px4_failsafe",
                        f"{self.namespace}/state: PX4 failsafe active, vehicle in {what}; "
                        "not evidence of a requested mode",
                    )
                )
            c.failsafe = what
        elif c.failsafe:
            c.events.append(
                LinkEvent(
                    now,
                    "px4_failsafe_end",
                    f"{self.namespace}/state: failsafe over, {s.mode} "
                    f"(system_status {s.system_status})",
                )
            )
            c.failsafe = ""
        self.last_mode = s.mode
        base = px4.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if s.armed:
            base |= px4.MAV_MODE_FLAG_SAFETY_ARMED
        self._inbox.append(
            _Msg(
                "HEARTBEAT",
                autopilot=MAV_AUTOPILOT_PX4,
                custom_mode=mode.custom_mode,
                base_mode=base,
            )
        )

    def on_service_answer(self, now: float, req: ServiceRequest, response: Any) -> None:
        """The final answer of a MAVROS service: a COMMAND_ACK of ``req.command``.
        ``set_mode``: ``mode_sent`` -> ACCEPTED (sent, not yet shown) else DENIED (MAVROS
        does not know the mode); ``arming``: ``result`` (PX4's COMMAND_ACK), FAILED when
        MAVROS reports no success without a result."""
        self.stats.service_answers += 1
        if req.key == "set_mode":
            result = px4.MAV_RESULT_ACCEPTED if bool(response.mode_sent) else MAV_RESULT_DENIED
        else:
            result = int(response.result)
            if not bool(response.success) and result == px4.MAV_RESULT_ACCEPTED:
                result = MAV_RESULT_FAILED
        self._inbox.append(_Msg("COMMAND_ACK", command=req.command, result=result))

    def on_service_failed(self, now: float, req: ServiceRequest) -> None:
        """A call that raised (no answer): nothing; the machine's ``ack_timeout`` retries."""

    def on_odometry(self, now: float, s: messages.StateSample) -> None:
        """``local_position/odom`` parsed in MAVROS's frames -> ODOMETRY (NED, FRD)."""
        q = frames.quaternion_from_euler(s.euler)
        self._inbox.append(
            _Msg(
                "ODOMETRY",
                time_usec=s.stamp_ns // 1000,
                q=[float(v) for v in q],
                x=float(s.pos_ned[0]),
                y=float(s.pos_ned[1]),
                z=float(s.pos_ned[2]),
                vx=float(s.v_body[0]),
                vy=float(s.v_body[1]),
                vz=float(s.v_body[2]),
                rollspeed=float(s.omega[0]),
                pitchspeed=float(s.omega[1]),
                yawspeed=float(s.omega[2]),
                child_frame_id=MAV_FRAME_BODY_FRD,
            )
        )

    def on_imu(self, now: float, i: messages.ImuSample) -> None:
        """``imu/data`` parsed (FRD) -> HIGHRES_IMU."""
        a, w = i.specific_force, i.omega
        self._inbox.append(
            _Msg(
                "HIGHRES_IMU",
                time_usec=i.stamp_ns // 1000,
                xacc=float(a[0]),
                yacc=float(a[1]),
                zacc=float(a[2]),
                xgyro=float(w[0]),
                ygyro=float(w[1]),
                zgyro=float(w[2]),
            )
        )

    def on_esc(self, now: float, stamp_ns: int, rpm: Sequence[float]) -> None:
        """``esc_status/status`` -> ESC_STATUS (index 0, all ESCs)."""
        self._inbox.append(_Msg("ESC_STATUS", time_usec=stamp_ns // 1000, index=0, rpm=list(rpm)))

    def on_rc_out(self, now: float, stamp_ns: int, channels: Sequence[int]) -> None:
        """``rc/out`` (PX4's SERVO_OUTPUT_RAW, port 0) -> SERVO_OUTPUT_RAW."""
        servos = {f"servo{k + 1}_raw": 0 for k in range(16)}
        servos.update({f"servo{k + 1}_raw": int(c) for k, c in enumerate(channels[:16])})
        self._inbox.append(
            _Msg("SERVO_OUTPUT_RAW", time_usec=(stamp_ns // 1000) % 2**32, port=0, **servos)
        )

    def on_target_attitude(
        self, now: float, time_boot_ms: int, rates_frd: np.ndarray, thrust: float
    ) -> None:
        """``setpoint_raw/target_attitude`` (PX4's ATTITUDE_TARGET, FLU turned back to FRD)
        -> ATTITUDE_TARGET: the rate setpoints PX4 tracks (the ``rate_setpoint`` echo)."""
        self._inbox.append(
            _Msg(
                "ATTITUDE_TARGET",
                time_boot_ms=int(time_boot_ms),
                thrust=float(thrust),
                body_roll_rate=float(rates_frd[0]),
                body_pitch_rate=float(rates_frd[1]),
                body_yaw_rate=float(rates_frd[2]),
            )
        )

    def on_home(self, now: float, home_ned: np.ndarray) -> None:
        """``home_position/home`` (local NED) -> HOME_POSITION (envelope home)."""
        self._inbox.append(
            _Msg("HOME_POSITION", x=float(home_ned[0]), y=float(home_ned[1]), z=float(home_ned[2]))
        )

    def status(self, now: float) -> dict[str, str]:
        c = self._clock
        age = now - c.t_state
        return {
            "mavros_state_age_s": f"{age:.3f}" if math.isfinite(age) else "inf",
            "mavros_mode": self.last_mode or "unknown",
            "px4_failsafe": c.failsafe or "false",
        }
