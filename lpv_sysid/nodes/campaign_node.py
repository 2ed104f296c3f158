"""campaign_node: the phase-1 flight campaign in the ROS 2 graph (``launch/campaign.launch.py``).

Shell around :class:`lpv_sysid.flight.campaign.runtime.CampaignRuntime`, which drives
:class:`lpv_sysid.control.campaign.Campaign` (the same core as ``lpv-sysid fly phase1``). It
commands ``velocity_reference`` (TwistStamped, FLU) to the ``mavlink_bridge`` node, which
streams it to PX4 and enforces the safety envelope, and follows the bridge through its
``status`` (DiagnosticArray: ``state``, ``reason``, ``vehicle_mode``, ``armed``,
``envelope_home``, ``envelope_violation``). It calls the bridge's ``start`` service to
pre-stream, switch to OFFBOARD and arm (the bridge needs ``offboard.arm: true``), its
``abort`` service to hand back. Subscribes ``state``, ``rotor_speeds``, ``imu`` (best
effort); publishes ``velocity_reference`` as flown (vertex, altitude correction,
multisine), ``excitation`` (zeros: phase 1 has no u_e) and ``status``. Services
``~/start`` (fly the campaign) and ``~/abort`` (excitation off, hand back).

Per-run bags: with ``out_dir`` the node writes one rosbag2 per run (trim + excitation),
``out_dir/bag_NNNN`` with the data logger's topics
(``lpv_sysid.cli.vehicle.fly.CampaignRecorder``), plus ``campaign_summary.yaml`` and ``trims.yaml``
at the end, so ``lpv-sysid identify --bags out_dir`` runs on it; the data logger records the whole
flight as usual. The bridge's ``vehicle_record`` (transient local) becomes the runs'
``experiment.yaml`` ``vehicle``, as ``fly phase1`` writes it.

The bridge node offers ``start`` and ``abort`` only: the campaign therefore ends with the
bridge's hand-back chain (``offboard.handback_chain``, HOLD first by default); a
``finish: LAND`` in the campaign file is flown as HOLD here (warned at start; use
``lpv-sysid fly phase1`` to land automatically). The envelope's floor activates by itself
above floor + margin (the explicit activation of the CLI needs no service).

    ros2 run lpv_sysid campaign_node --ros-args -p campaign_file:=config/campaign.yaml \
        -p out_dir:=flight_07_runs
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from lpv_sysid.flight.campaign import PARSERS, CampaignNodeSettings, CampaignRuntime
from lpv_sysid.io import messages
from lpv_sysid.nodes import shell

NODE_NAME = "campaign"
#: the rclpy declarations, generated from the one declaration (CampaignNodeSettings)
PARAMETERS = shell.settings_table(CampaignNodeSettings)


class CampaignNode(shell.ShellNode):
    SETTINGS = CampaignNodeSettings

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        s = CampaignNodeSettings.from_dict(self.params)
        bridge = self.resolve_topic_name(s.bridge_node)
        self.bridge_clients = {
            w: self.create_client(Trigger, f"{bridge}/{w}") for w in ("start", "abort")
        }
        self.runtime = rt = CampaignRuntime(
            s,
            messages.MsgFactory.rclpy(),
            self.get_fully_qualified_name(),
            bridge,
            lambda which: self.bridge_clients[which].service_is_ready(),
        )
        self.campaign = rt.campaign
        self.pub = {
            "velocity_reference": self.create_publisher(
                TwistStamped, "velocity_reference", shell.qos_for("velocity_reference")
            ),
            "excitation": self.create_publisher(
                JointState, "excitation", shell.qos_for("excitation")
            ),
            "status": shell.StatusPublisher(self),  # status and /diagnostics
        }
        for topic, typ in (
            ("state", Odometry),
            ("rotor_speeds", JointState),
            ("imu", Imu),
            ("rate_setpoint", JointState),
        ):
            self.create_subscription(typ, topic, self._input(topic), shell.qos_for(topic))
        self.create_subscription(DiagnosticArray, "status", rt.on_status, shell.qos_for("status"))
        self.create_subscription(
            String, messages.VEHICLE_RECORD_TOPIC, self._vehicle_record, shell.QOS_VEHICLE_RECORD
        )
        self.create_service(Trigger, "~/start", shell.trigger(self, rt.start, self.emit))
        self.create_service(Trigger, "~/abort", shell.trigger(self, rt.abort, self.emit))
        self.create_timer(1.0 / s.rate_hz, lambda: self.emit(rt.on_timer(self.now())))
        self.status_timer(s.status_rate_hz, lambda: self.emit(rt.status(self.now())))
        self.emit([])

    def _vehicle_record(self, msg):
        self.runtime.on_vehicle_record(msg)
        shell.log_lines(self.get_logger(), self.runtime.take_log())

    def _input(self, topic):
        parse = PARSERS[topic]

        def cb(msg):
            if self.runtime.wants(topic):
                parsed = self.parse_input(topic, parse, msg)
                if parsed is not None:
                    self.emit(self.runtime.on_sample(topic, parsed, self.now()))

        return cb

    def emit(self, out):
        """Publish the runtime's messages and call the bridge services it asks for, then
        log what it queued."""
        for key, payload in out:
            if key == "call":
                self._call(payload)
            else:
                self.pub[key].publish(payload)
        shell.log_lines(self.get_logger(), self.runtime.take_log())

    def _call(self, what: str) -> None:
        client = self.bridge_clients[what]
        if not client.service_is_ready():
            self.get_logger().error(f"bridge service {client.srv_name} not available ({what})")
        fut = client.call_async(Trigger.Request())
        fut.add_done_callback(
            lambda f: self.get_logger().info(
                f"bridge {what}: {f.result().message if f.result() is not None else 'no answer'}"
            )
        )

    # -- orderly shutdown (nodes/shell.run) ----------------------------------------
    def begin_shutdown(self):
        self.emit(self.runtime.shutdown(self.now()))

    def shutdown_complete(self):
        return self.runtime.shutdown_complete()

    def shutdown_state(self):
        return self.runtime.shutdown_state()

    def destroy_node(self):
        try:
            self.runtime.close(self.now())
            shell.log_lines(self.get_logger(), self.runtime.take_log())
        finally:
            super().destroy_node()


def main(args=None):
    return shell.run(CampaignNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
