"""sim_vehicle_node: the simulated quadrotor as a node, so the graph runs without hardware.

Shell around :class:`lpv_sysid.sim.vehicle_node.runtime.SimVehicleRuntime` (the physics of
sim/vehicle.py, the PX4-like baseline, lock-step, sample and status rules; see there). A
timer at ``state_hz`` advances the physics to the pace clock; ``state`` (Odometry), ``imu``
and ``rotor_speeds`` are published at their sensor rates (best effort), stamped with the
physics time. Mode ``baseline`` (phase 1) flies ``velocity_reference``; mode ``lpv`` (phase 2)
applies ``actuator_command`` (baseline hold once it goes stale: PX4's hand-back).
``lockstep`` (sim.launch.py): the simulation is the clock of the graph (``/clock``, physics
time from 0), paced by the steady clock, each state sample waiting for the controller's
answer (its command, or ``lockstep_ack`` while it sends none) and the reference before the
physics integrates on. Parameters: :data:`SPECS`
(:mod:`lpv_sysid.sim.vehicle_node.settings`).

    ros2 run lpv_sysid sim_vehicle_node --ros-args --params-file config/sim_vehicle.yaml
"""

from __future__ import annotations

from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import Imu, JointState

from lpv_sysid.io import messages
from lpv_sysid.nodes import shell
from lpv_sysid.sim.vehicle_node import SPECS, SimVehicleRuntime, settings_from_params

NODE_NAME = "sim_vehicle"
#: the rclpy declarations, generated from the one declaration (sim_vehicle_settings)
PARAMETERS = shell.spec_table(SPECS)


class SimVehicleNode(shell.RuntimeShell):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        settings, sensors = settings_from_params(self.params)
        # lockstep: the physics is paced by a steady (wall) clock and is itself the time of
        # the graph; otherwise it follows the node clock (system time)
        self.pace_clock = Clock(clock_type=ClockType.STEADY_TIME) if settings.lockstep else None
        self.runtime = SimVehicleRuntime(
            settings,
            sensors,
            messages.MsgFactory.rclpy(),
            self.get_fully_qualified_name(),
            t0_ns=self._pace_ns(),
            log=shell.core_log(self),
        )
        self.pub = {
            "state": self.create_publisher(Odometry, "state", shell.qos_for("state")),
            "imu": self.create_publisher(Imu, "imu", shell.qos_for("imu")),
            "rotor_speeds": self.create_publisher(
                JointState, "rotor_speeds", shell.qos_for("rotor_speeds")
            ),
            "status": shell.StatusPublisher(self),  # status and /diagnostics
        }
        self.create_subscription(
            TwistStamped,
            "velocity_reference",
            self.on_reference,
            shell.qos_for("velocity_reference"),
        )
        self.create_subscription(
            JointState, "actuator_command", self.on_command, shell.qos_for("actuator_command")
        )
        if settings.publish_tf:
            self.enable_tf()
        if settings.lockstep:
            self.pub["clock"] = self.create_publisher(ClockMsg, "/clock", shell.QOS_RELIABLE)
            # the controller's answer to a state sample it sends no command on (its lockstep)
            ack = messages.LOCKSTEP_ACK[0]
            self.create_subscription(ClockMsg, ack, self.on_ack, shell.qos_for(ack))
        self.create_timer(1.0 / sensors.state_hz, self.on_tick, clock=self.pace_clock)
        self.status_timer(settings.status_rate_hz, self.publish_status)

    def settings_from(self, values):
        return settings_from_params(values)

    def _pace_ns(self) -> int:
        return self.pace_clock.now().nanoseconds if self.pace_clock is not None else self.now_ns()

    def on_reference(self, msg):
        parsed = self.parse_input("velocity_reference", messages.reference_from_twist, msg)
        if parsed is not None:
            stamp_s, v, r = parsed
            self.publish_outputs(self.runtime.on_reference(stamp_s, v, r, self._pace_ns()))

    def on_command(self, msg):
        parsed = self.parse_input(
            "actuator_command", messages.actuator_command_from_joint_state, msg
        )
        if parsed is not None:
            stamp_s, u = parsed
            self.publish_outputs(self.runtime.on_command(stamp_s, u, self._pace_ns()))

    def on_ack(self, msg):
        stamp_ns = self.parse_input(messages.LOCKSTEP_ACK[0], messages.clock_ns_of, msg)
        if stamp_ns is not None:
            self.publish_outputs(self.runtime.on_answer(stamp_ns * 1e-9, self._pace_ns()))

    def on_tick(self):
        self.publish_outputs(self.runtime.on_tick(self._pace_ns()))

    def publish_status(self):
        self.publish_outputs([("status", self.runtime.status(self._pace_ns()))])


def main(args=None):
    return shell.run(SimVehicleNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
