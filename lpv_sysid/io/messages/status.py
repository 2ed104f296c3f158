"""The ``status`` topic: ``diagnostic_msgs/DiagnosticArray`` with one DiagnosticStatus per
node (level, name, message, values as text that parses back exactly)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from lpv_sysid.io.messages.factory import MessageError, MsgFactory
from lpv_sysid.io.messages.fields import header_msg, stamp_ns_of

DIAGNOSTIC_LEVELS = {"OK": 0, "WARN": 1, "ERROR": 2, "STALE": 3}


@dataclass(frozen=True)
class StatusSample:
    level: int
    name: str
    message: str
    values: dict
    hardware_id: str = ""


def _level(level) -> int:
    if isinstance(level, str):
        try:
            return DIAGNOSTIC_LEVELS[level.upper()]
        except KeyError:
            raise MessageError(
                f"status.level: unknown level {level!r}; expected one of {list(DIAGNOSTIC_LEVELS)}"
            ) from None
    if isinstance(level, (bytes, bytearray)):
        if len(level) != 1:
            raise MessageError(f"status.level: expected one byte, got {level!r}")
        level = level[0]
    lv = int(level)
    if lv not in DIAGNOSTIC_LEVELS.values():
        raise MessageError(f"status.level: {lv} is not one of OK=0, WARN=1, ERROR=2, STALE=3")
    return lv


def _value_text(v) -> str:
    if isinstance(v, bool) or v is None:
        return str(v).lower() if isinstance(v, bool) else ""
    if isinstance(v, (float, np.floating)):
        return repr(float(v))  # shortest round-trip representation
    return str(v)


def diagnostic_status(
    f: MsgFactory,
    level,
    name: str,
    message: str = "",
    values: Mapping[str, Any] | None = None,
    hardware_id: str = "",
):
    """``diagnostic_msgs/DiagnosticStatus`` from a level (0-3 or ``"OK"``/``"WARN"``/
    ``"ERROR"``/``"STALE"``), name, message and a dict of values (stored as text;
    floats with ``repr`` so they parse back exactly)."""
    kvs = [
        f("diagnostic_msgs/msg/KeyValue", key=str(k), value=_value_text(v))
        for k, v in (values or {}).items()
    ]
    return f(
        "diagnostic_msgs/msg/DiagnosticStatus",
        level=f.byte(_level(level)),
        name=str(name),
        message=str(message),
        hardware_id=str(hardware_id),
        values=kvs,
    )


def diagnostic_array(f: MsgFactory, stamp_ns: int, statuses: Sequence):
    return f(
        "diagnostic_msgs/msg/DiagnosticArray",
        header=header_msg(f, stamp_ns, ""),
        status=list(statuses),
    )


def status_from_diagnostic_array(msg):
    """``(t, [StatusSample, ...])``; values come back as the strings that were sent."""
    out = []
    for i, s in enumerate(msg.status):
        try:
            lv = _level(s.level)
        except MessageError as exc:
            raise MessageError(f"status.status[{i}]: {exc}") from None
        out.append(
            StatusSample(
                level=lv,
                name=s.name,
                message=s.message,
                values={kv.key: kv.value for kv in s.values},
                hardware_id=s.hardware_id,
            )
        )
    ns = stamp_ns_of(msg)
    return ns / 1e9, out
