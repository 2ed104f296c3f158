"""sequencer_node: starts a phase's nodes in the safe order (phase launch files).

Shell around :class:`lpv_sysid.flight.sequencer.SequencerRuntime`: calls ``start`` on each
node of ``steps`` (default ``mavlink_bridge`` -> ``lpv_controller`` -> ``excitation``, in
this namespace) once the previous one has confirmed its start on ``status``, and ``abort``
on every started node (reverse order) when one refuses, does not confirm in time, or reports
an abort. Subscribes ``status``; publishes ``status``; services ``~/start`` (run the
sequence: one call for the operator) and ``~/abort``. Parameters: :class:`SequencerSettings`.

    ros2 run lpv_sysid sequencer_node --ros-args -p "steps:=[mavlink_bridge, excitation]"
    ros2 service call /lpv_sysid/sequencer/start std_srvs/srv/Trigger
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from std_srvs.srv import Trigger

from lpv_sysid.flight.sequencer import SequencerRuntime, SequencerSettings, split_step
from lpv_sysid.io import messages
from lpv_sysid.nodes import shell

NODE_NAME = "sequencer"
#: the rclpy declarations, generated from the one declaration (SequencerSettings)
PARAMETERS = shell.settings_table(SequencerSettings)


class SequencerNode(shell.ShellNode):
    SETTINGS = SequencerSettings

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        s = SequencerSettings.from_dict(self.params)
        self.clients_ = {
            (node, which): self.create_client(Trigger, f"{self.resolve_topic_name(node)}/{which}")
            for node in dict.fromkeys(split_step(step)[0] for step in s.steps)
            for which in ("start", "abort")
        }
        self.runtime = rt = SequencerRuntime(
            s,
            messages.MsgFactory.rclpy(),
            self.get_fully_qualified_name(),
            lambda node, which: self.clients_[(node, which)].service_is_ready(),
        )
        self.pub = {"status": shell.StatusPublisher(self)}  # status and /diagnostics
        self.create_subscription(
            DiagnosticArray,
            "status",
            lambda msg: self.emit(rt.on_status(msg, self.now())),
            shell.qos_for("status"),
        )
        self.create_service(Trigger, "~/start", shell.trigger(self, rt.start, self.emit))
        self.create_service(Trigger, "~/abort", shell.trigger(self, rt.abort, self.emit))
        self.create_timer(1.0 / s.rate_hz, lambda: self.emit(rt.on_timer(self.now())))
        self.status_timer(s.status_rate_hz, lambda: self.emit(rt.status(self.now())))
        if s.auto_start:
            self.emit(rt.start(self.now())[2])
        else:
            self.emit([])

    def emit(self, out):
        """Publish the runtime's status and call the services it asks for, then log."""
        for key, payload in out:
            if key == "call":
                self._call(*payload)
            else:
                self.pub[key].publish(payload)
        shell.log_lines(self.get_logger(), self.runtime.take_log())

    def _call(self, node: str, which: str) -> None:
        client = self.clients_[(node, which)]
        if not client.service_is_ready():
            self.get_logger().error(f"service {client.srv_name} not available ({which})")
        fut = client.call_async(Trigger.Request())

        def done(f):
            r = f.result()
            ok, text = (r.success, r.message) if r is not None else (False, "no answer")
            self.emit(self.runtime.on_answer(node, which, ok, text, self.now()))

        fut.add_done_callback(done)


def main(args=None):
    return shell.run(SequencerNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
