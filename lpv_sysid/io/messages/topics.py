"""The topics of the package: their namespace and message types (docs/DESIGN.md)."""

from __future__ import annotations

NAMESPACE = "lpv_sysid"
#: the topics' absolute prefix (bags, replay)
TOPIC_NAMESPACE = "/" + NAMESPACE

TYPES = {
    "state": "nav_msgs/msg/Odometry",
    "rotor_speeds": "sensor_msgs/msg/JointState",
    "imu": "sensor_msgs/msg/Imu",
    "velocity_reference": "geometry_msgs/msg/TwistStamped",
    "excitation": "sensor_msgs/msg/JointState",
    "actuator_command": "sensor_msgs/msg/JointState",
    "status": "diagnostic_msgs/msg/DiagnosticArray",
    # PX4's ATTITUDE_TARGET (thrust + body-rate setpoints it tracks; names thrust, p_sp, q_sp,
    # r_sp in ``position``): the rate-plant identification's input, phase 2's echo
    "rate_setpoint": "sensor_msgs/msg/JointState",
}
#: lock-stepped simulation only (sim.launch.py): the controller's answer to a state sample on
#: which it sent no ``actuator_command`` (not started, or aborted), ``clock`` = the sample's
#: stamp; sim_vehicle (``lockstep``) integrates past a state sample only once it is answered
#: (command or this). Not an experiment topic: not recorded, absent on a vehicle.
LOCKSTEP_ACK = ("lockstep_ack", "rosgraph_msgs/msg/Clock")

#: QoS of the high-rate measurement streams: best effort, keep last 5 (rclpy's
#: ``qos_profile_sensor_data``): a late sample is worthless, a retransmission only delays
#: the next one
SENSOR_QOS = {
    "history": "keep_last",
    "depth": 5,
    "reliability": "best_effort",
    "durability": "volatile",
}
#: references, excitation and commands: reliable, keep last 10, volatile
RELIABLE_QOS = {
    "history": "keep_last",
    "depth": 10,
    "reliability": "reliable",
    "durability": "volatile",
}
#: ``status`` (and ``/diagnostics``): reliable and transient local, keep last 10, so a
#: subscriber that joins late (``ros2 topic echo``, a restarted logger) still receives each
#: node's last status, e.g. the final state of a node that aborted
STATUS_QOS = {**RELIABLE_QOS, "durability": "transient_local"}
SENSOR_TOPICS = frozenset({"state", "rotor_speeds", "imu"})
#: the bridge's vehicle record (firmware, PX4 parameters, PX4's boot on the ROS clock, ...,
#: ``experiment.yaml``'s ``vehicle``): JSON in a std_msgs/String, published when it changes
#: materially; metadata, not a recorded stream (not in :data:`TYPES`)
VEHICLE_RECORD_TOPIC = "vehicle_record"
VEHICLE_RECORD_TYPE = "std_msgs/msg/String"
#: ``vehicle_record``: reliable and transient local, keep last 1: a logger started (or
#: restarted) after the bridge still receives the latest record, and only that one
VEHICLE_RECORD_QOS = {**RELIABLE_QOS, "depth": 1, "durability": "transient_local"}


def qos_of(topic: str) -> dict:
    """The QoS the package's publishers offer on ``topic`` (relative or absolute name; the
    last name component decides) -- what the nodes publish with and what a recording
    stores as the topic's ``offered_qos_profiles``."""
    leaf = topic.rsplit("/", 1)[-1]
    if leaf in SENSOR_TOPICS:
        return dict(SENSOR_QOS)
    if leaf in ("status", "diagnostics"):
        return dict(STATUS_QOS)
    if leaf == VEHICLE_RECORD_TOPIC:
        return dict(VEHICLE_RECORD_QOS)
    return dict(RELIABLE_QOS)
