"""mavlink_bridge_node: ROS topics <-> PX4 over MAVLink (offboard), with safe hand-back.

Shell around :class:`lpv_sysid.flight.bridge.runtime.BridgeRuntime` (which wraps
:class:`lpv_sysid.mavlink.bridge.BridgeCore`). A timer at ``poll_rate_hz`` polls the link:
decoded telemetry is published on ``state`` (Odometry), ``imu`` and ``rotor_speeds`` (best
effort); link and offboard events and the core's status go to ``status``; the vehicle
record (firmware, PX4 parameters, battery, site, PX4's boot on the node clock) on
``vehicle_record`` (std_msgs/String, JSON; reliable, transient local) when it changes
materially -- the data logger's ``experiment.yaml`` ``vehicle`` (through MAVROS: what
MAVROS offers, no PX4 boot time; :mod:`lpv_sysid.flight.bridge.runtime`).
``velocity_reference`` (phase 1, ``command: velocity``) or ``actuator_command`` (phase 2,
``command: attitude_rate``) are forwarded as setpoints. When commands stop for
``offboard.input_timeout`` s (e.g. the controller aborted), or on the ``abort`` service, or
on shutdown, the core hands control back to PX4 (``offboard.handback_mode``). Services
``start`` / ``abort`` (std_srvs/Trigger). Parameters: :mod:`lpv_sysid.flight.bridge.settings`.

``transport: mavros`` (vehicles already running MAVROS): no MAVLink link. With
``mavros.interfaces`` ``mavros_msgs`` (``auto``: when mavros_msgs can be loaded) the runtime
runs the same BridgeCore over :class:`lpv_sysid.mavlink.bridge.MavrosLink`: ``/mavros/state``
is the mode evidence, ``/mavros/set_mode`` and ``/mavros/cmd/arming`` are called through
:class:`ServiceCaller`, setpoints go to ``/mavros/setpoint_raw/local`` (velocity) or
``/mavros/setpoint_raw/attitude`` (rates + thrust), rotor speeds come from
``/mavros/esc_status/status`` or ``/mavros/rc/out``. With ``common`` it wraps
:class:`lpv_sysid.mavlink.bridge.mavros.MavrosCore` instead, republishes
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
from rosidl_runtime_py.utilities import get_message, get_service
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from lpv_sysid.flight.bridge import SPECS, BridgeRuntime, settings_from_params
from lpv_sysid.io import messages
from lpv_sysid.nodes import shell
from lpv_sysid.nodes.lean_executor import HIGH_RATE_EXECUTOR

NODE_NAME = "mavlink_bridge"
#: the rclpy declarations, generated from the one declaration (bridge_settings.SPECS)
PARAMETERS = shell.spec_table(SPECS)

#: message type of each endpoint key of the runtime
TYPES = {
    "state": Odometry,
    "imu": Imu,
    "rotor_speeds": JointState,
    "cmd_vel": TwistStamped,
    "velocity_reference": TwistStamped,
    "actuator_command": JointState,
    "rate_setpoint": JointState,
    "mavros_odom": Odometry,
    "mavros_imu": Imu,
    "mavros_diagnostics": DiagnosticArray,
    "vehicle_record": String,
}
QOS = {
    "sensor": shell.QOS_SENSOR,
    "reliable": shell.QOS_RELIABLE,
    "record": shell.QOS_VEHICLE_RECORD,
}


def type_of(endpoint):
    """An endpoint's type: mavros_msgs by name (loaded only in MAVROS mode), else TYPES."""
    name = endpoint.typename
    if not name:
        return TYPES[endpoint.key]
    return get_service(name) if "/srv/" in name else get_message(name)


class ServiceCaller:
    """A MAVROS service as an output key: ``publish(ServiceRequest)`` calls it
    asynchronously and hands the answer (None when the call failed) to the runtime."""

    def __init__(self, node, srv_type, name):
        self.node, self.srv_type = node, srv_type
        self.client = node.create_client(srv_type, name)

    def publish(self, req):
        future = self.client.call_async(self.srv_type.Request(**req.fields))
        node = self.node

        def done(fut):
            try:
                response = fut.result()
            except Exception:  # noqa: BLE001 -- any failure of the call: no answer
                response = None
            node.emit(node.runtime.on_service_answer(req, response, node.now()))

        future.add_done_callback(done)


def qos_of(endpoint):
    """An endpoint's QoS: its own, else the package topic table's."""
    return QOS[endpoint.qos] if endpoint.qos else shell.qos_for(endpoint.topic)


class MavlinkBridgeNode(shell.ShellNode):
    #: the 250 Hz link poll and the 250 Hz actuator_command: under rclpy's executor the
    #: bridge's wakes cost as the controller's did (issue 27), and a late poll stamps a
    #: backlog of MAVLink states with one time (measured in the real phase-2 graph: 10+
    #: states per stamp, up to 250 ms late at the controller)
    EXECUTOR = HIGH_RATE_EXECUTOR

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        self.runtime = rt = BridgeRuntime(
            self.params,
            messages.MsgFactory.rclpy(),
            self.get_fully_qualified_name(),
            shell.LAUNCH_SIGTERM_TIMEOUT_S,
            shell.TEARDOWN_MARGIN_S,
        )
        self.core = rt.core
        if rt.settings.publish_tf:
            self.enable_tf()
        self.pub: dict = {"status": shell.StatusPublisher(self)}  # status and /diagnostics
        for e in rt.publishers:
            self.pub[e.key] = self.create_publisher(type_of(e), e.topic, qos_of(e))
        for e in rt.subscriptions:
            self.create_subscription(type_of(e), e.topic, self._input(e.key), qos_of(e))
        for e in rt.clients:
            self.pub[e.key] = ServiceCaller(self, type_of(e), e.topic)
        self.create_service(Trigger, "~/start", shell.trigger(self, rt.start, self.emit))
        self.create_service(Trigger, "~/abort", shell.trigger(self, rt.abort, self.emit))
        rt.clock_kind = shell.clock_kind(self)
        rt.open(self.now())
        self.create_timer(rt.timer_period_s, lambda: self.emit(rt.on_timer(self.now())))
        if rt.shutdown_timeout_s is not None:
            self.SHUTDOWN_TIMEOUT_S = rt.shutdown_timeout_s
        self.status_timer(rt.settings.status_rate_hz, lambda: self.emit(rt.status(self.now())))
        self.emit([])

    def settings_from(self, values):
        return settings_from_params(values)

    def _input(self, key):
        parse = self.runtime.parsers.get(key)

        def cb(msg):
            if parse is None:  # a MAVROS message: the runtime judges it
                return self.emit(self.runtime.on_message(key, msg, self.now()))
            parsed = self.parse_input(key, parse, msg)
            if parsed is not None:
                self.emit(self.runtime.on_sample(key, parsed, self.now()))

        return cb

    def emit(self, out):
        """Publish the runtime's ``[(key, message)]``, then log what it queued."""
        for key, msg in out:
            self.pub[key].publish(msg)
            self.publish_tf_of(key, msg)
        shell.log_lines(self.get_logger(), self.runtime.take_log())

    # -- orderly shutdown (nodes/shell.run) ----------------------------------------
    def begin_shutdown(self):
        """Hand control back while the context is valid; the poll timer keeps running
        until PX4's HEARTBEAT confirms the hand-back mode (or the chain fails)."""
        self.emit(self.runtime.shutdown(self.now()))

    def shutdown_complete(self):
        return self.runtime.shutdown_complete()

    def shutdown_state(self):
        return self.runtime.shutdown_state(self.now())

    def destroy_node(self):
        try:
            if self.context_ok():  # destroyed without run(): hand back (once) now
                self.emit(self.runtime.shutdown(self.now()))
        finally:
            self.runtime.close()
            super().destroy_node()


def main(args=None):
    return shell.run(MavlinkBridgeNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
