"""The ``imu`` topic: ``sensor_msgs/Imu`` (FLU) <-> specific force, rates and (when known)
attitude in core frames."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lpv_sysid.io import frames
from lpv_sysid.io.messages.factory import MsgFactory
from lpv_sysid.io.messages.fields import (
    BASE_FRAME,
    check_frame,
    finite,
    header_msg,
    quaternion,
    stamp_ns_of,
    vector3,
    xyz,
)


@dataclass(frozen=True)
class ImuSample:
    """IMU in core frames: FRD specific force (m/s^2), FRD rates (rad/s) and, when the
    message carries an orientation, NED/FRD Euler angles (else ``None``)."""

    t: float
    specific_force: np.ndarray
    omega: np.ndarray
    euler: np.ndarray | None
    stamp_ns: int = 0


def imu_msg(
    f: MsgFactory,
    stamp_ns: int,
    specific_force_frd,
    omega_frd,
    euler=None,
    *,
    frame_id: str = BASE_FRAME,
):
    """``sensor_msgs/Imu`` (FLU). Without ``euler`` the orientation is marked unknown
    (``orientation_covariance[0] = -1``, as sensor_msgs/Imu documents)."""
    a = frames.frd_to_flu(finite(specific_force_frd, 3, "imu.specific_force"))
    w = frames.frd_to_flu(finite(omega_frd, 3, "imu.omega"))
    ocov = np.zeros(9)
    if euler is None:
        q = np.array([0.0, 0.0, 0.0, 1.0])
        ocov[0] = -1.0
    else:
        q = frames.ros_orientation_from_euler(finite(euler, 3, "imu.euler"))
    return f(
        "sensor_msgs/msg/Imu",
        header=header_msg(f, stamp_ns, frame_id),
        orientation=quaternion(f, q),
        orientation_covariance=f.float_array(ocov),
        angular_velocity=vector3(f, w),
        angular_velocity_covariance=f.float_array(np.zeros(9)),
        linear_acceleration=vector3(f, a),
        linear_acceleration_covariance=f.float_array(np.zeros(9)),
    )


def imu_from_msg(msg, *, frame_id: str | None = BASE_FRAME) -> ImuSample:
    check_frame(msg.header.frame_id, frame_id, "imu.header")
    a = finite(xyz(msg.linear_acceleration), 3, "imu.linear_acceleration")
    w = finite(xyz(msg.angular_velocity), 3, "imu.angular_velocity")
    euler = None
    if float(np.asarray(msg.orientation_covariance, dtype=float)[0]) != -1.0:
        o = msg.orientation
        euler = frames.euler_from_ros_orientation(
            finite([o.x, o.y, o.z, o.w], 4, "imu.orientation")
        )
    ns = stamp_ns_of(msg)
    return ImuSample(
        t=ns / 1e9,
        specific_force=frames.flu_to_frd(a),
        omega=frames.flu_to_frd(w),
        euler=euler,
        stamp_ns=ns,
    )
