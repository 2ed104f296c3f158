"""lpv_controller_node: the robust LPV velocity controller of phase 2 (seed 0 Sec. VI).

Shell around :class:`lpv_sysid.nodes.controller_runtime.ControllerRuntime` (the runtime law
of control/lpv_controller.py + the safety supervisor of control/safety.py). Loads and
validates ``gains_file`` at start and refuses to start on any mismatch, naming the field
(exit status 2). Subscribes ``state``, ``rotor_speeds`` (best effort), ``velocity_reference``
and ``excitation`` (reliable); after ``start`` publishes ``actuator_command`` at ``rate_hz``.
On a fault it publishes the abort on ``status`` and stops commanding, so the bridge hands
control back to PX4. Services ``start`` / ``abort`` (std_srvs/Trigger).

    ros2 run lpv_sysid lpv_controller_node --ros-args \
        --params-file config/lpv_controller.yaml -p gains_file:=gains.yaml
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from lpv_sysid.io import messages as M
from lpv_sysid.nodes import _common as C
from lpv_sysid.nodes.controller_runtime import ControllerRuntime, ControllerSettings

NODE_NAME = "lpv_controller"
S = Parameter.Type.STRING

PARAMETERS = [
    ("gains_file", "", C.typed(S, "gains.yaml from `lpv-sysid synthesize` (validated at start)")),
    ("models_file", "", C.typed(S, "vertex_models.yaml to check the gains against (optional)")),
    ("rate_hz", 250.0, C.double("actuator command rate [Hz]", 1.0, 2000.0)),
    ("state_timeout_s", 0.02, C.double("state older than this -> abort [s]", 0.001, 10.0)),
    ("rotor_timeout_s", 0.05, C.double("rotor_speeds older than this -> abort [s]",
                                       0.001, 10.0)),
    ("reference_timeout_s", 0.1, C.double("velocity_reference older than this -> abort [s]",
                                          0.001, 10.0)),
    ("excitation_timeout_s", 0.1, C.double("excitation older than this -> abort [s]",
                                           0.001, 10.0)),
    ("box_margin", 0.0, C.double("tolerance around the scheduling box [m/s]", 0.0, 10.0)),
    ("excitation_gain", 1.0, C.double("excitation multiplier kappa (seed 0 Eq. 33)",
                                      0.0, 100.0)),
    ("arm_length", 0.225, C.double("arm length of the mixer (seed 0 Eq. 7) [m]", 0.01, 10.0)),
    ("u_esc_min", 0.0, C.double("lower ESC command limit", 0.0, 1.0)),
    ("u_esc_max", 1.0, C.double("upper ESC command limit", 0.0, 1.0)),
    ("rate_limit", Parameter.Type.DOUBLE_ARRAY, C.typed(
        Parameter.Type.DOUBLE_ARRAY, "per-channel rate limit of u [1/s] (unset: none)")),
    ("monitor_margin", 1.2, C.double("bound monitor: abort when gain > gamma x margin",
                                     0.01, 100.0)),
    ("monitor_min_energy", 0.05, C.double("bound monitor: ||u_e||^2 before judging",
                                          1e-9, 1e6)),
    ("auto_start", False, C.typed(Parameter.Type.BOOL, "start commanding without the service")),
    ("status_rate_hz", 2.0, C.double("status publication rate [Hz]", 0.1, 100.0)),
]
SHELL_ONLY = ("auto_start", "status_rate_hz")


class LpvControllerNode(C.ShellNode):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        p = self.params
        settings = ControllerSettings.from_dict({k: v for k, v in p.items()
                                                 if k not in SHELL_ONLY})
        self.runtime = ControllerRuntime(settings, M.MsgFactory.rclpy(),
                                         self.get_fully_qualified_name())
        self.pub = {"actuator_command": self.create_publisher(
                        JointState, "actuator_command", C.qos_for("actuator_command")),
                    "status": self.create_publisher(DiagnosticArray, "status",
                                                    C.qos_for("status"))}
        for topic, typ in (("state", Odometry), ("rotor_speeds", JointState),
                           ("velocity_reference", TwistStamped), ("excitation", JointState)):
            self.create_subscription(typ, topic, self._input(topic), C.qos_for(topic))
        self.create_service(Trigger, "~/start", self.on_start)
        self.create_service(Trigger, "~/abort", self.on_abort)
        self.create_timer(1.0 / settings.rate_hz, self.on_tick)
        self.create_timer(1.0 / p["status_rate_hz"], self.publish_status)
        self.get_logger().info(f"gains {settings.gains_file}: box "
                               f"{self.runtime.schedule.scheduling.to_dict()}, "
                               f"gamma {self.runtime.schedule.gamma:g}")
        if p["auto_start"]:
            self.get_logger().info(self.runtime.start(self.now())[1])

    def _input(self, topic):
        def cb(msg):
            self.runtime.on_message(topic, msg, self.now())
        return cb

    def on_tick(self):
        for topic, msg in self.runtime.tick(self.now()):
            self.pub[topic].publish(msg)

    def publish_status(self):
        self.pub["status"].publish(self.runtime.status(self.now()))

    def on_start(self, request, response):
        response.success, response.message = self.runtime.start(self.now())
        self.get_logger().info(f"start: {response.message}")
        return response

    def on_abort(self, request, response):
        response.message = self.runtime.abort(self.now(), "abort service")
        response.success = True
        self.get_logger().warning(f"abort: {response.message}")
        self.on_tick()
        return response


def main(args=None):
    return C.run(LpvControllerNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
