"""Message-level behaviour of mavlink_bridge_node (no rclpy here).

The node shell (``nodes/mavlink_bridge_node.py``) creates the publishers, subscriptions and
timers :class:`BridgeRuntime` lists for the selected ``transport`` and forwards messages,
timer ticks and service calls to it; the runtime answers with ``[(key, message), ...]`` to
publish (keys of :attr:`BridgeRuntime.publishers`) and queues its log lines
(:meth:`BridgeRuntime.take_log`, logged by the shell with the node's logger).

``transport: mavlink``: :class:`~lpv_sysid.mavlink.bridge.BridgeCore` (own MAVLink link):
the timer at ``poll_rate_hz`` polls the link, decoded telemetry goes out on ``state``,
``imu`` and ``rotor_speeds``; ``velocity_reference`` / ``actuator_command`` are forwarded as
setpoints; when commands stop for ``offboard.input_timeout`` s, on ``abort`` or on
shutdown the core hands control back to PX4. ``transport: mavros``:
:class:`~lpv_sysid.mavlink.bridge.mavros.MavrosCore`: MAVROS odometry and IMU are republished on
``state`` / ``imu``, references streamed on MAVROS's ``cmd_vel`` by a timer at twice the
setpoint rate. Either way the core's events and status values make the ``status``
DiagnosticArray (:meth:`BridgeRuntime.status`): the last warn/error event names the level
and message, every event is logged.

Vehicle record (``transport: mavlink``): every message of the target feeds a
:class:`~lpv_sysid.mavlink.telemetry.VehicleRecord` on the node clock (the one the fly CLI
keeps: firmware, PX4 parameter snapshot, battery, site, PX4's boot on that clock); once the
link is up the parameter list is asked (PARAM_REQUEST_LIST, again after a link loss: PX4 may
have rebooted) and AUTOPILOT_VERSION (MAV_CMD_REQUEST_MESSAGE, every
:data:`RECORD_ASK_PERIOD_S` until it arrives, at most :data:`RECORD_ASKS` times), as
``fly phase2`` does; neither touches the offboard logic (its COMMAND_ACK is not the pending
command's). The record goes out on ``vehicle_record`` (:meth:`BridgeRuntime.record_output`)
when it changed materially (``VehicleRecord.revision``), at most every
:data:`RECORD_MIN_PERIOD_S`, and every :data:`RECORD_REFRESH_S` while the vehicle's clock
knots or the battery reading move; the data logger writes it to ``experiment.yaml`` (``vehicle``).
``transport: mavros`` with mavros_msgs: the same record from what MAVROS offers -- firmware
and the HIL flag from ``vehicle_info_get``, the parameter snapshot by ``param/pull`` then
``param/list_parameters`` + ``param/get_parameters`` (MAVROS publishes no ``param/event``
for a pull: measured), battery from ``battery``, the site's latitude/longitude from
``home_position/home`` (its altitude is MAVROS' WGS-84 ellipsoid height, kept as
``altitude_wgs84_m``, not AMSL); PX4's boot time is not in MAVROS' messages, so
``px4_clock`` stays empty with a note (docs/px4_transport.md). ``mavros.interfaces:
common``: no record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence, Union

from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.flight.bridge.settings import (
    BridgeNodeSettings,
    handback_bound_s,
    link_url_source,
    split_parameters,
)
from lpv_sysid.io import messages
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.bridge import (
    DIAGNOSTICS_TOPIC,
    MODE_CONTROL,
    BridgeConfig,
    BridgeCore,
    MavrosConfig,
    MavrosCore,
    MavrosLink,
    RATE_INPUT_NAMES,
    MavrosOutput,
    RateTarget,
    ServiceRequest,
    VelocityTarget,
    cmd_vel_msg,
)
from lpv_sysid.mavlink.offboard import StatusEvent
from lpv_sysid.mavlink.preflight import (
    NOGO,
    PARAMS,
    MavrosEvidence,
    format_table,
    mavros_checks,
    verdict,
)
from lpv_sysid.mavlink.telemetry import ImuSample, RotorSample, StateSample, VehicleRecord

#: the package input topics parsed by the shell (``ShellNode.parse_input``: a bad message is
#: dropped with a throttled warning) before :meth:`BridgeRuntime.on_sample`
PARSERS = {
    "velocity_reference": messages.reference_from_twist,
    "actuator_command": messages.actuator_command_from_joint_state,
}
#: ``command: rate_setpoint`` (the rate-plant design): ``actuator_command`` carries the rate
#: plant's inputs (thrust, p_sp, q_sp, r_sp), sent as SET_ATTITUDE_TARGET unchanged but clipped
RATE_PLANT_PARSERS = {
    **PARSERS,
    "actuator_command": lambda msg: messages.channels_from_joint_state(
        msg, RATE_INPUT_NAMES, field="position"
    ),
}
#: rate of PX4's ATTITUDE_TARGET requested with ``command: rate_setpoint`` unless configured [Hz]
ATTITUDE_TARGET_HZ = 50.0


def with_attitude_target_stream(cfg: BridgeConfig) -> BridgeConfig:
    """``cfg`` with PX4's ATTITUDE_TARGET requested at :data:`ATTITUDE_TARGET_HZ` (the echo of
    the rate setpoints it tracks, recorded on ``rate_setpoint``) unless its rate is
    configured (also 0 = off)."""
    import dataclasses

    if any(name == "ATTITUDE_TARGET" for name, _ in cfg.link.streams):
        return cfg
    streams = tuple(cfg.link.streams) + (("ATTITUDE_TARGET", ATTITUDE_TARGET_HZ),)
    return dataclasses.replace(cfg, link=dataclasses.replace(cfg.link, streams=streams))


POSITION_TARGET = messages.MAVROS_TYPES["position_target"]
ATTITUDE_TARGET = messages.MAVROS_TYPES["attitude_target"]
#: transport mavros with mavros_msgs: subscription key -> (topic under the MAVROS
#: namespace, type); odometry and IMU are the common_interfaces ones of MavrosConfig
MAVROS_INPUTS = {
    "mavros_state": ("state", messages.MAVROS_TYPES["state"]),
    "mavros_esc": ("esc_status/status", messages.MAVROS_TYPES["esc_status"]),  # extras
    "mavros_rc_out": ("rc/out", messages.MAVROS_TYPES["rc_out"]),
    "mavros_home": ("home_position/home", messages.MAVROS_TYPES["home_position"]),
}
#: the MAVROS inputs of the preflight (``mavros.preflight``), besides the ones above
MAVROS_PREFLIGHT_INPUTS = {
    "mavros_rc_in": ("rc/in", messages.MAVROS_TYPES["rc_in"]),
    "mavros_battery": ("battery", messages.MAVROS_TYPES["battery"]),
    "mavros_gps_raw": ("gpsstatus/gps1/raw", messages.MAVROS_TYPES["gps_raw"]),
    "mavros_gps_fix": ("global_position/raw/fix", messages.MAVROS_TYPES["nav_sat_fix"]),
    "mavros_estimator": ("estimator_status", messages.MAVROS_TYPES["estimator_status"]),
}
#: preflight input key -> (MavrosEvidence field, parser of the message)
MAVROS_EVIDENCE = {
    "mavros_rc_in": ("rc_in", messages.rc_in_from_msg),
    "mavros_battery": ("battery", messages.battery_from_msg),
    "mavros_gps_raw": ("gps_raw", messages.gps_from_gpsraw),
    "mavros_gps_fix": ("gps_fix", messages.gps_from_navsatfix),
    "mavros_estimator": ("estimator_flags", messages.estimator_flags_from_msg),
}
#: seconds between the preflight's questions to MAVROS while answers are missing, and
#: between refreshes of the parameters once all are in (a parameter set meanwhile counts)
PREFLIGHT_ASK_PERIOD_S = 2.0
PREFLIGHT_REFRESH_S = 10.0
#: MAVLink ids of SERVO_OUTPUT_RAW (MAVROS rc/out), asked at ``mavros.rc_out_rate_hz``,
#: and ATTITUDE_TARGET (MAVROS setpoint_raw/target_attitude: the rate_setpoint echo)
SERVO_OUTPUT_RAW_ID, ATTITUDE_TARGET_ID = 36, 83
#: MAVLink id of AUTOPILOT_VERSION: MAVROS 2.10's sys_status plugin requests it only a few
#: times, 1 s apart, after connecting (a stalled host can miss them all, and its
#: vehicle_info_get then answers flight_sw_version 0 for good); while the firmware is
#: unknown the preflight asks PX4 for it through ``<ns>/cmd/command`` (MAV_CMD_REQUEST_MESSAGE)
#: every PREFLIGHT_ASK_PERIOD_S, one call at a time -- MAVROS's AUTOPILOT_VERSION handler
#: stores the answer whenever it arrives
AUTOPILOT_VERSION_ID = 148
#: seconds between rate requests until MAVROS answers success (again after a link loss)
RATE_ASK_PERIOD_S = 5.0
#: preflight checks that do not refuse the bridge's ``start``: an armed vehicle (airborne
#: in Hold, phase 2) is the normal case of a start; the CLI preflight is a ground check
NOT_BLOCKING_AT_START = ("armed",)
#: MAVROS input key -> the MAVLink stream it stands for (preflight ``seen``)
SEEN = {
    "mavros_odom": "ODOMETRY",
    "mavros_imu": "HIGHRES_IMU",
    "mavros_esc": "ESC_STATUS",
    "mavros_rc_out": "SERVO_OUTPUT_RAW",
}


def _use_mavros_msgs(cfg: MavrosConfig, factory: messages.MsgFactory) -> bool:
    """``interfaces`` resolved: ``auto`` means mavros_msgs when the factory can load it."""
    if cfg.interfaces != "auto":
        return cfg.interfaces == "mavros_msgs"
    try:
        factory.lookup(messages.MAVROS_TYPES["state"])
    except (LpvSysidError, ImportError, ValueError):
        return False
    return True


#: vehicle record: AUTOPILOT_VERSION asked every RECORD_ASK_PERIOD_S [s] until it arrives, at
#: most RECORD_ASKS times per link-up; the record published at most every
#: RECORD_MIN_PERIOD_S [s] after a material change and every RECORD_REFRESH_S [s] while the
#: clock knots grow (PX4's boot offset, battery at the end)
RECORD_ASK_PERIOD_S, RECORD_ASKS = 2.0, 10
RECORD_MIN_PERIOD_S, RECORD_REFRESH_S = 1.0, 10.0
#: names per ``param/get_parameters`` call of the MAVROS parameter snapshot
PARAM_BATCH = 200
#: ``px4_clock`` note of a record made through MAVROS
MAVROS_CLOCK_NOTE = (
    "not recorded: MAVROS' messages carry no PX4 boot time (their stamps are already on "
    "the ROS clock); a ULog cannot be lined up from this record"
)
#: MAVLink id of AUTOPILOT_VERSION (MAV_CMD_REQUEST_MESSAGE's param 1)
AUTOPILOT_VERSION_ID = 148

#: core states in which the orderly shutdown needs no more spinning
SHUTDOWN_DONE = ("IDLE", "DONE", "FAILED")


@dataclass(frozen=True)
class Endpoint:
    """A publisher or subscription the shell creates: ``key`` names the message type and
    the handler, ``topic`` the topic (relative: in the node's namespace); ``qos``
    ``sensor`` | ``reliable``, or empty for the package topic table's QoS."""

    key: str
    topic: str
    qos: str = ""
    typename: str = ""  # a mavros_msgs type (looked up by name: no import without MAVROS)


Output = list[tuple[str, Any]]


class BridgeRuntime:
    """See module docstring. ``params``: the declared values of
    :data:`~lpv_sysid.flight.bridge.settings.SPECS`; ``factory`` builds the messages;
    ``sigterm_timeout_s`` / ``teardown_margin_s``: what a launch leaves the orderly shutdown
    (a hand-back chain longer than their difference is warned)."""

    def __init__(
        self,
        params: Mapping[str, Any],
        factory: messages.MsgFactory,
        name: str,
        sigterm_timeout_s: float,
        teardown_margin_s: float,
    ) -> None:
        own, bridge, mavros = split_parameters(params)
        self.settings = s = BridgeNodeSettings.from_dict(own)
        #: where link.url came from (the launch argument or the parameter file)
        self.link_url_source = link_url_source(own)
        self.f, self.name = factory, name
        self._log: list[tuple[str, str]] = []
        self._shutting_down = False
        self.link: BridgeCore | None = None
        self.mavros: MavrosCore | None = None
        #: transport mavros with mavros_msgs: the link of ``self.link`` (a BridgeCore)
        self.mavros_link: MavrosLink | None = None
        #: MAVROS services the shell calls with the ServiceRequests of the output
        self.clients: list[Endpoint] = []
        #: the preflight's MAVROS evidence (mavros_msgs with ``mavros.preflight``), else None
        self.evidence: MavrosEvidence | None = None
        self._t_asked = -math.inf
        #: the orderly-shutdown bound [s] (None: the shell's default)
        self.shutdown_timeout_s: float | None = None
        self.publishers = [Endpoint("state", "state"), Endpoint("imu", "imu")]
        self.subscriptions = [Endpoint("velocity_reference", "velocity_reference")]
        self.core: Union[MavrosCore, BridgeCore]
        #: the parsers of the package input topics for this configuration (the shell's)
        self.parsers: Mapping[str, Any] = PARSERS
        #: PX4's ATTITUDE_TARGET (the setpoints it tracks) seen since the last poll
        self._echo: list[tuple[float, Any]] = []
        #: transport mavlink: the vehicle record (module docstring), fed from :meth:`open`
        self.vehicle: VehicleRecord | None = None
        #: the node clock's kind (``utc`` | ``ros_sim_time``): what the record's times are on
        self.clock_kind = "utc"
        self._record_asked = False  # PARAM_REQUEST_LIST sent on this link-up
        self._version_asks = 0
        self._t_version_asked = -math.inf
        #: (revision, boot samples, last battery stamp) of the record sent last
        self._record_sent: tuple | None = None
        self._t_record_sent = -math.inf
        mcfg = MavrosConfig.from_dict(mavros) if s.transport == "mavros" else None
        if mcfg is not None and _use_mavros_msgs(mcfg, factory):
            self._init_mavros_msgs(mcfg, bridge, sigterm_timeout_s, teardown_margin_s)
        elif mcfg is not None:
            if mcfg.command != "velocity":
                raise ConfigError(
                    f"mavros.command {mcfg.command!r} needs mavros_msgs, which cannot be "
                    "loaded (source a ROS with mavros_msgs, or use command velocity)"
                )
            self.core = self.mavros = MavrosCore(mcfg)
            cfg = self.mavros.config
            self.publishers.append(Endpoint("cmd_vel", cfg.topic("cmd_vel"), "reliable"))
            self.subscriptions += [
                Endpoint("mavros_odom", cfg.topic("odom"), "sensor"),
                Endpoint("mavros_imu", cfg.topic("imu"), "sensor"),
            ]
            if cfg.use_diagnostics:
                self.subscriptions.append(
                    Endpoint("mavros_diagnostics", DIAGNOSTICS_TOPIC, "sensor")
                )
            # twice the setpoint rate: the core sends when due; stale input is seen within
            # half a setpoint period
            self.timer_period_s = 0.5 / cfg.setpoint_rate_hz
            self._log.append(
                (
                    "info",
                    f"MAVROS {cfg.namespace}: setpoints on {cfg.topic('cmd_vel')}; "
                    f"mode control: {MODE_CONTROL}",
                )
            )
        else:
            cfg_b = BridgeConfig.from_dict(bridge)
            if cfg_b.command == "rate_setpoint":
                self.parsers = RATE_PLANT_PARSERS
            if s.rate_setpoints:
                cfg_b = with_attitude_target_stream(cfg_b)
            self.core = self.link = BridgeCore(cfg_b)
            self.publishers.append(Endpoint("rotor_speeds", "rotor_speeds"))
            self.publishers.append(
                Endpoint("vehicle_record", messages.VEHICLE_RECORD_TOPIC, "record")
            )
            if s.rate_setpoints:
                self.publishers.append(Endpoint("rate_setpoint", "rate_setpoint"))
            self.subscriptions.append(Endpoint("actuator_command", "actuator_command"))
            if cfg_b.command != "velocity":
                # phase 2: the excitation node's velocity_reference is the controller's input,
                # not a setpoint of this bridge (each one was rejected with a WARN status:
                # 100 status messages a second on the stand-in graph)
                self.subscriptions = [
                    e for e in self.subscriptions if e.key != "velocity_reference"
                ]
            self.timer_period_s = 1.0 / s.poll_rate_hz
            self._log += self._handback_lines(sigterm_timeout_s, teardown_margin_s)

    def _init_mavros_msgs(
        self, mcfg: MavrosConfig, bridge: Mapping[str, Any], sigterm_s: float, margin_s: float
    ) -> None:
        """transport mavros with mavros_msgs: BridgeCore over a :class:`MavrosLink`."""
        ns = mcfg.namespace
        self.mavros_link = MavrosLink(mcfg.state_timeout, ns)
        cfg_b = BridgeConfig.from_dict(bridge)
        if cfg_b.command == "rate_setpoint":
            self.parsers = RATE_PLANT_PARSERS
        self.core = self.link = BridgeCore(cfg_b, link=self.mavros_link)
        self._mavros_cfg = mcfg
        self._rejected: dict[str, int] = {}
        self.evidence = MavrosEvidence() if mcfg.preflight else None
        #: when the pending request for AUTOPILOT_VERSION was made (None: none pending)
        self._version_asked: float | None = None
        #: MAVLink message id -> rate [Hz] asked through set_message_interval; the ids
        #: MAVROS answered success for (cleared by a link loss)
        self._rates: dict[int, float] = {}
        if mcfg.rc_out_rate_hz > 0:
            self._rates[SERVO_OUTPUT_RAW_ID] = mcfg.rc_out_rate_hz
        if self.settings.rate_setpoints:
            self._rates[ATTITUDE_TARGET_ID] = ATTITUDE_TARGET_HZ
        self._rates_ok: set[int] = set()
        self._t_rate_asked = -math.inf
        if self.link.config.command == "velocity":
            sp = Endpoint("mavros_local", f"{ns}/setpoint_raw/local", "reliable", POSITION_TARGET)
        else:
            sp = Endpoint(
                "mavros_attitude", f"{ns}/setpoint_raw/attitude", "reliable", ATTITUDE_TARGET
            )
        self.publishers += [Endpoint("rotor_speeds", "rotor_speeds"), sp]
        if self.settings.rate_setpoints:  # PX4's ATTITUDE_TARGET, as MAVROS republishes it
            self.publishers.append(Endpoint("rate_setpoint", "rate_setpoint"))
            self.subscriptions.append(
                Endpoint(
                    "mavros_target_attitude",
                    f"{ns}/setpoint_raw/target_attitude",
                    "sensor",
                    ATTITUDE_TARGET,
                )
            )
        if self.link.config.command != "velocity":
            # phase 2: velocity_reference is the controller's input, not a setpoint here (as
            # over MAVLink: each one was refused with an ERROR line, 50 a second through
            # real MAVROS, load enough to trip the controller's loop-delay watchdog)
            self.subscriptions = [e for e in self.subscriptions if e.key != "velocity_reference"]
        self.subscriptions += [
            Endpoint("actuator_command", "actuator_command"),
            Endpoint("mavros_odom", mcfg.topic("odom"), "sensor"),
            Endpoint("mavros_imu", mcfg.topic("imu"), "sensor"),
        ] + [Endpoint(k, f"{ns}/{t}", "sensor", ty) for k, (t, ty) in MAVROS_INPUTS.items()]
        self.clients = [
            Endpoint("set_mode", f"{ns}/set_mode", "", messages.MAVROS_TYPES["set_mode"]),
            Endpoint("arming", f"{ns}/cmd/arming", "", messages.MAVROS_TYPES["command_bool"]),
        ]
        if self._rates:
            self.clients.append(
                Endpoint(
                    "message_interval",
                    f"{ns}/set_message_interval",
                    "",
                    messages.MAVROS_TYPES["message_interval"],
                )
            )
        # the vehicle record (module docstring): its inputs, its questions to MAVROS
        self.vehicle = VehicleRecord(clock_note=MAVROS_CLOCK_NOTE)
        self._params_state = "ask"  # ask -> pulling -> listing -> getting -> done
        self._t_pull_asked = -math.inf
        self._param_names: list[str] = []
        self.publishers.append(Endpoint("vehicle_record", messages.VEHICLE_RECORD_TOPIC, "record"))
        self.clients += [
            Endpoint("param_pull", f"{ns}/param/pull", "", messages.MAVROS_TYPES["param_pull"]),
            Endpoint(
                "param_list",
                f"{ns}/param/list_parameters",
                "",
                messages.MAVROS_TYPES["list_parameters"],
            ),
            Endpoint(
                "record_param_get",
                f"{ns}/param/get_parameters",
                "",
                messages.MAVROS_TYPES["get_parameters"],
            ),
            Endpoint(
                "vehicle_info",
                f"{ns}/vehicle_info_get",
                "",
                messages.MAVROS_TYPES["vehicle_info_get"],
            ),
        ]
        if mcfg.preflight:
            self.subscriptions += [
                Endpoint(k, f"{ns}/{t}", "sensor", ty)
                for k, (t, ty) in MAVROS_PREFLIGHT_INPUTS.items()
            ]
            self.clients.append(
                Endpoint(
                    "param_get",
                    f"{ns}/param/get_parameters",
                    "",
                    messages.MAVROS_TYPES["get_parameters"],
                ),
            )
            self.clients.append(
                Endpoint(
                    "request_message",
                    f"{ns}/cmd/command",
                    "",
                    messages.MAVROS_TYPES["command_long"],
                )
            )
        else:  # the record's battery
            t, ty = MAVROS_PREFLIGHT_INPUTS["mavros_battery"]
            self.subscriptions.append(Endpoint("mavros_battery", f"{ns}/{t}", "sensor", ty))
        self.timer_period_s = 1.0 / self.settings.poll_rate_hz
        self._log.append(
            (
                "info",
                f"MAVROS {ns} with mavros_msgs: mode from {ns}/state (stale after "
                f"{mcfg.state_timeout:g} s), {ns}/set_mode and {ns}/cmd/arming, setpoints on "
                f"{sp.topic}",
            )
        )
        self._log += self._handback_lines(sigterm_s, margin_s)

    def _handback_lines(self, sigterm_timeout_s: float, margin_s: float) -> list[tuple[str, str]]:
        assert self.link is not None  # transport mavlink
        cfg = self.link.config
        bound = self.shutdown_timeout_s = handback_bound_s(cfg.offboard)
        lines = [
            (
                "info",
                f"MAVLink {cfg.link.url} (from the {self.link_url_source}), command "
                f"{cfg.command}; hand-back chain "
                f"{list(cfg.offboard.handback_chain)} within {bound:g} s",
            )
        ]
        budget = sigterm_timeout_s - margin_s
        if bound > budget:
            lines.append(
                (
                    "warn",
                    f"the hand-back chain may need {bound:g} s, more than the "
                    f"{budget:g} s a launch Ctrl-C leaves before SIGTERM: launch with "
                    f"sigterm_timeout:={bound + margin_s:g}",
                )
            )
        return lines

    def take_log(self) -> list[tuple[str, str]]:
        """Queued ``(level, text)`` lines (level: info | warn | error), oldest first."""
        out, self._log = self._log, []
        return out

    def open(self, now: float) -> None:
        """Open the MAVLink link (transport mavlink; MAVROS owns its link); PX4's
        ATTITUDE_TARGET is republished on ``rate_setpoint``."""
        if self.link is not None:
            from lpv_sysid.flight.vehicle import tap_attitude_target, tap_messages

            self.link.open(now)
            if self.settings.rate_setpoints:
                tap_attitude_target(self.link.link, lambda t, u: self._echo.append((t, u)))
            if self.mavros_link is None:
                rec = self.vehicle = VehicleRecord()
                tap_messages(self.link.link, lambda t, m: rec.absorb(m, round(t * 1e9)))

    # -- inputs ---------------------------------------------------------------------------
    def on_sample(self, key: str, parsed: tuple, now: float) -> Output:
        """A package input parsed by :data:`PARSERS` ``[key]``: forwarded to the core."""
        if key == "velocity_reference":
            t, v, r = parsed
            out = self.core.on_velocity_reference(now, v, r, stamp=t)
            return self._mavros_out(out, now) if isinstance(out, MavrosOutput) else []
        if self.link is not None and key == "actuator_command":
            self.link.on_actuator_command(now, parsed[1], stamp=parsed[0])
        return self._drain(now)

    def on_message(self, key: str, msg: Any, now: float) -> Output:
        """A MAVROS message (transport mavros): ``mavros_odom`` / ``mavros_imu`` are parsed in
        MAVROS's frames (a bad one is counted and reported by the core) and republished on
        ``state`` / ``imu``; ``mavros_diagnostics`` gives the PX4 mode."""
        if self.mavros_link is not None:
            return self._on_mavros_msgs(key, msg, now)
        core = self.mavros
        if core is None:
            return []
        if key == "mavros_diagnostics":
            try:
                _, statuses = messages.status_from_diagnostic_array(msg)
            except LpvSysidError:
                return []  # other nodes' diagnostics are not ours to judge
            core.on_diagnostics(now, statuses)
            return []
        cfg, f = core.config, self.f
        odom = key == "mavros_odom"
        try:
            if odom:
                s = messages.state_from_odometry(
                    msg, frame_id=cfg.odom_frame_id, child_frame_id=cfg.base_frame_id
                )
            else:
                i = messages.imu_from_msg(msg, frame_id=cfg.base_frame_id)
        except LpvSysidError as exc:
            core.reject(now, f"{cfg.topic('odom' if odom else 'imu')} rejected: {exc}")
            return []
        if odom:
            st = core.on_odometry(now, s)
            if st is None:
                return []
            return [
                (
                    "state",
                    messages.odometry_from_state(
                        f, st.stamp_ns, st.pos_ned, st.euler, st.v_body, st.omega
                    ),
                )
            ]
        imu = core.on_imu(now, i)
        if imu is None:
            return []
        return [
            ("imu", messages.imu_msg(f, imu.stamp_ns, imu.specific_force, imu.omega, imu.euler))
        ]

    def _on_mavros_msgs(self, key: str, msg: Any, now: float) -> Output:
        """transport mavros with mavros_msgs: a MAVROS message becomes link evidence (the
        core judges it at the next poll); a malformed one is counted and reported."""
        link, cfg, ev = self.mavros_link, self._mavros_cfg, self.evidence
        assert link is not None
        try:
            self._record_mavros(key, msg, now)
            if key in MAVROS_EVIDENCE:
                name, parse = MAVROS_EVIDENCE[key]
                if ev is not None:
                    ev.put(name, parse(msg), now)
                return []
            if key == "mavros_state":
                link.on_state(now, messages.state_from_msg(msg))
            elif key == "mavros_odom":
                link.on_odometry(
                    now,
                    messages.state_from_odometry(
                        msg, frame_id=cfg.odom_frame_id, child_frame_id=cfg.base_frame_id
                    ),
                )
            elif key == "mavros_imu":
                link.on_imu(now, messages.imu_from_msg(msg, frame_id=cfg.base_frame_id))
            elif key == "mavros_esc":
                link.on_esc(now, *messages.esc_rpm_from_msg(msg))
            elif key == "mavros_rc_out":
                stamp_ns, channels = messages.rc_out_from_msg(msg)
                link.on_rc_out(now, stamp_ns, channels)
                if ev is not None:
                    ev.put("servo_raw", channels, now)
            elif key == "mavros_home":
                link.on_home(now, messages.home_ned_from_msg(msg))
                if ev is not None:
                    ev.put("home", messages.home_geo_from_msg(msg), now)
            elif key == "mavros_target_attitude":
                t_boot_ms = messages.stamp_ns_of(msg) // 1_000_000
                _, rates, thrust = messages.rate_setpoint_from_attitude_target_msg(msg)
                link.on_target_attitude(now, t_boot_ms, rates, thrust)
            if ev is not None and key in SEEN:
                ev.saw(SEEN[key], now)
        except LpvSysidError as exc:
            link.stats.rejected_inputs += 1
            n = self._rejected[key] = self._rejected.get(key, 0) + 1
            if n & (n - 1) == 0:  # the 1st, 2nd, 4th, 8th, ... of a kind: no log flood
                self._log.append(("warn", f"{key} rejected ({n} so far): {exc}"))
        return []

    def _record_mavros(self, key: str, msg: Any, now: float) -> None:
        """The vehicle record's MAVROS inputs: battery and home (module docstring)."""
        rec = self.vehicle
        if rec is None:
            return
        if key == "mavros_battery":
            pct, volts = messages.battery_from_msg(msg)
            if math.isfinite(volts) and volts > 0.0:
                rec.battery_reading(round(now * 1e9), volts, -1 if pct is None else round(pct))
        elif key == "mavros_home":
            lat, lon, alt = messages.home_geo_from_msg(msg)
            rec.set_site(
                "MAVROS home_position/home",
                lat,
                lon,
                None,  # MAVROS' geo altitude is the WGS-84 ellipsoid height, not AMSL
                messages.home_ned_from_msg(msg),
                round(now * 1e9),
                altitude_wgs84_m=alt,
            )

    def _record_questions(self, now: float) -> list[ServiceRequest]:
        """transport mavros: the record's questions -- ``param/pull`` (PARAM_REQUEST_LIST
        through MAVROS) once per link-up, then the names (``param/list_parameters``) and
        their values (``param/get_parameters``, :data:`PARAM_BATCH` at a time); and
        ``vehicle_info_get`` until it answers (every RECORD_ASK_PERIOD_S, RECORD_ASKS
        times)."""
        link, rec = self.mavros_link, self.vehicle
        if link is None or rec is None:
            return []
        if not link.link_up(now):
            self._params_state, self._version_asks = "ask", 0
            return []
        out = []
        if self._params_state == "ask" and now - self._t_pull_asked >= RECORD_ASK_PERIOD_S:
            self._params_state, self._t_pull_asked = "pulling", now
            out.append(ServiceRequest("param_pull", {"force_pull": False}, 0))
        elif self._params_state == "listing":
            self._params_state = "listing_asked"
            out.append(ServiceRequest("param_list", {"prefixes": [], "depth": 0}, 0))
        elif self._params_state == "getting" and self._param_names:
            batch = self._param_names[:PARAM_BATCH]
            self._param_names = self._param_names[PARAM_BATCH:]
            self._params_state = "getting_asked"
            out.append(ServiceRequest("record_param_get", {"names": batch}, 0))
        if (
            rec.version is None
            and self._version_asks < RECORD_ASKS
            and now - self._t_version_asked >= RECORD_ASK_PERIOD_S
        ):
            self._version_asks += 1
            self._t_version_asked = now
            out.append(
                ServiceRequest("vehicle_info", {"sysid": 0, "compid": 0, "get_all": False}, 0)
            )
        return out

    def _record_answer(self, req: ServiceRequest, response: Any) -> bool:
        """An answer to :meth:`_record_questions` (True when it was one). A failed step of
        the parameter snapshot starts it again at the next link-up check."""
        rec = self.vehicle
        if rec is None or req.key not in ("param_pull", "param_list", "record_param_get"):
            return False
        if response is None:
            self._params_state = "ask"
            return True
        try:
            if req.key == "param_pull":
                ok = bool(response.success)
                self._params_state = "listing" if ok else "ask"
                self._log.append(
                    (
                        "info" if ok else "warn",
                        f"vehicle record: MAVROS param pull {'received' if ok else 'failed'}"
                        f" ({int(response.param_received)} parameters)",
                    )
                )
            elif req.key == "param_list":
                self._param_names = messages.param_names_from_list(response)
                self._params_state = "getting" if self._param_names else "ask"
            else:
                for name, value in messages.params_from_get_parameters(
                    req.fields["names"], response
                ).items():
                    rec.set_param(name, value)
                self._params_state = "getting" if self._param_names else "done"
        except (LpvSysidError, AttributeError, TypeError, ValueError) as exc:
            self._params_state = "ask"
            self._log.append(("warn", f"vehicle record: {req.key} answer unusable: {exc}"))
        return True

    def on_service_answer(self, req: ServiceRequest, response: Any, now: float) -> Output:
        """The answer of a MAVROS service call the shell made for ``req`` (None: the call
        failed; the core's ``ack_timeout`` then retries)."""
        assert self.mavros_link is not None
        if req.key == "request_message":
            self._version_asked = None  # answered (or failed): the next one may go
        if self._record_answer(req, response):
            if response is None:
                self._log.append(("warn", f"{req.key} got no answer"))
        elif response is None:
            self.mavros_link.on_service_failed(now, req)
            self._log.append(("warn", f"{req.key} {req.fields} got no answer"))
        elif req.key == "vehicle_info":
            self._vehicle_info_answer(response)
        elif req.key == "param_get":
            self._preflight_answer(req, response)
        elif req.key == "request_message":
            if not bool(getattr(response, "success", False)):
                n = self._rejected[req.key] = self._rejected.get(req.key, 0) + 1
                if n & (n - 1) == 0:  # the 1st, 2nd, 4th, ... refusal: no log flood
                    self._log.append(
                        (
                            "warn",
                            f"AUTOPILOT_VERSION request not accepted ({n} so far): "
                            f"MAV_RESULT {getattr(response, 'result', '?')}",
                        )
                    )
        elif req.key == "message_interval":
            ok = bool(getattr(response, "success", False))
            if ok:
                self._rates_ok.add(int(req.fields["message_id"]))
            else:
                self._log.append(("warn", f"{req.fields} refused by MAVROS/PX4"))
        else:
            self.mavros_link.on_service_answer(now, req, response)
        return []

    def _vehicle_info_answer(self, response: Any) -> None:
        """``vehicle_info_get``: the record's firmware and HIL flag, the preflight's vehicle."""
        try:
            vi = messages.vehicle_from_info_response(response)
            if vi is None:
                return
            fw = messages.firmware_from_vehicle_info(vi)
            if self.vehicle is not None and fw is not None:  # None: asked again
                sw, custom, board, vendor, product, uid, base_mode = fw
                self.vehicle.set_firmware(sw, custom, board, vendor, product, uid)
                self.vehicle.observe_base_mode(base_mode)
            if self.evidence is not None:
                self.evidence.vehicle = vi
        except (LpvSysidError, AttributeError, TypeError, ValueError) as exc:
            self._log.append(("warn", f"vehicle_info answer unusable: {exc}"))

    def _preflight_answer(self, req: ServiceRequest, response: Any) -> None:
        ev = self.evidence
        assert ev is not None
        try:
            got = messages.params_from_get_parameters(req.fields["names"], response)
            ev.params.update(got)
            if self.vehicle is not None:  # a parameter set since the snapshot counts there too
                for name, value in got.items():
                    self.vehicle.set_param(name, value)
        except (LpvSysidError, AttributeError, TypeError, ValueError) as exc:
            self._log.append(("warn", f"{req.key} answer unusable: {exc}"))

    def _rate_request(self, now: float) -> list[ServiceRequest]:
        """The stream rates of ``self._rates`` (PX4's onboard link sends SERVO_OUTPUT_RAW
        and ATTITUDE_TARGET at 10 Hz): asked once MAVROS is connected, every
        RATE_ASK_PERIOD_S until it answers success, again after a link loss (PX4 may have
        rebooted)."""
        link = self.mavros_link
        if link is None or not self._rates:
            return []
        if not link.link_up(now):
            self._rates_ok.clear()
            return []
        todo = [i for i in self._rates if i not in self._rates_ok]
        if not todo or now - self._t_rate_asked < RATE_ASK_PERIOD_S:
            return []
        self._t_rate_asked = now
        return [
            ServiceRequest(
                "message_interval", {"message_id": i, "message_rate": float(self._rates[i])}, 0
            )
            for i in todo
        ]

    def _preflight_questions(self, now: float) -> list[ServiceRequest]:
        """While MAVROS is connected: ask what is missing (every PREFLIGHT_ASK_PERIOD_S),
        refresh the parameters once all are in (every PREFLIGHT_REFRESH_S). The vehicle
        info is asked until it holds the firmware (AUTOPILOT_VERSION); while MAVROS has
        answered without it, PX4 is asked for it through ``cmd/command``
        (:data:`AUTOPILOT_VERSION_ID`)."""
        ev, link = self.evidence, self.mavros_link
        if ev is None or link is None or not link.link_up(now):
            return []
        missing = ev.missing_params()
        firmware = ev.firmware_known()
        period = PREFLIGHT_REFRESH_S if not missing and firmware else PREFLIGHT_ASK_PERIOD_S
        if now - self._t_asked < period:
            return []
        self._t_asked = now
        out = [ServiceRequest("param_get", {"names": missing or list(PARAMS)}, 0)]
        if not firmware:
            out.append(
                ServiceRequest("vehicle_info", {"sysid": 0, "compid": 0, "get_all": False}, 0)
            )
        # one call at a time; one MAVROS never answered (service not up yet) is made again
        asked = self._version_asked
        pending = asked is not None and now - asked < PREFLIGHT_REFRESH_S
        if not firmware and ev.vehicle is not None and not pending:
            self._version_asked = now
            out.append(
                ServiceRequest(
                    "request_message",
                    {
                        "broadcast": False,
                        "command": px4.MAV_CMD_REQUEST_MESSAGE,
                        "confirmation": 0,
                        "param1": float(AUTOPILOT_VERSION_ID),
                    },
                    0,
                )
            )
        return out

    def _preflight_refusal(self, now: float) -> str:
        """'' when the preflight on MAVROS's evidence finds no NO-GO (or is off), else the
        reason ``start`` is refused (and the parameters are asked again, so a fixed one
        counts at the next ``start``); the table is logged either way."""
        ev, core = self.evidence, self.link
        if ev is None or core is None or self.mavros_link is None:
            return ""
        up = self.mavros_link.link_up(now)
        ev.mode = core.machine.vehicle_mode if up else None
        ev.armed = core.machine.armed
        max_age = self._mavros_cfg.health_max_age
        stale = ev.stale(now, max_age)
        if stale:
            self._log.append(
                ("warn", f"MAVROS evidence older than {max_age:g} s ignored: {', '.join(stale)}")
            )
        checks = mavros_checks(
            ev.fresh(now, max_age), core.config.rotor_estimate, self._mavros_cfg.namespace
        )
        blocking = [c for c in checks if c.name not in NOT_BLOCKING_AT_START]
        ok = verdict(blocking)
        self._log.append(
            ("info" if ok else "error", "preflight (MAVROS):\n" + format_table(checks))
        )
        if ok:
            return ""
        # a refusal is acted on (a parameter set, MAVROS reconnected): ask again
        ev.params.clear()
        ev.vehicle = None
        self._t_asked = -math.inf
        nogo = [c for c in blocking if c.verdict == NOGO]
        # judged values first; evidence not received yet is named as missing (MAVROS may
        # still deliver it: a retry of the start can pass; a judged NO-GO needs a fix)
        nogo.sort(key=lambda c: c.missing)
        bad = "; ".join(f"{c.name}: {c.value}" for c in nogo)
        absent = [c.name for c in nogo if c.missing]
        tail = f"; evidence missing so far: {', '.join(absent)}" if absent else ""
        return f"start refused: preflight NO-GO through MAVROS ({bad}){tail}"

    def _drain(self, now: float) -> Output:
        """transport mavros with mavros_msgs: the link's setpoints as MAVROS messages and its
        service requests (key ``set_mode`` / ``arming``, the shell calls them)."""
        if self.mavros_link is None:
            return []
        f, stamp, out = self.f, round(now * 1e9), []
        for item in self.mavros_link.take_outbox():
            if isinstance(item, VelocityTarget):
                msg = messages.position_target_msg(
                    f, stamp, item.frame, item.type_mask, item.v, item.yaw_rate
                )
                out.append(("mavros_local", msg))
            elif isinstance(item, RateTarget):
                msg = messages.attitude_target_msg(
                    f, stamp, item.type_mask, item.rates_frd, item.thrust
                )
                out.append(("mavros_attitude", msg))
            elif isinstance(item, ServiceRequest):
                out.append((item.key, item))
        return out

    # -- services -------------------------------------------------------------------------
    def start(self, now: float) -> tuple[bool, str, Output]:
        """The ``start`` service: ``(success, message, output)`` (the status to publish)."""
        refusal = self._preflight_refusal(now)
        if refusal:
            st = self.core.state.value
            return False, refusal, self.status(now, [StatusEvent(now, st, st, refusal, "error")])
        events = self.core.start(now)
        out = self.status(now, events) + self._drain(now)
        return True, f"offboard: {self.core.state.value}", out

    def abort(self, now: float, reason: str = "abort service") -> tuple[bool, str, Output]:
        """The ``abort`` service: hand control back; ``(success, message, output)``."""
        events = self.core.abort(now, reason)
        message = f"handing control back to PX4: {self.core.state.value}"
        return True, message, self.status(now, events) + self._drain(now)

    # -- loop -----------------------------------------------------------------------------
    def on_timer(self, now: float) -> Output:
        """The ``timer_period_s`` timer: poll the link (mavlink) or step the MAVROS stream."""
        if self.mavros is not None:
            return self._mavros_out(self.mavros.step(now), now)
        assert self.link is not None
        out = self.link.poll(now)
        questions = (
            self._preflight_questions(now) + self._rate_request(now) + self._record_questions(now)
        )
        asks = [(q.key, q) for q in questions]
        f = self.f
        pubs: Output = []
        for s in out.samples:
            stamp = round(s.t * 1e9)
            if isinstance(s, StateSample):
                pubs.append(
                    (
                        "state",
                        messages.odometry_from_state(
                            f, stamp, s.pos_ned, s.euler, s.v_body, s.omega
                        ),
                    )
                )
            elif isinstance(s, ImuSample):
                pubs.append(("imu", messages.imu_msg(f, stamp, s.accel_frd, s.gyro_frd)))
            elif isinstance(s, RotorSample):
                pubs.append(
                    ("rotor_speeds", messages.rotor_speeds_msg(f, stamp, s.omega, s.source))
                )
        for t, u in self._echo:
            pubs.append(
                (
                    "rate_setpoint",
                    messages.joint_state(f, round(t * 1e9), RATE_INPUT_NAMES, position=u),
                )
            )
        self._echo.clear()
        if out.events:
            pubs += self.status(now, out.events)
        self._ask_record(now)
        return pubs + self._drain(now) + asks + self.record_output(now)

    def _ask_record(self, now: float) -> None:
        """The vehicle record's questions to PX4 (module docstring): the parameter list once
        per link-up, AUTOPILOT_VERSION until it arrives."""
        if self.vehicle is None or self.link is None or self.mavros_link is not None:
            return
        from lpv_sysid.flight.vehicle import request_parameter_list
        from lpv_sysid.mavlink import px4

        link = self.link.link
        if not (link.target_system and link.link_up(now)):
            self._record_asked, self._version_asks = False, 0
            return
        if not self._record_asked:
            self._record_asked = True
            request_parameter_list(link)
        if (
            self.vehicle.version is None
            and self._version_asks < RECORD_ASKS
            and now - self._t_version_asked >= RECORD_ASK_PERIOD_S
        ):
            self._version_asks += 1
            self._t_version_asked = now
            link.command_long(px4.MAV_CMD_REQUEST_MESSAGE, float(AUTOPILOT_VERSION_ID))

    def record_output(self, now: float, force: bool = False) -> Output:
        """``[("vehicle_record", msg)]`` when the record is due (module docstring; ``force``:
        now if anything is new, e.g. at shutdown), else ``[]``."""
        rec = self.vehicle
        if rec is None or rec.revision == 0:
            return []
        last_battery = rec.battery_last["stamp_ns"] if rec.battery_last else None
        key = (rec.revision, rec.boot_samples, last_battery)
        if key == self._record_sent:
            return []
        changed = self._record_sent is None or rec.revision != self._record_sent[0]
        age = now - self._t_record_sent
        if not (force or (changed and age >= RECORD_MIN_PERIOD_S) or age >= RECORD_REFRESH_S):
            return []
        self._record_sent, self._t_record_sent = key, now
        return [
            ("vehicle_record", messages.vehicle_record_msg(self.f, rec.summary(), self.clock_kind))
        ]

    def _mavros_out(self, out: MavrosOutput, now: float) -> Output:
        assert self.mavros is not None
        frame = self.mavros.config.odom_frame_id
        pubs: Output = [
            ("cmd_vel", cmd_vel_msg(self.f, round(sp.t * 1e9), sp, frame)) for sp in out.setpoints
        ]
        if out.events:
            pubs += self.status(now, out.events)
        return pubs

    def status(self, now: float, events: Sequence[Any] = ()) -> Output:
        """The ``status`` array: the core's values; level and message of the last warn/error
        event (else OK and the core state); every event is logged."""
        values = self.core.status(now)
        if self.mavros_link is not None:
            values.update(self.mavros_link.status(now))
        level, message = "OK", self.core.state.value
        for ev in events:
            lv = getattr(ev, "level", None) or (
                "info" if getattr(ev, "kind", "") in ("link_up", "px4_failsafe_end") else "warn"
            )
            text = getattr(ev, "reason", None) or f"{ev.kind}: {ev.detail}"
            self._log.append((lv, text))
            if lv in ("warn", "error"):
                level = "ERROR" if lv == "error" or level == "ERROR" else "WARN"
                message = text
        st = messages.diagnostic_status(self.f, level, self.name, message, values)
        return [("status", messages.diagnostic_array(self.f, round(now * 1e9), [st]))]

    # -- orderly shutdown -----------------------------------------------------------------
    def shutdown(self, now: float) -> Output:
        """Hand control back (once); the poll timer keeps running until PX4's HEARTBEAT
        confirms the hand-back mode (or the chain fails)."""
        if self._shutting_down:
            return []
        self._shutting_down = True
        out = self.status(now, self.core.shutdown(now)) + self._drain(now)
        return out + self.record_output(now, force=True)

    def shutdown_complete(self) -> bool:
        return self.core.state.value in SHUTDOWN_DONE

    def shutdown_state(self, now: float) -> str:
        return f"hand-back {self.core.state.value}: {self.core.status(now).get('reason', '')}"

    def close(self) -> None:
        self.core.close()
