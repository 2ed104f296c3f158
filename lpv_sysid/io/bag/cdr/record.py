"""One serialized ``nav_msgs/msg/Odometry`` record decoded without building the message: the
high-rate state input of the controller (a raw rclpy subscription hands its callback the CDR
bytes; issue 27 measured rclpy's own deserialisation at 124 us per Odometry, 72 of its 85
doubles covariance that nothing here reads).

The record (XCDR1 as ROS 2 writes it: a 4-byte encapsulation header, then alignment counted
from its end): ``header.stamp`` (int32 sec, uint32 nanosec), ``header.frame_id`` and
``child_frame_id`` (uint32 length with the terminating NUL, the bytes, 4-byte aligned), then
8-byte aligned ``pose.pose.position`` (3 float64), ``pose.pose.orientation`` (x, y, z, w),
``pose.covariance`` (36, skipped), ``twist.twist.linear`` (3), ``twist.twist.angular`` (3),
``twist.covariance`` (36, skipped). Little- and big-endian encapsulations are read; anything
else, or a record too short for its strings, is refused with :class:`LayoutError` (the caller
then deserialises it the ordinary way, which names the problem).
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from lpv_sysid.io.bag.cdr.layout import LayoutError

#: encapsulation identifier (bytes 0-1) -> struct byte order: CDR_BE, CDR_LE (plain XCDR1)
_ORDERS = {b"\x00\x00": ">", b"\x00\x01": "<"}
_STAMP = {o: struct.Struct(o + "iI") for o in _ORDERS.values()}
_U32 = {o: struct.Struct(o + "I") for o in _ORDERS.values()}
# position 3, orientation 4, pose covariance 36 (skipped), linear 3, angular 3
_BODY = {o: struct.Struct(o + "7d288x6d") for o in _ORDERS.values()}
_COVARIANCE_TAIL = 36 * 8  # twist.covariance after the angular rate


class OdometryRecord(NamedTuple):
    """The fields of a serialized Odometry the state input reads (ROS frames, as sent)."""

    sec: int
    nanosec: int
    frame_id: str
    child_frame_id: str
    values: tuple  # position x y z, orientation x y z w, linear x y z, angular x y z (13)


def _string(data: bytes, pos: int, order: str) -> tuple[str, int]:
    """(text, next position) of the CDR string whose length word is at ``pos`` (aligned)."""
    pos += -(pos - 4) % 4
    (n,) = _U32[order].unpack_from(data, pos)
    end = pos + 4 + n
    if n == 0 or end > len(data) or data[end - 1] != 0:
        raise LayoutError(f"Odometry record: bad string of length {n} at byte {pos}")
    return data[pos + 4 : end - 1].decode("utf-8"), end


def odometry_record(data: bytes) -> OdometryRecord:
    """The :class:`OdometryRecord` of one serialized ``nav_msgs/msg/Odometry`` (module
    docstring); LayoutError when the bytes are not such a record."""
    try:
        order = _ORDERS[bytes(data[:2])]
        sec, nanosec = _STAMP[order].unpack_from(data, 4)
        frame_id, pos = _string(data, 12, order)
        child, pos = _string(data, pos, order)
        pos += -(pos - 4) % 8
        body = _BODY[order]
        if pos + body.size + _COVARIANCE_TAIL > len(data):
            raise LayoutError(f"Odometry record: {len(data)} bytes, too short")
        return OdometryRecord(sec, nanosec, frame_id, child, body.unpack_from(data, pos))
    except (KeyError, struct.error, UnicodeDecodeError) as exc:
        raise LayoutError(f"Odometry record: not a CDR nav_msgs/Odometry ({exc})") from None
