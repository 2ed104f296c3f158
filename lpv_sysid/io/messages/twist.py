"""``geometry_msgs/TwistStamped`` velocity references: the ``velocity_reference`` topic (body
velocity and yaw-rate reference, FLU on the wire) and the MAVROS ENU velocity setpoint."""

from __future__ import annotations

from lpv_sysid.io import frames
from lpv_sysid.io.messages.factory import MsgFactory
from lpv_sysid.io.messages.fields import (
    BASE_FRAME,
    check_frame,
    finite,
    header_msg,
    stamp_ns_of,
    vector3,
    xyz,
)


def twist_reference_msg(
    f: MsgFactory, stamp_ns: int, v_d_frd, r_d_frd: float = 0.0, *, frame_id: str = BASE_FRAME
):
    """``geometry_msgs/TwistStamped``: body velocity reference (FLU) and yaw-rate reference
    in ``angular.z`` (FLU, i.e. ``-r_d``)."""
    v = frames.frd_to_flu(finite(v_d_frd, 3, "velocity_reference.v_d"))
    r = finite([r_d_frd], 1, "velocity_reference.r_d")[0]
    w = frames.frd_to_flu([0.0, 0.0, r])
    twist = f("geometry_msgs/msg/Twist", linear=vector3(f, v), angular=vector3(f, w))
    return f(
        "geometry_msgs/msg/TwistStamped", header=header_msg(f, stamp_ns, frame_id), twist=twist
    )


def enu_velocity_setpoint_msg(
    f: MsgFactory, stamp_ns: int, v_enu, yaw_rate_enu: float, frame_id: str
):
    """``geometry_msgs/TwistStamped`` already in a local ENU frame (MAVROS
    ``setpoint_velocity/cmd_vel``): linear = ENU velocity, angular = (0, 0, ENU yaw rate).
    The NED/FRD -> ENU conversion happens before, through :mod:`lpv_sysid.io.frames`."""
    v = finite(v_enu, 3, "v_enu")
    r = finite([yaw_rate_enu], 1, "yaw_rate_enu")[0]
    return f(
        "geometry_msgs/msg/TwistStamped",
        header=header_msg(f, stamp_ns, frame_id),
        twist=f(
            "geometry_msgs/msg/Twist", linear=vector3(f, v), angular=vector3(f, [0.0, 0.0, r])
        ),
    )


def reference_from_twist(msg, *, frame_id: str | None = BASE_FRAME):
    """``(t, v_d_frd(3), r_d_frd)`` from a ``velocity_reference`` TwistStamped."""
    check_frame(msg.header.frame_id, frame_id, "velocity_reference.header")
    v = finite(xyz(msg.twist.linear), 3, "velocity_reference.twist.linear")
    w = finite(xyz(msg.twist.angular), 3, "velocity_reference.twist.angular")
    ns = stamp_ns_of(msg)
    return ns / 1e9, frames.flu_to_frd(v), float(frames.flu_to_frd(w)[2])
