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
