"""``vehicle_record`` (std_msgs/String): the bridge's vehicle record as JSON.

The payload is ``{"clock_kind": KIND, "vehicle": RECORD}``: ``RECORD`` is what
``experiment.yaml`` stores under ``vehicle`` (written by
:meth:`lpv_sysid.mavlink.telemetry.VehicleRecord.summary`, the one format), its times on
the publisher's ROS clock, whose kind is ``KIND`` (``utc``: the system wall clock, epoch ns;
``ros_sim_time``: ``/clock``). JSON, not YAML: every value of the record (numbers, strings,
None, lists, mappings) round-trips exactly (floats by their shortest repr).
"""

from __future__ import annotations

import json
from typing import Any

from lpv_sysid.io.messages.factory import MessageError, MsgFactory

#: the kinds of clock a record's times can be on (the data logger's ``clock.kind``)
CLOCK_KINDS = ("utc", "ros_sim_time")


def vehicle_record_msg(f: MsgFactory, record: dict, clock_kind: str) -> Any:
    """The std_msgs/String of ``record`` (a ``vehicle`` mapping) on a ``clock_kind`` clock."""
    if clock_kind not in CLOCK_KINDS:
        raise MessageError(f"vehicle_record: clock_kind {clock_kind!r} not in {CLOCK_KINDS}")
    if not isinstance(record, dict):
        raise MessageError(f"vehicle_record: record must be a mapping, got {type(record)}")
    data = json.dumps({"clock_kind": clock_kind, "vehicle": record}, sort_keys=True)
    return f("std_msgs/msg/String", data=data)


def vehicle_record_from_msg(msg: Any) -> tuple[str, dict]:
    """``(clock_kind, record)`` of a ``vehicle_record`` message; MessageError naming the
    problem for anything else."""
    data = getattr(msg, "data", None)
    if not isinstance(data, str):
        raise MessageError("vehicle_record: not a std_msgs/String (no text 'data')")
    try:
        doc = json.loads(data)
    except ValueError as exc:
        raise MessageError(f"vehicle_record: data is not JSON ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("vehicle"), dict):
        raise MessageError("vehicle_record: data has no 'vehicle' mapping")
    kind = doc.get("clock_kind")
    if kind not in CLOCK_KINDS:
        raise MessageError(f"vehicle_record: clock_kind {kind!r} not in {CLOCK_KINDS}")
    return kind, doc["vehicle"]
