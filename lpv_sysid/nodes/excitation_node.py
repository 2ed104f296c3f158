"""excitation_node: plays a signal set as velocity reference and excitation u_e.

Shell around :class:`lpv_sysid.flight.excitation.ExcitationRuntime` (the
:class:`~lpv_sysid.signals.excitation.ExcitationCore` with the start, abort, fade and status
rules; see there). Publishes, at ``rate_hz`` from a timer that samples the core at the node
clock's current time: ``velocity_reference`` (TwistStamped) and ``excitation`` (JointState
``ue_t, ue_a, ue_e, ue_r``); ``status`` (DiagnosticArray) at ``status_rate_hz``. Services
``start`` / ``abort`` (std_srvs/Trigger). An abort from any source (the service, an abort on
``status`` from a node of ``abort_on_status_from``, the node clock going back, shutdown) fades
everything to zero within one ramp. Parameters are declared once, in
:class:`ExcitationSettings`.

    ros2 run lpv_sysid excitation_node --ros-args --params-file config/excitation_node.yaml \
        -p signals_file:=signals.npz -p mode:=phase1
"""

from __future__ import annotations

import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from lpv_sysid.flight.excitation import ExcitationRuntime, ExcitationSettings
from lpv_sysid.io import messages
from lpv_sysid.nodes import shell

NODE_NAME = "excitation"
#: the rclpy declarations, generated from the one declaration (ExcitationSettings)
PARAMETERS = shell.settings_table(ExcitationSettings)


class ExcitationNode(shell.RuntimeShell):
    SETTINGS = ExcitationSettings

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        s = ExcitationSettings.from_dict(self.params)
        self.runtime = ExcitationRuntime(
            s, messages.MsgFactory.rclpy(), self.get_fully_qualified_name(), shell.core_log(self)
        )
        self.pub = {
            "velocity_reference": self.create_publisher(
                TwistStamped, "velocity_reference", shell.qos_for("velocity_reference")
            ),
            "excitation": self.create_publisher(
                JointState, "excitation", shell.qos_for("excitation")
            ),
            "status": shell.StatusPublisher(self),  # status and /diagnostics
        }
        self.create_subscription(
            DiagnosticArray, "status", self.on_status, shell.qos_for("status")
        )
        self.create_service(Trigger, "~/start", self.on_start)
        self.create_service(Trigger, "~/abort", self.on_abort)
        self.create_timer(1.0 / s.rate_hz, self.on_timer)
        self.status_timer(s.status_rate_hz, self.publish_status)
        table = self.runtime.table
        self.get_logger().info(
            f"{s.mode}: {table[1].shape[0]} samples of {list(table[2])} "
            f"({self.runtime.core.duration:.1f} s), {s.rate_hz:g} Hz; {shell.clock_source(self)}"
        )
        if s.auto_start:
            self.runtime.start(self.now_ns())

    def on_status(self, msg):
        self.publish_outputs(self.runtime.on_status(msg, self.now_ns()))

    def on_start(self, request, response):
        response.success, response.message = self.runtime.start(self.now_ns())
        self.get_logger().info(f"start: {response.message}")
        return response

    def on_abort(self, request, response):
        self.publish_outputs(self.runtime.abort(self.now_ns(), "abort service"))
        response.success = True
        response.message = "excitation aborted: fading to zero"
        return response

    def on_timer(self):
        self.publish_outputs(self.runtime.on_timer(self.now_ns()))

    def publish_status(self):
        self.publish_outputs([("status", self.runtime.status(self.now_ns()))])

    # -- orderly shutdown (nodes/shell.run) ----------------------------------------
    def begin_shutdown(self):
        self.publish_outputs(self.runtime.begin_shutdown(self.now_ns(), time.monotonic()))

    def shutdown_complete(self):
        self.publish_outputs(self.runtime.poll_shutdown(self.now_ns(), time.monotonic()))
        return self.runtime.shutdown_done

    def shutdown_state(self):
        return self.runtime.shutdown_state(self.now_ns())


def main(args=None):
    return shell.run(ExcitationNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
