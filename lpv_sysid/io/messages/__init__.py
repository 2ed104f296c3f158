"""ROS message <-> array conversion: the only place message fields are touched (this package).

Builders take a :class:`MsgFactory` so the same code makes rosbags dataclasses (CI, bag
files) and real rclpy messages (onboard). Messages are constructed with keyword arguments
for every field, floats are passed as Python ``float`` and numeric sequences through the
factory's adapters, which is what both rosbags and rclpy's generated classes accept.

Parsers accept either kind of message and return core quantities in the seed's frames
(NED world, FRD body, SI units); every frame conversion goes through
:mod:`lpv_sysid.io.frames`. Topic contents (docs/DESIGN.md):

============================  ==============================  ===================================
topic                         type                            content
============================  ==============================  ===================================
``state``                     nav_msgs/Odometry               ``odom`` (ENU) / ``base_link`` (FLU);
                                                              ENU position, ENU/FLU attitude,
                                                              body velocity and rates FLU
``rotor_speeds``              sensor_msgs/JointState          ``rotor_1..rotor_4``, velocity rad/s,
                                                              measured (ESC);
                                                              ``rotor_1_estimated..`` from the
                                                              motor outputs (seed 0 Eq. 8);
                                                              frame_id ``base_link``
``imu``                       sensor_msgs/Imu                 FLU specific force and rates,
                                                              ENU/FLU orientation
``velocity_reference``        geometry_msgs/TwistStamped      ``base_link``; linear = v_d FLU,
                                                              angular.z = yaw-rate ref FLU
``excitation``                sensor_msgs/JointState          ``ue_t, ue_a, ue_e, ue_r``, position
``actuator_command``          sensor_msgs/JointState          ``ut, ua, ue, ur``, position
``status``                    diagnostic_msgs/DiagnosticArray one DiagnosticStatus per node
``vehicle_record``            std_msgs/String                 JSON: the bridge's vehicle record
                                                              (``experiment.yaml`` ``vehicle``)
============================  ==============================  ===================================

Virtual actuator channels are named channels in the seed's FRD sense and are never frame
converted. Stamps are integer nanoseconds in the core (``stamp_ns``) and
``builtin_interfaces/Time`` on the wire; samples also carry ``t = stamp_ns / 1e9`` (s).

One module per message family:

=========================================  =====================================================
:mod:`~lpv_sysid.io.messages.factory`      :class:`MsgFactory`, :class:`MessageError`
:mod:`~lpv_sysid.io.messages.fields`       frame ids, stamps and headers, field checks
:mod:`~lpv_sysid.io.messages.state`        ``state`` (Odometry)
:mod:`~lpv_sysid.io.messages.channels`  ``rotor_speeds``, ``excitation``, ``actuator_command``
:mod:`~lpv_sysid.io.messages.imu`          ``imu``
:mod:`~lpv_sysid.io.messages.twist`        ``velocity_reference``, the MAVROS setpoint
:mod:`~lpv_sysid.io.messages.status`       ``status`` (DiagnosticArray)
:mod:`~lpv_sysid.io.messages.record`       ``vehicle_record`` (String, JSON)
=======================================  ===========================================
"""

from __future__ import annotations

from lpv_sysid.io.messages.channels import (
    ROTOR_ESTIMATED_FRAME,
    ROTOR_ESTIMATED_NAMES,
    ROTOR_NAMES,
    ROTOR_SOURCES,
    actuator_command_from_joint_state,
    actuator_command_msg,
    channels_from_joint_state,
    channels_from_joint_states,
    excitation_from_joint_state,
    excitation_msg,
    joint_state,
    rotor_names_of,
    rotor_source_of,
    rotor_speeds_from_joint_state,
    rotor_speeds_msg,
)
from lpv_sysid.io.messages.factory import MessageError, MsgFactory
from lpv_sysid.io.messages.fields import (
    BASE_FRAME,
    clock_msg,
    clock_ns_of,
    header_msg,
    stamp_ns_from_time,
    stamp_ns_of,
    time_msg,
)
from lpv_sysid.io.messages.imu import ImuSample, imu_from_msg, imu_msg
from lpv_sysid.io.messages.state import (
    TF_TOPIC,
    StateSample,
    odometry_from_state,
    odometry_cdr_frames,
    state_from_odometry,
    state_from_odometry_cdr,
    states_from_odometry,
    tf_from_odometry,
)
from lpv_sysid.io.messages.status import (
    StatusSample,
    diagnostic_array,
    diagnostic_status,
    status_from_diagnostic_array,
)
from lpv_sysid.io.messages.mavros import (
    MAVROS_TYPES,
    MavrosVehicleState,
    attitude_target_msg,
    battery_from_msg,
    esc_rpm_from_msg,
    estimator_flags_from_msg,
    autopilot_version_known,
    firmware_from_vehicle_info,
    gps_from_gpsraw,
    gps_from_navsatfix,
    home_geo_from_msg,
    home_ned_from_msg,
    param_from_event,
    param_names_from_list,
    params_from_get_parameters,
    position_target_msg,
    rate_setpoint_from_attitude_target_msg,
    rc_in_from_msg,
    rc_out_from_msg,
    state_from_msg,
    vehicle_from_info_response,
    velocity_setpoint_from_position_target,
)
from lpv_sysid.io.messages.record import (
    CLOCK_KINDS,
    vehicle_record_from_msg,
    vehicle_record_msg,
)
from lpv_sysid.io.messages.topics import (
    LOCKSTEP_ACK,
    NAMESPACE,
    SENSOR_TOPICS,
    TOPIC_NAMESPACE,
    TYPES,
    VEHICLE_RECORD_TOPIC,
    VEHICLE_RECORD_TYPE,
    qos_of,
)
from lpv_sysid.io.messages.twist import (
    enu_velocity_setpoint_msg,
    reference_from_twist,
    twist_reference_msg,
)

__all__ = [
    "BASE_FRAME",
    "ImuSample",
    "MAVROS_TYPES",
    "MavrosVehicleState",
    "MessageError",
    "MsgFactory",
    "LOCKSTEP_ACK",
    "NAMESPACE",
    "ROTOR_ESTIMATED_FRAME",
    "ROTOR_ESTIMATED_NAMES",
    "ROTOR_NAMES",
    "ROTOR_SOURCES",
    "StateSample",
    "StatusSample",
    "TOPIC_NAMESPACE",
    "TYPES",
    "SENSOR_TOPICS",
    "qos_of",
    "actuator_command_from_joint_state",
    "attitude_target_msg",
    "battery_from_msg",
    "actuator_command_msg",
    "channels_from_joint_state",
    "clock_msg",
    "clock_ns_of",
    "channels_from_joint_states",
    "diagnostic_array",
    "diagnostic_status",
    "enu_velocity_setpoint_msg",
    "esc_rpm_from_msg",
    "estimator_flags_from_msg",
    "excitation_from_joint_state",
    "excitation_msg",
    "gps_from_gpsraw",
    "gps_from_navsatfix",
    "header_msg",
    "home_geo_from_msg",
    "home_ned_from_msg",
    "imu_from_msg",
    "imu_msg",
    "joint_state",
    "odometry_from_state",
    "params_from_get_parameters",
    "position_target_msg",
    "rate_setpoint_from_attitude_target_msg",
    "rc_in_from_msg",
    "rc_out_from_msg",
    "reference_from_twist",
    "rotor_names_of",
    "rotor_source_of",
    "rotor_speeds_from_joint_state",
    "rotor_speeds_msg",
    "stamp_ns_from_time",
    "stamp_ns_of",
    "odometry_cdr_frames",
    "state_from_msg",
    "state_from_odometry",
    "state_from_odometry_cdr",
    "states_from_odometry",
    "tf_from_odometry",
    "TF_TOPIC",
    "status_from_diagnostic_array",
    "time_msg",
    "twist_reference_msg",
    "vehicle_from_info_response",
    "velocity_setpoint_from_position_target",
    "CLOCK_KINDS",
    "autopilot_version_known",
    "firmware_from_vehicle_info",
    "param_from_event",
    "param_names_from_list",
    "VEHICLE_RECORD_TOPIC",
    "VEHICLE_RECORD_TYPE",
    "vehicle_record_from_msg",
    "vehicle_record_msg",
]
