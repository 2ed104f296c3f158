"""Building blocks of every message family: frame ids, stamps and headers, and the checked
conversions of numeric fields (finite values, vectors, quaternions, covariances)."""

from __future__ import annotations

import math

import numpy as np

from lpv_sysid.io.messages.factory import MessageError, MsgFactory

ODOM_FRAME = "odom"
BASE_FRAME = "base_link"
_INT32 = (-(2**31), 2**31 - 1)


def finite(values, n: int | None, what: str) -> np.ndarray:
    try:
        a = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise MessageError(f"{what}: not numeric: {values!r}") from None
    if n is not None and a.size != n:
        raise MessageError(f"{what}: expected {n} values, got {a.size}")
    bad = ~np.isfinite(a)
    if bad.any():
        raise MessageError(f"{what}: non-finite value(s) at index {np.flatnonzero(bad).tolist()}")
    return a


def xyz(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=float)


def vector3(f: MsgFactory, v):
    return f("geometry_msgs/msg/Vector3", x=float(v[0]), y=float(v[1]), z=float(v[2]))


def point(f: MsgFactory, v):
    return f("geometry_msgs/msg/Point", x=float(v[0]), y=float(v[1]), z=float(v[2]))


def quaternion(f: MsgFactory, q_xyzw):
    return f(
        "geometry_msgs/msg/Quaternion",
        x=float(q_xyzw[0]),
        y=float(q_xyzw[1]),
        z=float(q_xyzw[2]),
        w=float(q_xyzw[3]),
    )


def covariance(f: MsgFactory, cov, n: int, what: str):
    if cov is None:
        return f.float_array(np.zeros(n * n))
    c = np.asarray(cov, dtype=float)
    if c.size != n * n:
        raise MessageError(f"{what}: expected {n}x{n} = {n * n} values, got {c.size}")
    return f.float_array(c.reshape(-1))


def check_frame(actual: str, expected: str | None, what: str) -> None:
    if expected is not None and actual != expected:
        raise MessageError(f"{what}: expected frame_id {expected!r}, got {actual!r}")


# -------------------------------------------------------------------------- stamps
def time_msg(f: MsgFactory, stamp_ns: int):
    """``builtin_interfaces/Time`` of integer nanoseconds (``nanosec`` in [0, 1e9))."""
    if isinstance(stamp_ns, float):
        if not math.isfinite(stamp_ns):
            raise MessageError(f"stamp: non-finite time {stamp_ns!r}")
        stamp_ns = round(stamp_ns)
    ns = int(stamp_ns)
    sec, nanosec = divmod(ns, 1_000_000_000)
    if not _INT32[0] <= sec <= _INT32[1]:
        raise MessageError(f"stamp: {ns} ns does not fit builtin_interfaces/Time (int32 seconds)")
    return f("builtin_interfaces/msg/Time", sec=int(sec), nanosec=int(nanosec))


def stamp_ns_from_time(t) -> int:
    """Integer nanoseconds of a ``builtin_interfaces/Time``."""
    sec, nanosec = int(t.sec), int(t.nanosec)
    if not 0 <= nanosec < 1_000_000_000:
        raise MessageError(f"stamp: nanosec {nanosec} outside [0, 1e9)")
    return sec * 1_000_000_000 + nanosec


def stamp_ns_of(msg) -> int:
    """Integer nanoseconds of ``msg.header.stamp``."""
    return stamp_ns_from_time(msg.header.stamp)


def clock_msg(f: MsgFactory, stamp_ns: int):
    """``rosgraph_msgs/Clock`` of integer nanoseconds (``/clock``, ``lockstep_ack``)."""
    return f("rosgraph_msgs/msg/Clock", clock=time_msg(f, stamp_ns))


def clock_ns_of(msg) -> int:
    """Integer nanoseconds of a ``rosgraph_msgs/Clock``."""
    return stamp_ns_from_time(msg.clock)


def header_msg(f: MsgFactory, stamp_ns: int, frame_id: str = ""):
    return f("std_msgs/msg/Header", stamp=time_msg(f, stamp_ns), frame_id=str(frame_id))
