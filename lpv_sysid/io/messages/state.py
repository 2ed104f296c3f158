"""The ``state`` topic: ``nav_msgs/Odometry`` <-> the vehicle state in core frames (NED
position, Euler angles, FRD body velocity and rates), one message at a time or a whole
recording as arrays."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from lpv_sysid.io import frames
from lpv_sysid.io.messages.factory import MessageError, MsgFactory
from lpv_sysid.io.messages.fields import (
    BASE_FRAME,
    ODOM_FRAME,
    check_frame,
    covariance,
    finite,
    header_msg,
    point,
    quaternion,
    stamp_ns_from_time,
    stamp_ns_of,
    vector3,
    xyz,
)


@dataclass(frozen=True)
class StateSample:
    """Vehicle state in core frames: NED position (m), Euler ``[phi, theta, psi]`` (rad,
    seed 0 Eq. 1), FRD body velocity ``[u, v, w]`` (m/s), FRD body rates ``[p, q, r]``."""

    t: float
    pos_ned: np.ndarray
    euler: np.ndarray
    v_body: np.ndarray
    omega: np.ndarray
    stamp_ns: int = 0


def odometry_from_state(
    f: MsgFactory,
    stamp_ns: int,
    pos_ned,
    euler,
    v_body,
    omega,
    *,
    frame_id: str = ODOM_FRAME,
    child_frame_id: str = BASE_FRAME,
    pose_covariance=None,
    twist_covariance=None,
):
    """``nav_msgs/Odometry`` for the ``state`` topic from NED/FRD core quantities."""
    pos = frames.ned_to_enu(finite(pos_ned, 3, "state.pos_ned"))
    q = frames.ros_orientation_from_euler(finite(euler, 3, "state.euler"))
    v = frames.frd_to_flu(finite(v_body, 3, "state.v_body"))
    w = frames.frd_to_flu(finite(omega, 3, "state.omega"))
    pose = f("geometry_msgs/msg/Pose", position=point(f, pos), orientation=quaternion(f, q))
    twist = f("geometry_msgs/msg/Twist", linear=vector3(f, v), angular=vector3(f, w))
    return f(
        "nav_msgs/msg/Odometry",
        header=header_msg(f, stamp_ns, frame_id),
        child_frame_id=str(child_frame_id),
        pose=f(
            "geometry_msgs/msg/PoseWithCovariance",
            pose=pose,
            covariance=covariance(f, pose_covariance, 6, "state.pose.covariance"),
        ),
        twist=f(
            "geometry_msgs/msg/TwistWithCovariance",
            twist=twist,
            covariance=covariance(f, twist_covariance, 6, "state.twist.covariance"),
        ),
    )


#: the TF topic (tf2's convention: absolute, one tree per ROS domain)
TF_TOPIC = "/tf"


def tf_from_odometry(f: MsgFactory, odom):
    """The REP-105 transform of a ``state`` message: ``tf2_msgs/TFMessage`` with one
    ``geometry_msgs/TransformStamped`` from the Odometry's ``header.frame_id`` (``odom``) to
    its ``child_frame_id`` (``base_link``), stamped like it: translation = the ENU position,
    rotation = the ENU/FLU orientation (RViz and Foxglove place the vehicle with it)."""
    p, q = odom.pose.pose.position, odom.pose.pose.orientation
    transform = f(
        "geometry_msgs/msg/Transform",
        translation=vector3(f, (p.x, p.y, p.z)),
        rotation=quaternion(f, (q.x, q.y, q.z, q.w)),
    )
    tf = f(
        "geometry_msgs/msg/TransformStamped",
        header=header_msg(f, stamp_ns_of(odom), odom.header.frame_id),
        child_frame_id=str(odom.child_frame_id),
        transform=transform,
    )
    return f("tf2_msgs/msg/TFMessage", transforms=[tf])


def state_from_odometry(
    msg, *, frame_id: str | None = ODOM_FRAME, child_frame_id: str | None = BASE_FRAME
) -> StateSample:
    """Core state from a ``nav_msgs/Odometry`` (``None`` skips a frame check)."""
    check_frame(msg.header.frame_id, frame_id, "state.header")
    check_frame(msg.child_frame_id, child_frame_id, "state.child_frame_id")
    p, tw = msg.pose.pose, msg.twist.twist
    pp, o, tl, ta = p.position, p.orientation, tw.linear, tw.angular
    vals = (pp.x, pp.y, pp.z, o.x, o.y, o.z, o.w, tl.x, tl.y, tl.z, ta.x, ta.y, ta.z)
    try:
        f = [float(c) for c in vals]
    except (TypeError, ValueError):
        f = None
    if f is not None and _plain(f):
        return _fast_sample(f, stamp_ns_of(msg))
    # validating path: names the offending field
    pos = finite(xyz(p.position), 3, "state.pose.pose.position")
    o = p.orientation
    q = finite([o.x, o.y, o.z, o.w], 4, "state.pose.pose.orientation")
    if abs(np.linalg.norm(q) - 1.0) > 1e-3:
        raise MessageError(
            f"state.pose.pose.orientation: not a unit quaternion (norm {np.linalg.norm(q):.6g})"
        )
    v = finite(xyz(tw.linear), 3, "state.twist.twist.linear")
    w = finite(xyz(tw.angular), 3, "state.twist.twist.angular")
    ns = stamp_ns_of(msg)
    return StateSample(
        t=ns / 1e9,
        pos_ned=frames.enu_to_ned(pos),
        euler=frames.euler_from_ros_orientation(q),
        v_body=frames.flu_to_frd(v),
        omega=frames.flu_to_frd(w),
        stamp_ns=ns,
    )


def _plain(f: list) -> bool:
    """Every value finite and the quaternion (``f[3:7]``) of unit norm within 1e-3: the fast
    path's condition (anything else takes the validating path, which names the field)."""
    return (
        all(map(math.isfinite, f))
        and abs(math.sqrt(f[3] * f[3] + f[4] * f[4] + f[5] * f[5] + f[6] * f[6]) - 1.0) <= 1e-3
    )


def _fast_sample(f: Sequence[float], ns: int) -> StateSample:
    """The fast path (the controller's state rate): plain floats through io.frames."""
    pos_ned, euler, v_frd, w_frd = frames.odometry_ned_frd_from_ros_scalar(
        f[0:3], f[3:7], f[7:10], f[10:13]
    )
    return StateSample(
        t=ns / 1e9,
        pos_ned=np.array(pos_ned),
        euler=np.array(euler),
        v_body=np.array(v_frd),
        omega=np.array(w_frd),
        stamp_ns=ns,
    )


def odometry_cdr_frames(
    data: bytes, *, frame_id: str | None = ODOM_FRAME, child_frame_id: str | None = BASE_FRAME
) -> tuple[int, tuple, tuple, tuple, tuple] | None:
    """``(stamp_ns, pos_ned, euler, v_frd, w_frd)`` (float tuples) of a serialized
    ``nav_msgs/Odometry`` (a raw subscription's bytes), reading only the 13 values it needs
    (:func:`lpv_sysid.io.bag.cdr.odometry_record`) through the fast path of
    :func:`state_from_odometry`: the same numbers, the same frame and stamp checks
    (MessageError). ``None`` when the message needs the validating path (a non-finite value,
    a quaternion off unit norm, bytes that are no CDR Odometry record): the caller
    deserialises it and calls :func:`state_from_odometry`, which names the problem."""
    from lpv_sysid.io.bag.cdr import LayoutError, odometry_record  # the node's path only

    try:
        rec = odometry_record(data)
    except LayoutError:
        return None
    check_frame(rec.frame_id, frame_id, "state.header")
    check_frame(rec.child_frame_id, child_frame_id, "state.child_frame_id")
    f = list(rec.values)
    if not _plain(f):
        return None
    if not 0 <= rec.nanosec < 1_000_000_000:
        raise MessageError(f"stamp: nanosec {rec.nanosec} outside [0, 1e9)")
    ns = rec.sec * 1_000_000_000 + rec.nanosec
    return (ns, *frames.odometry_ned_frd_from_ros_scalar(f[0:3], f[3:7], f[7:10], f[10:13]))


def state_from_odometry_cdr(
    data: bytes, *, frame_id: str | None = ODOM_FRAME, child_frame_id: str | None = BASE_FRAME
) -> StateSample | None:
    """:func:`state_from_odometry` of the serialized message (:func:`odometry_cdr_frames`;
    ``None``: take the validating path)."""
    got = odometry_cdr_frames(data, frame_id=frame_id, child_frame_id=child_frame_id)
    if got is None:
        return None
    ns, pos_ned, euler, v_frd, w_frd = got
    return StateSample(
        t=ns / 1e9,
        pos_ned=np.array(pos_ned),
        euler=np.array(euler),
        v_body=np.array(v_frd),
        omega=np.array(w_frd),
        stamp_ns=ns,
    )


@dataclass(frozen=True)
class StateArrays:
    """A time series of :class:`StateSample` as arrays: ``t`` (N,) s, ``stamp_ns`` (N,)
    int64, ``pos_ned``, ``euler``, ``v_body``, ``omega`` (N, 3)."""

    t: np.ndarray
    stamp_ns: np.ndarray
    pos_ned: np.ndarray
    euler: np.ndarray
    v_body: np.ndarray
    omega: np.ndarray


def states_from_odometry(
    msgs: Sequence, *, frame_id: str | None = ODOM_FRAME, child_frame_id: str | None = BASE_FRAME
) -> StateArrays:
    """Vectorised :func:`state_from_odometry` for a list of messages (bag replay): the
    fields are gathered in one pass and converted with array operations. Errors name the
    index of the offending message."""
    n = len(msgs)
    ns = np.empty(n, dtype=np.int64)
    raw = np.empty((n, 13))
    for i, msg in enumerate(msgs):
        if frame_id is not None and msg.header.frame_id != frame_id:
            raise MessageError(
                f"state[{i}].header: expected frame_id {frame_id!r}, got {msg.header.frame_id!r}",
                row=i,
            )
        if child_frame_id is not None and msg.child_frame_id != child_frame_id:
            raise MessageError(
                f"state[{i}].child_frame_id: expected frame_id {child_frame_id!r}, "
                f"got {msg.child_frame_id!r}",
                row=i,
            )
        p, o = msg.pose.pose.position, msg.pose.pose.orientation
        lin, ang = msg.twist.twist.linear, msg.twist.twist.angular
        raw[i] = (p.x, p.y, p.z, o.x, o.y, o.z, o.w, lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
        ns[i] = stamp_ns_from_time(msg.header.stamp)
    return state_arrays(ns, raw)


#: Odometry leaves in the order of the (N, 13) array :func:`state_arrays` converts
ODOM_LEAVES = (
    "pose.pose.position.x",
    "pose.pose.position.y",
    "pose.pose.position.z",
    "pose.pose.orientation.x",
    "pose.pose.orientation.y",
    "pose.pose.orientation.z",
    "pose.pose.orientation.w",
    "twist.twist.linear.x",
    "twist.twist.linear.y",
    "twist.twist.linear.z",
    "twist.twist.angular.x",
    "twist.twist.angular.y",
    "twist.twist.angular.z",
)


def state_arrays(ns: np.ndarray, raw: np.ndarray) -> StateArrays:
    """:class:`StateArrays` of stamps ``ns`` and the (N, 13) Odometry values
    ``raw`` (:data:`ODOM_LEAVES`), checked finite and unit-quaternion row by row
    (:class:`MessageError` naming the first bad row, ``row`` set)."""
    bad = ~np.isfinite(raw)
    if np.any(bad):
        i, j = (int(k) for k in np.argwhere(bad)[0])
        where = ODOM_LEAVES[j].rsplit(".", 1)[0]
        raise MessageError(f"state[{i}].{where}: non-finite value", row=i)
    norm = np.linalg.norm(raw[:, 3:7], axis=1)
    off = np.abs(norm - 1.0) > 1e-3
    if np.any(off):
        i = int(np.argmax(off))
        raise MessageError(
            f"state[{i}].pose.pose.orientation: not a unit quaternion (norm {norm[i]:.6g})",
            row=i,
        )
    return StateArrays(
        t=ns / 1e9,
        stamp_ns=ns,
        pos_ned=frames.enu_to_ned(raw[:, 0:3]),
        euler=frames.euler_from_ros_orientation(raw[:, 3:7]),
        v_body=frames.flu_to_frd(raw[:, 7:10]),
        omega=frames.flu_to_frd(raw[:, 10:13]),
    )
