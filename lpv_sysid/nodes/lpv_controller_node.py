"""lpv_controller_node: the robust LPV velocity controller of phase 2 (seed 0 Sec. VI).

Shell around :class:`lpv_sysid.flight.controller.ControllerRuntime` (the runtime law
of control/law/controller.py + the safety supervisor of control/safety.py). Loads and
validates ``gains_file`` at start and refuses to start on any mismatch, naming the field
(exit status 2): the file must hash to what its certificate certified, the certified
closed loops must be stable and the design envelope present (controller_runtime). Its
parameters are declared once, in ``ControllerSettings``. Subscribes ``state``,
``rotor_speeds`` (best effort), ``velocity_reference`` and ``excitation`` (reliable); after
``start`` publishes ``actuator_command`` at ``rate_hz`` (``tick_source: timer``) or one per
state sample, stamped with it (``tick_source: state``, the lock-stepped sim of
sim.launch.py; with ``lockstep`` a state sample it sends no command on -- not started,
aborted -- is answered on ``lockstep_ack``, so the simulation waits for it before and after
start alike, and ``start`` waits until the simulation receives those answers); ``start``
and ``auto_start`` wait until every input stream has delivered a sample. The core's log
lines (the safety abort among them) go to this node's logger.
On a fault it publishes the abort on ``status`` and stops commanding, so the bridge hands
control back to PX4. Services ``start`` / ``abort`` (std_srvs/Trigger). Spun by
:class:`lpv_sysid.nodes.lean_executor.LeanExecutor` under a real rclpy (issue 27: rclpy's
executor cost per wake dominated the node's CPU).

    ros2 run lpv_sysid lpv_controller_node --ros-args \
        --params-file config/lpv_controller.yaml -p gains_file:=gains.yaml
"""

from __future__ import annotations

from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from lpv_sysid.flight.controller import ControllerRuntime, ControllerSettings, settle_gc
from lpv_sysid.io import messages
from lpv_sysid.nodes import shell
from lpv_sysid.nodes.lean_executor import HIGH_RATE_EXECUTOR

NODE_NAME = "lpv_controller"

#: the rclpy declarations, generated from the one declaration (ControllerSettings)
PARAMETERS = shell.settings_table(ControllerSettings)


class LpvControllerNode(shell.ShellNode):
    SETTINGS = ControllerSettings
    #: ~800 wakes/s in the vehicle configuration: rclpy's executor cost per wake dominated
    #: the node's CPU (issue 27; bench/bench_node_rclpy.py measures both executors)
    EXECUTOR = HIGH_RATE_EXECUTOR

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        self._clock = self.get_clock()  # the node clock, looked up once (now())
        settings = ControllerSettings.from_dict(self.params)
        # one preallocated actuator_command, filled per tick (published before the next one)
        self.runtime = ControllerRuntime(
            settings,
            messages.MsgFactory.rclpy(),
            self.get_fully_qualified_name(),
            reuse_messages=True,
        )

        self.pub = {
            "actuator_command": self.create_publisher(
                JointState, "actuator_command", shell.qos_for("actuator_command")
            ),
            "status": shell.StatusPublisher(self),
        }  # status and /diagnostics
        if settings.lockstep:  # the answer to a state sample without a command (sim only)
            topic = messages.LOCKSTEP_ACK[0]
            self.pub[topic] = self.create_publisher(ClockMsg, topic, shell.qos_for(topic))
        # state (the high-rate input): serialized bytes, only the fields the law needs read
        # (rclpy would build the whole Odometry, 72 covariance doubles included)
        self.create_subscription(
            Odometry, "state", self._on_state_raw, shell.qos_for("state"), raw=True
        )
        for topic, typ in (
            ("rotor_speeds", JointState),
            ("velocity_reference", TwistStamped),
            ("excitation", JointState),
        ):
            self.create_subscription(typ, topic, self._input(topic), shell.qos_for(topic))
        self.create_service(Trigger, "~/start", self.on_start)
        self.create_service(Trigger, "~/abort", self.on_abort)
        # tick_source timer: the law step at rate_hz; state: only the staleness watch
        self.create_timer(settings.timer_period_s, self.on_tick)
        self.status_timer(settings.status_rate_hz, self.publish_status)
        self.get_logger().info(
            f"gains {settings.gains_file}: box "
            f"{self.runtime.schedule.scheduling.to_dict()}, "
            f"gamma {self.runtime.schedule.gamma:g}; {shell.clock_source(self)}"
        )
        self.log_core()
        # auto_start: started by the timer once every input stream has delivered a sample
        self._auto_start = settings.auto_start
        if settings.auto_start:
            self.get_logger().info("auto_start: commanding once every input stream arrives")
        settle_gc()  # loaded: the GC policy of the flying controller (controller_runtime)

    def log_core(self):
        """Log what the core queued, with this node's logger (timestamp, /rosout)."""
        shell.log_lines(self.get_logger(), self.runtime.take_log())

    def now(self) -> float:
        """The node clock [s], read once per callback (the clock object looked up once)."""
        return self._clock.now().nanoseconds * 1e-9

    def _input(self, topic):
        def cb(msg):
            for out, m in self.runtime.on_input(topic, msg, self.now()):
                self.pub[out].publish(m)
            self.log_core()

        return cb

    def _on_state_raw(self, data):
        rt = self.runtime
        if rt.settings.lockstep and not rt.lockstep_linked:
            # the simulation's subscription to the answers matched (start waits for it)
            ack = self.pub[messages.LOCKSTEP_ACK[0]]
            rt.lockstep_linked = ack.get_subscription_count() > 0
        # tick_source state: a state sample steps the law at once (freshest sample)
        for out, m in self.runtime.on_state_cdr(data, self.now(), self._deserialize_state):
            self.pub[out].publish(m)
        self.log_core()

    @staticmethod
    def _deserialize_state(data):
        return deserialize_message(data, Odometry)

    def on_tick(self):
        if self._auto_start and not self.runtime.supervisor.armed:
            ok, why = self.runtime.start(self.now(), wait_for_inputs=True)
            if ok or self.runtime.supervisor.aborted:
                self._auto_start = False
                self.get_logger().info(f"auto_start: {why}")
        for topic, msg in self.runtime.on_timer(self.now()):
            self.pub[topic].publish(msg)
        self.log_core()

    def publish_status(self):
        self.pub["status"].publish(self.runtime.status(self.now()))

    def on_start(self, request, response):
        response.success, response.message = self.runtime.start(self.now(), wait_for_inputs=True)
        self.get_logger().info(f"start: {response.message}")
        return response

    def on_abort(self, request, response):
        response.message = self.runtime.abort(self.now(), "abort service")
        response.success = True
        self.get_logger().warning(f"abort: {response.message}")
        self.on_tick()
        return response

    # -- orderly shutdown (nodes/shell.run) ----------------------------------------
    def begin_shutdown(self):
        """Latch an abort "shutdown" while the context is valid and publish the final
        status: no actuator_command follows (the bridge hands control back to PX4 when the
        commands stop; the excitation node fades out on the abort status)."""
        now = self.now()
        self.runtime.abort(now, "shutdown")
        published = False
        for topic, msg in self.runtime.tick(now):  # aborted: the abort status, no command
            self.pub[topic].publish(msg)
            published |= topic == "status"
        if not published:  # not started, or abort already reported
            self.publish_status()
        self.log_core()


def main(args=None):
    return shell.run(LpvControllerNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
