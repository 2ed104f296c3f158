"""mavlink_bridge_node: ROS topics <-> PX4 over MAVLink (offboard), with safe hand-back.

Shell around :class:`lpv_sysid.mavlink.bridge.BridgeCore`. A timer at ``poll_rate_hz``
polls the link: decoded telemetry is published on ``state`` (Odometry), ``imu`` and
``rotor_speeds`` (best effort); link and offboard events and the core's status go to
``status``. ``velocity_reference`` (phase 1, ``command: velocity``) or
``actuator_command`` (phase 2, ``command: attitude_rate``) are forwarded as setpoints.
When commands stop for ``offboard.input_timeout`` s (e.g. the controller aborted), or on
the ``abort`` service, or on shutdown, the core hands control back to PX4
(``offboard.handback_mode``). Services ``start`` / ``abort`` (std_srvs/Trigger).

``transport: mavros`` (vehicles already running MAVROS): no MAVLink link; the shell wraps
:class:`lpv_sysid.mavlink.mavros.MavrosCore` instead, republishes
``/mavros/local_position/odom`` and ``/mavros/imu/data`` (best effort) on ``state`` / ``imu``
and streams ``velocity_reference`` rotated to local ENU on
``/mavros/setpoint_velocity/cmd_vel`` (reliable). Mode switching and arming need
mavros_msgs and are left to the operator; a stop ends the stream (PX4's offboard-loss
failsafe takes over). See docs/px4_transport.md, "MAVROS mode".

    ros2 run lpv_sysid mavlink_bridge_node --ros-args \
        --params-file config/mavlink_bridge_node.yaml -p link.url:=udpin:0.0.0.0:14540
"""

from __future__ import annotations

from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, JointState
from std_srvs.srv import Trigger

from lpv_sysid.errors import LpvSysidError
from lpv_sysid.io import messages
from lpv_sysid.mavlink.bridge import BridgeConfig, BridgeCore
from lpv_sysid.mavlink.mavros import (
    DIAGNOSTICS_TOPIC,
    MODE_CONTROL,
    MavrosConfig,
    MavrosCore,
    cmd_vel_msg,
)
from lpv_sysid.mavlink.telemetry import ImuSample, RotorSample, StateSample
from lpv_sysid.nodes import shell
from lpv_sysid.nodes import parameters

NODE_NAME = "mavlink_bridge"
TRANSPORTS = ("mavlink", "mavros")

#: MavrosConfig fields supplied by the bridge's own parameters (one value for both transports)
MAVROS_SHARED = {
    "setpoint_rate_hz": "offboard.setpoint_rate_hz",
    "input_timeout": "offboard.input_timeout",
    "send_on_command": "offboard.send_on_command",
    "telemetry_max_age": "telemetry_max_age",
    "auto_start": "auto_start",
    "command": "command",
}


@dataclass(frozen=True)
class BridgeNodeSettings(parameters.Settings):
    """The parameters of the shell itself (the rest: :data:`PARAMETERS`)."""

    WHERE = "mavlink_bridge"

    transport: str = parameters.text(
        "mavlink",
        "mavlink (own MAVLink link to PX4) | mavros (MAVROS topics, docs/px4_transport.md)",
    )
    poll_rate_hz: float = parameters.double(250.0, "link poll rate [Hz]", 10.0, 2000.0)
    status_rate_hz: float = parameters.double(2.0, "status publication rate [Hz]", 0.1, 100.0)

    def validate(self) -> None:
        if self.transport not in TRANSPORTS:
            self.fail(f"transport must be 'mavlink' or 'mavros', got {self.transport!r}")


#: descriptions of the parameters generated from BridgeConfig (config/mavlink_bridge.yaml
#: explains each section); types, defaults and checks are BridgeConfig's
BRIDGE_DESCRIPTIONS = {
    "link.url": "pymavlink connection string (udpin:H:P, udpout:H:P, tcp:H:P, serial device)",
    "link.baud": "serial baud rate (serial URLs only)",
    "link.source_system": "our MAVLink system id (1..255)",
    "link.source_component": "our component id (191: onboard computer)",
    "link.target_system": "autopilot system id (0: the first autopilot HEARTBEAT)",
    "link.target_component": "autopilot component id",
    "link.dialect": "MAVLink dialect (PX4: development)",
    "link.heartbeat_period": "our HEARTBEAT period [s]",
    "link.link_timeout": "no autopilot HEARTBEAT for this long -> link lost [s]",
    "link.reconnect_period": "reopen period of a lost serial/TCP link [s]",
    "link.stream_request_period": "SET_MESSAGE_INTERVAL retry period for missing streams [s]",
    "link.streams": "requested telemetry rate [Hz] (0: off)",
    "link.signing_key_file": "MAVLink 2 signing key file (32 raw bytes or 64 hex chars); "
    "empty: unsigned",
    "link.signing_link_id": "signing link id",
    "link.allow_unsigned": "with a signing key: still accept unsigned messages",
    "offboard.setpoint_rate_hz": "setpoint stream rate [Hz] (PX4 needs > 2 Hz)",
    "offboard.prestream_time": "setpoints before OFFBOARD is requested [s] (PX4 needs > 1 s)",
    "offboard.arm": "arm the vehicle on start",
    "offboard.handback_chain": "PX4 modes tried in turn on hand-back until the HEARTBEAT "
    "confirms one (HOLD, POSCTL, ALTCTL, LAND, RTL)",
    "offboard.handback_mode": "tried before the chain (single-mode key of earlier releases); "
    "empty: the chain alone",
    "offboard.input_timeout": "no command for this long -> hand back [s]",
    "offboard.ack_timeout": "per attempt, for a COMMAND_ACK [s]",
    "offboard.ack_settle_s": "quiet time after the last ACK before a step counts [s]",
    "offboard.max_retries": "command retries per step",
    "offboard.mode_confirm_timeout": "after ACCEPTED, for the HEARTBEAT to show the mode [s]",
    "offboard.send_on_command": "forward each new command at once (latency)",
    "command": "velocity (phase 1) | attitude_rate (phase 2)",
    "velocity_frame": "velocity setpoint frame: body_ned (PX4 rotates by yaw) | local_ned",
    "use_yaw_rate": "velocity setpoints carry the yaw-rate reference",
    "arm_length": "attitude_rate: seed 0 Eq. (7) geometry [m]",
    "rate_p": "attitude_rate: PX4 MC_ROLLRATE_P, MC_PITCHRATE_P, MC_YAWRATE_P",
    "auto_start": "start offboard on the first command",
    "telemetry_max_age": "attitude/velocity older than this is not fused [s]",
    "n_rotors": "number of rotors (ESC_STATUS / motor outputs)",
    "rotor_estimate.enabled": "estimate rotor speeds from motor outputs while no fresh ESC "
    "telemetry (seed 0 Eq. 8)",
    "rotor_estimate.source": "auto | actuator_output_status | servo_output_raw",
    "rotor_estimate.mapping": "motor output -> u_ESC: pwm | dshot | normalized | symmetric",
    "rotor_estimate.output_min": "override of the mapping's output range (NaN: the mapping's)",
    "rotor_estimate.output_max": "override of the mapping's output range (NaN: the mapping's)",
    "rotor_estimate.motor_outputs": "output channel (1-based) of rotor 1..n",
    "rotor_estimate.servo_port": "SERVO_OUTPUT_RAW port of the motors",
    "rotor_estimate.airframe": "YAML with a quadrotor section (empty: built-in airframe)",
    "rotor_estimate.a_omega": "motor time constant inverse [1/s] (NaN: the airframe's)",
    "rotor_estimate.b_omega": "motor gain [rad/s^2 per unit u_ESC] (NaN: the airframe's)",
    "rotor_estimate.omega_min": "idle rotor speed [rad/s] (NaN: the airframe's)",
    "rotor_estimate.omega_max": "maximum rotor speed [rad/s] (NaN: the airframe's)",
    "rotor_estimate.max_gap": "longer gaps between output samples restart the estimate [s]",
    "rotor_estimate.esc_timeout": "ESC telemetry older than this -> the estimate is used [s]",
    "envelope.enabled": "onboard safety envelope (violation -> hand-back)",
    "envelope.home": "auto | home_position | start",
    "envelope.floor": "floor above home [m]",
    "envelope.ceiling": "ceiling above home [m]",
    "envelope.floor_arm_margin": "the floor is active once above floor + margin [m]",
    "envelope.lookahead": "predictive floor/ceiling/fence on p + v * lookahead [s]",
    "envelope.radius": "horizontal geofence around home [m]",
    "envelope.max_tilt_deg": "largest tilt [deg]",
    "envelope.max_speed": "largest NED speed [m/s]",
    "envelope.max_setpoint": "velocity references above this are rejected [m/s]",
    "envelope.max_setpoint_yaw_rate": "yaw-rate references above this are rejected [rad/s]",
}
#: not a parameter: the MAV_TYPE of our HEARTBEAT identifies this program (onboard controller)
BRIDGE_EXCLUDED = ("link.mav_type",)

MAVROS_DESCRIPTIONS = {
    "mavros.namespace": "MAVROS node namespace (transport mavros)",
    "mavros.odom_frame_id": "frame_id of MAVROS local_position/odom",
    "mavros.base_frame_id": "MAVROS body frame (odom child, imu)",
    "mavros.prestream_timeout": "zero-velocity stream without a reference -> stop [s]",
    "mavros.use_diagnostics": "read the PX4 mode from /diagnostics (read-only)",
}

#: the rclpy declarations: the shell's settings, then BridgeConfig's and MavrosConfig's
#: fields (generated; nothing restated)
SPECS = {
    **parameters.specs(BridgeNodeSettings),
    **parameters.config_specs(BridgeConfig, BRIDGE_DESCRIPTIONS, exclude=BRIDGE_EXCLUDED),
    **parameters.config_specs(
        MavrosConfig,
        MAVROS_DESCRIPTIONS,
        prefix="mavros.",
        exclude=tuple(f"mavros.{k}" for k in MAVROS_SHARED),
    ),
}
PARAMETERS = shell.spec_table(SPECS)


def _split(p: dict) -> tuple[dict, dict, dict]:
    """Declared values -> (shell settings, BridgeConfig mapping, MavrosConfig mapping)."""
    own = {k: p[k] for k in parameters.specs(BridgeNodeSettings)}
    mavros = {k.split(".", 1)[1]: v for k, v in p.items() if k.startswith("mavros.")}
    mavros.update({k: p[v] for k, v in MAVROS_SHARED.items()})
    bridge = parameters.nest(
        {k: v for k, v in p.items() if k not in own and not k.startswith("mavros.")}, SPECS
    )
    return own, bridge, parameters.nest(mavros)


def handback_bound_s(offboard) -> float:
    """Longest a hand-back can take (the orderly-shutdown bound of the bridge), from the
    truth rules of mavlink/offboard.py: each mode of the chain gets ``max_retries + 1``
    DO_SET_MODE attempts of ``ack_timeout`` and, once ACCEPTED, ``mode_confirm_timeout``
    for the HEARTBEAT; plus one poll-and-heartbeat period of slack."""
    per_mode = (offboard.max_retries + 1) * offboard.ack_timeout + offboard.mode_confirm_timeout
    return round(len(offboard.chain) * per_mode + 1.0, 3)


class MavlinkBridgeNode(shell.ShellNode):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        p = self.params
        own, bridge, mavros = _split(p)
        self.settings = s = BridgeNodeSettings.from_dict(own)
        self.mavros = s.transport == "mavros"
        self.core = (
            MavrosCore(MavrosConfig.from_dict(mavros))
            if self.mavros
            else BridgeCore(BridgeConfig.from_dict(bridge))
        )
        self.f = messages.MsgFactory.rclpy()
        self.pub_state = self.create_publisher(Odometry, "state", shell.qos_for("state"))
        self.pub_imu = self.create_publisher(Imu, "imu", shell.qos_for("imu"))
        self.pub_status = shell.StatusPublisher(self)  # status and /diagnostics
        self.create_subscription(
            TwistStamped,
            "velocity_reference",
            self.on_reference,
            shell.qos_for("velocity_reference"),
        )
        self.create_service(Trigger, "~/start", self.on_start)
        self.create_service(Trigger, "~/abort", self.on_abort)
        if self.mavros:
            cfg = self.core.config
            self.pub_cmd = self.create_publisher(
                TwistStamped, cfg.topic("cmd_vel"), shell.QOS_RELIABLE
            )
            self.create_subscription(
                Odometry, cfg.topic("odom"), self.on_mavros_odom, shell.QOS_SENSOR
            )
            self.create_subscription(Imu, cfg.topic("imu"), self.on_mavros_imu, shell.QOS_SENSOR)
            if cfg.use_diagnostics:
                self.create_subscription(
                    DiagnosticArray,
                    DIAGNOSTICS_TOPIC,
                    self.on_mavros_diagnostics,
                    shell.QOS_SENSOR,
                )
            # twice the setpoint rate: the core sends when due; stale input is seen within
            # half a setpoint period
            self.create_timer(
                0.5 / cfg.setpoint_rate_hz, lambda: self.publish_mavros(self.core.step(self.now()))
            )
            self.get_logger().info(
                f"MAVROS {cfg.namespace}: setpoints on {cfg.topic('cmd_vel')}; "
                f"mode control: {MODE_CONTROL}"
            )
        else:
            self.pub_rot = self.create_publisher(
                JointState, "rotor_speeds", shell.qos_for("rotor_speeds")
            )
            self.create_subscription(
                JointState, "actuator_command", self.on_command, shell.qos_for("actuator_command")
            )
            self.core.open(self.now())
            self.create_timer(1.0 / s.poll_rate_hz, self.on_poll)
            self.SHUTDOWN_TIMEOUT_S = handback_bound_s(self.core.config.offboard)
            self.get_logger().info(
                f"MAVLink {self.core.config.link.url}, "
                f"command {self.core.config.command}; hand-back chain "
                f"{list(self.core.config.offboard.handback_chain)} within "
                f"{self.SHUTDOWN_TIMEOUT_S:g} s"
            )
            budget = shell.LAUNCH_SIGTERM_TIMEOUT_S - shell.TEARDOWN_MARGIN_S
            if self.SHUTDOWN_TIMEOUT_S > budget:
                self.get_logger().warning(
                    f"the hand-back chain may need {self.SHUTDOWN_TIMEOUT_S:g} s, more than the "
                    f"{budget:g} s a launch Ctrl-C leaves before SIGTERM: launch with "
                    f"sigterm_timeout:={self.SHUTDOWN_TIMEOUT_S + shell.TEARDOWN_MARGIN_S:g}"
                )
        self.create_timer(1.0 / s.status_rate_hz, lambda: self.publish_status([]))

    # -- inputs -------------------------------------------------------------------------
    def on_reference(self, msg):
        parsed = self.parse_input("velocity_reference", messages.reference_from_twist, msg)
        if parsed is None:
            return
        t, v, r = parsed
        out = self.core.on_velocity_reference(self.now(), v, r, stamp=t)
        if self.mavros:
            self.publish_mavros(out)

    # -- MAVROS mode (transport: mavros) ----------------------------------------------------
    def on_mavros_odom(self, msg):
        cfg = self.core.config
        try:
            s = messages.state_from_odometry(
                msg, frame_id=cfg.odom_frame_id, child_frame_id=cfg.base_frame_id
            )
        except LpvSysidError as exc:
            return self.core.reject(self.now(), f"{cfg.topic('odom')} rejected: {exc}")
        s = self.core.on_odometry(self.now(), s)
        if s is not None:
            self.pub_state.publish(
                messages.odometry_from_state(
                    self.f, s.stamp_ns, s.pos_ned, s.euler, s.v_body, s.omega
                )
            )

    def on_mavros_imu(self, msg):
        try:
            s = messages.imu_from_msg(msg, frame_id=self.core.config.base_frame_id)
        except LpvSysidError as exc:
            return self.core.reject(self.now(), f"{self.core.config.topic('imu')} rejected: {exc}")
        s = self.core.on_imu(self.now(), s)
        if s is not None:
            self.pub_imu.publish(
                messages.imu_msg(self.f, s.stamp_ns, s.specific_force, s.omega, s.euler)
            )

    def on_mavros_diagnostics(self, msg):
        try:
            _, statuses = messages.status_from_diagnostic_array(msg)
        except LpvSysidError:
            return  # other nodes' diagnostics are not ours to judge
        self.core.on_diagnostics(self.now(), statuses)

    def publish_mavros(self, out):
        for sp in out.setpoints:
            self.pub_cmd.publish(
                cmd_vel_msg(self.f, round(sp.t * 1e9), sp, self.core.config.odom_frame_id)
            )
        if out.events:
            self.publish_status(out.events)

    def on_command(self, msg):
        parsed = self.parse_input(
            "actuator_command", messages.actuator_command_from_joint_state, msg
        )
        if parsed is not None:
            self.core.on_actuator_command(self.now(), parsed[1], stamp=parsed[0])

    def on_start(self, request, response):
        events = self.core.start(self.now())
        response.success = True
        response.message = f"offboard: {self.core.state.value}"
        self.publish_status(events)
        return response

    def on_abort(self, request, response):
        events = self.core.abort(self.now(), "abort service")
        response.success = True
        response.message = f"handing control back to PX4: {self.core.state.value}"
        self.publish_status(events)
        return response

    # -- loop ---------------------------------------------------------------------------
    def on_poll(self):
        out = self.core.poll(self.now())
        f = self.f
        for s in out.samples:
            stamp = round(s.t * 1e9)
            if isinstance(s, StateSample):
                self.pub_state.publish(
                    messages.odometry_from_state(f, stamp, s.pos_ned, s.euler, s.v_body, s.omega)
                )
            elif isinstance(s, ImuSample):
                self.pub_imu.publish(messages.imu_msg(f, stamp, s.accel_frd, s.gyro_frd))
            elif isinstance(s, RotorSample):
                self.pub_rot.publish(messages.rotor_speeds_msg(f, stamp, s.omega, s.source))
        if out.events:
            self.publish_status(out.events)

    def publish_status(self, events):
        now = self.now()
        values = self.core.status(now)
        level, message = "OK", self.core.state.value
        for ev in events:
            lv = getattr(ev, "level", "warn" if getattr(ev, "kind", "") != "link_up" else "info")
            text = getattr(ev, "reason", None) or f"{ev.kind}: {ev.detail}"
            # one call site per severity: rclpy keys a log context on the calling line and
            # raises "Logger severity cannot be changed between calls" otherwise
            if lv == "info":
                self.get_logger().info(text)
            elif lv == "error":
                self.get_logger().error(text)
            else:
                self.get_logger().warning(text)
            if lv in ("warn", "error"):
                level = "ERROR" if lv == "error" or level == "ERROR" else "WARN"
                message = text
        st = messages.diagnostic_status(
            self.f, level, self.get_fully_qualified_name(), message, values
        )
        self.pub_status.publish(messages.diagnostic_array(self.f, round(now * 1e9), [st]))

    # -- orderly shutdown (nodes/shell.run) ----------------------------------------
    def begin_shutdown(self):
        """Hand control back while the context is valid; the poll timer keeps running
        until PX4's HEARTBEAT confirms the hand-back mode (or the chain fails)."""
        self._shutting_down = True
        self.publish_status(self.core.shutdown(self.now()))

    def shutdown_complete(self):
        return self.core.state.value in ("IDLE", "DONE", "FAILED")

    def shutdown_state(self):
        return (
            f"hand-back {self.core.state.value}: {self.core.status(self.now()).get('reason', '')}"
        )

    def destroy_node(self):
        try:
            if not getattr(self, "_shutting_down", False) and self.context_ok():
                self.publish_status(self.core.shutdown(self.now()))  # destroyed without run()
        finally:
            self.core.close()
            super().destroy_node()


def main(args=None):
    return shell.run(MavlinkBridgeNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
