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

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, JointState
from std_srvs.srv import Trigger

from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.io import messages as M
from lpv_sysid.mavlink import mavros as MR
from lpv_sysid.mavlink.bridge import BridgeConfig, BridgeCore
from lpv_sysid.mavlink.telemetry import ImuSample, RotorSample, StateSample
from lpv_sysid.nodes import _common as C

NODE_NAME = "mavlink_bridge"
S = Parameter.Type.STRING

PARAMETERS = [
    ("transport", "mavlink", C.typed(S, "mavlink (own MAVLink link) | mavros (MAVROS topics)")),
    ("mavros.namespace", "/mavros", C.typed(S, "MAVROS node namespace (transport mavros)")),
    ("mavros.odom_frame_id", "map", C.typed(S, "frame_id of MAVROS local_position/odom")),
    ("mavros.base_frame_id", "base_link", C.typed(S, "MAVROS body frame (odom child, imu)")),
    ("mavros.prestream_timeout", 30.0, C.double("zero-velocity stream without a reference "
                                                "-> stop [s]", 1.0001, 3600.0)),
    ("mavros.use_diagnostics", True, C.typed(Parameter.Type.BOOL,
                                             "read the PX4 mode from /diagnostics (read-only)")),
    ("link.url", "udpin:127.0.0.1:14540", C.typed(S, "pymavlink connection string")),
    ("link.baud", 921600, C.integer("serial baud rate (serial URLs only)", 1200, 12000000)),
    ("link.source_system", 1, C.integer("our MAVLink system id", 1, 255)),
    ("link.source_component", 191, C.integer("our component id (191: onboard computer)",
                                             1, 255)),
    ("link.target_system", 0, C.integer("autopilot system id (0: first heartbeat)", 0, 255)),
    ("link.heartbeat_period", 1.0, C.double("heartbeat period [s]", 0.05, 10.0)),
    ("link.link_timeout", 1.5, C.double("no heartbeat for this long -> link lost [s]",
                                        0.1, 60.0)),
    ("offboard.setpoint_rate_hz", 20.0, C.double("setpoint stream rate [Hz] (PX4 > 2 Hz)",
                                                 2.0001, 1000.0)),
    ("offboard.prestream_time", 1.2, C.double("setpoints before OFFBOARD [s] (PX4 > 1 s)",
                                              1.0001, 60.0)),
    ("offboard.arm", False, C.typed(Parameter.Type.BOOL, "arm the vehicle on start")),
    ("offboard.handback_mode", "HOLD", C.typed(S, "PX4 mode on hand-back: HOLD|POSCTL|LAND")),
    ("offboard.input_timeout", 0.5, C.double("no command for this long -> hand back [s]",
                                             0.01, 60.0)),
    ("command", "velocity", C.typed(S, "velocity (phase 1) | attitude_rate (phase 2)")),
    ("velocity_frame", "body_ned", C.typed(S, "velocity setpoint frame: body_ned|local_ned")),
    ("auto_start", False, C.typed(Parameter.Type.BOOL, "start offboard on the first command")),
    ("telemetry_max_age", 0.5, C.double("attitude/velocity older than this is not fused [s]",
                                        0.01, 10.0)),
    ("poll_rate_hz", 250.0, C.double("link poll rate [Hz]", 10.0, 2000.0)),
    ("status_rate_hz", 2.0, C.double("status publication rate [Hz]", 0.1, 100.0)),
]


def bridge_config(p: dict) -> BridgeConfig:
    link = {k.split(".", 1)[1]: v for k, v in p.items() if k.startswith("link.")}
    offboard = {k.split(".", 1)[1]: v for k, v in p.items() if k.startswith("offboard.")}
    return BridgeConfig.from_dict({"link": link, "offboard": offboard, "command": p["command"],
                                   "velocity_frame": p["velocity_frame"],
                                   "auto_start": p["auto_start"],
                                   "telemetry_max_age": p["telemetry_max_age"]})


def mavros_config(p: dict) -> MR.MavrosConfig:
    d = {k.split(".", 1)[1]: v for k, v in p.items() if k.startswith("mavros.")}
    return MR.MavrosConfig.from_dict({**d, "setpoint_rate_hz": p["offboard.setpoint_rate_hz"],
                                      "input_timeout": p["offboard.input_timeout"],
                                      "telemetry_max_age": p["telemetry_max_age"],
                                      "auto_start": p["auto_start"], "command": p["command"]})


class MavlinkBridgeNode(C.ShellNode):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        p = self.params
        if p["transport"] not in ("mavlink", "mavros"):
            raise ConfigError(f"transport must be 'mavlink' or 'mavros', got {p['transport']!r}")
        self.mavros = p["transport"] == "mavros"
        self.core = MR.MavrosCore(mavros_config(p)) if self.mavros else BridgeCore(bridge_config(p))
        self.f = M.MsgFactory.rclpy()
        self.pub_state = self.create_publisher(Odometry, "state", C.qos_for("state"))
        self.pub_imu = self.create_publisher(Imu, "imu", C.qos_for("imu"))
        self.pub_status = self.create_publisher(DiagnosticArray, "status", C.qos_for("status"))
        self.create_subscription(TwistStamped, "velocity_reference", self.on_reference,
                                 C.qos_for("velocity_reference"))
        self.create_service(Trigger, "~/start", self.on_start)
        self.create_service(Trigger, "~/abort", self.on_abort)
        if self.mavros:
            cfg = self.core.config
            self.pub_cmd = self.create_publisher(TwistStamped, cfg.topic("cmd_vel"), C.QOS_RELIABLE)
            self.create_subscription(Odometry, cfg.topic("odom"), self.on_mavros_odom, C.QOS_SENSOR)
            self.create_subscription(Imu, cfg.topic("imu"), self.on_mavros_imu, C.QOS_SENSOR)
            if cfg.use_diagnostics:
                self.create_subscription(DiagnosticArray, MR.DIAGNOSTICS_TOPIC,
                                         self.on_mavros_diagnostics, C.QOS_SENSOR)
            # twice the setpoint rate: the core sends when due; stale input is seen within
            # half a setpoint period
            self.create_timer(0.5 / cfg.setpoint_rate_hz,
                              lambda: self.publish_mavros(self.core.step(self.now())))
            self.get_logger().info(f"MAVROS {cfg.namespace}: setpoints on {cfg.topic('cmd_vel')}; "
                                   f"mode control: {MR.MODE_CONTROL}")
        else:
            self.pub_rot = self.create_publisher(JointState, "rotor_speeds",
                                                 C.qos_for("rotor_speeds"))
            self.create_subscription(JointState, "actuator_command", self.on_command,
                                     C.qos_for("actuator_command"))
            self.core.open(self.now())
            self.create_timer(1.0 / p["poll_rate_hz"], self.on_poll)
            self.get_logger().info(f"MAVLink {p['link.url']}, command {p['command']}")
        self.create_timer(1.0 / p["status_rate_hz"], lambda: self.publish_status([]))

    # -- inputs -------------------------------------------------------------------------
    def on_reference(self, msg):
        parsed = self.parse_input("velocity_reference", M.reference_from_twist, msg)
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
            s = M.state_from_odometry(msg, frame_id=cfg.odom_frame_id,
                                      child_frame_id=cfg.base_frame_id)
        except LpvSysidError as exc:
            return self.core.reject(self.now(), f"{cfg.topic('odom')} rejected: {exc}")
        s = self.core.on_odometry(self.now(), s)
        if s is not None:
            self.pub_state.publish(M.odometry_from_state(self.f, s.stamp_ns, s.pos_ned, s.euler,
                                                         s.v_body, s.omega))

    def on_mavros_imu(self, msg):
        try:
            s = M.imu_from_msg(msg, frame_id=self.core.config.base_frame_id)
        except LpvSysidError as exc:
            return self.core.reject(self.now(), f"{self.core.config.topic('imu')} rejected: {exc}")
        s = self.core.on_imu(self.now(), s)
        if s is not None:
            self.pub_imu.publish(M.imu_msg(self.f, s.stamp_ns, s.specific_force, s.omega, s.euler))

    def on_mavros_diagnostics(self, msg):
        try:
            _, statuses = M.status_from_diagnostic_array(msg)
        except LpvSysidError:
            return                       # other nodes' diagnostics are not ours to judge
        self.core.on_diagnostics(self.now(), statuses)

    def publish_mavros(self, out):
        for sp in out.setpoints:
            self.pub_cmd.publish(MR.cmd_vel_msg(self.f, round(sp.t * 1e9), sp,
                                                self.core.config.odom_frame_id))
        if out.events:
            self.publish_status(out.events)

    def on_command(self, msg):
        parsed = self.parse_input("actuator_command", M.actuator_command_from_joint_state, msg)
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
                self.pub_state.publish(M.odometry_from_state(f, stamp, s.pos_ned, s.euler,
                                                             s.v_body, s.omega))
            elif isinstance(s, ImuSample):
                self.pub_imu.publish(M.imu_msg(f, stamp, s.accel_frd, s.gyro_frd))
            elif isinstance(s, RotorSample):
                self.pub_rot.publish(M.rotor_speeds_msg(f, stamp, s.omega, s.source))
        if out.events:
            self.publish_status(out.events)

    def publish_status(self, events):
        now = self.now()
        values = self.core.status(now)
        level, message = "OK", self.core.state.value
        for ev in events:
            lv = getattr(ev, "level", "warn" if getattr(ev, "kind", "") != "link_up" else "info")
            text = getattr(ev, "reason", None) or f"{ev.kind}: {ev.detail}"
            log = {"info": self.get_logger().info, "warn": self.get_logger().warning,
                   "error": self.get_logger().error}.get(lv, self.get_logger().warning)
            log(text)
            if lv in ("warn", "error"):
                level = "ERROR" if lv == "error" or level == "ERROR" else "WARN"
                message = text
        st = M.diagnostic_status(self.f, level, self.get_fully_qualified_name(), message, values)
        self.pub_status.publish(M.diagnostic_array(self.f, round(now * 1e9), [st]))

    # -- orderly shutdown (nodes/_common.run) ----------------------------------------
    def begin_shutdown(self):
        """Hand control back while the context is valid; the poll timer keeps running
        until PX4's HEARTBEAT confirms the hand-back mode (or the chain fails)."""
        self._shutting_down = True
        self.publish_status(self.core.shutdown(self.now()))

    def shutdown_complete(self):
        return self.core.state.value in ("IDLE", "DONE", "FAILED")

    def shutdown_state(self):
        return f"hand-back {self.core.state.value}: {self.core.status(self.now()).get('reason', '')}"

    def destroy_node(self):
        try:
            if not getattr(self, "_shutting_down", False) and self.context_ok():
                self.publish_status(self.core.shutdown(self.now()))   # destroyed without run()
        finally:
            self.core.close()
            super().destroy_node()


def main(args=None):
    return C.run(MavlinkBridgeNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
