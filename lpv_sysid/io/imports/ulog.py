"""PX4 ULog (the SD-card / SITL ``log/`` file) -> :class:`FlightRecord` through pyulog.

Every logged uORB topic becomes a table (:mod:`~lpv_sysid.io.imports.uorb` maps them); the
log's info messages and parameters become the provenance: firmware (``ver_sw``,
``ver_sw_release``), board (``ver_hw``, ``sys_name``), airframe (``SYS_AUTOSTART``), the full
parameter snapshot at start, and the vehicle kind (:func:`vehicle_kind`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from lpv_sysid.errors import BagError
from lpv_sysid.io.imports.record import Event, FlightRecord
from lpv_sysid.io.imports.uorb import flight_from_uorb

#: uORB topics the importer reads (others are skipped while parsing)
TOPICS = (
    "vehicle_attitude",
    "vehicle_local_position",
    "vehicle_odometry",
    "vehicle_angular_velocity",
    "sensor_combined",
    "esc_status",
    "actuator_motors",
    "actuator_outputs",
    "trajectory_setpoint",
    "vehicle_rates_setpoint",
    "vehicle_status",
    "vehicle_gps_position",
    "sensor_gps",
    "battery_status",
    "home_position",
)
#: the kinds of vehicle a recording can come from (report labels)
VEHICLE_KINDS = ("SITL", "HITL", "SIH", "FLOWN", "SIMULATED")
#: ULog logging levels (syslog) -> status levels
_LEVELS = {0: "ERROR", 1: "ERROR", 2: "ERROR", 3: "ERROR", 4: "WARN"}


def firmware_release(value: Any) -> str | None:
    """``ver_sw_release`` (0xAABBCCTT: major, minor, patch, type; TT 255 = release) as
    ``vA.B.C`` (``-dev``/``-alpha``/``-beta``/``-rc`` for other types)."""
    try:
        v = int(value)
    except (TypeError, ValueError):
        return None
    if v <= 0:
        return None
    major, minor, patch, kind = (v >> 24) & 0xFF, (v >> 16) & 0xFF, (v >> 8) & 0xFF, v & 0xFF
    suffix = {255: "", 0: "-dev"}.get(kind)
    if suffix is None:
        suffix = "-alpha" if kind < 64 else "-beta" if kind < 128 else "-rc"
    return f"v{major}.{minor}.{patch}{suffix}"


def vehicle_kind(info: Mapping[str, Any], params: Mapping[str, Any]) -> str:
    """``SITL`` (PX4 built for the host: board ``PX4_SITL``), ``HITL`` (``SYS_HITL`` 1),
    ``SIH`` (simulation in hardware, ``SYS_HITL`` 2), else ``FLOWN``."""
    hw = f"{info.get('ver_hw', '')} {info.get('sys_name', '')}".upper()
    if "SITL" in hw:
        return "SITL"
    hitl = int(params.get("SYS_HITL", 0) or 0)
    return {1: "HITL", 2: "SIH"}.get(hitl, "FLOWN")


def _jsonable(v: Any) -> Any:
    if isinstance(v, (bytes, bytearray)):
        return v.decode("utf-8", "replace")
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating, float)):
        return float(v)
    if isinstance(v, (int, str, bool)) or v is None:
        return v
    return str(v)


def read_ulog(
    path: str | Path, rotor_config: Any = None, epoch_ns: int | None = None
) -> FlightRecord:
    """Read the ULog ``path`` (BagError naming it when pyulog cannot)."""
    try:
        import pyulog
    except ImportError:  # pinned in requirements.txt
        raise BagError("pyulog is not installed (requirements.txt pins it)") from None
    p = Path(path)
    if not p.is_file():
        raise BagError(f"{p}: no such ULog file")
    try:
        ulog = pyulog.ULog(str(p), list(TOPICS))
    except Exception as exc:  # noqa: BLE001 - pyulog raises plain exceptions on bad input
        raise BagError(f"{p}: not a readable ULog ({type(exc).__name__}: {exc})") from None
    tables: dict[str, dict[str, np.ndarray]] = {}
    for d in ulog.data_list:
        if d.multi_id != 0 and d.name in tables:
            continue  # first instance (e.g. actuator_outputs 0 = the main outputs)
        tables[d.name] = dict(d.data)
    rec = flight_from_uorb(tables, str(p), rotor_config, epoch_ns)
    info = {k: _jsonable(v) for k, v in ulog.msg_info_dict.items()}
    params = {k: _jsonable(v) for k, v in ulog.initial_parameters.items()}
    t_end = float(rec.state.t[-1])
    for m in ulog.logged_messages:
        rec.events.append(
            Event(m.timestamp * 1e-6, _LEVELS.get(int(m.log_level), "OK"), f"px4: {m.message}")
        )
    rec.events.sort(key=lambda e: e.t)
    changed = [
        {"t": round(ts * 1e-6, 6), "name": name, "value": _jsonable(val)}
        for ts, name, val in ulog.changed_parameters
        if ts * 1e-6 <= t_end + 1.0
    ]
    rec.provenance.update(
        {
            "source": {
                "kind": "px4_ulog",
                "file": p.name,
                "start_timestamp_us": int(ulog.start_timestamp),
                "last_timestamp_us": int(ulog.last_timestamp),
                "dropouts": len(ulog.dropouts),
            },
            "vehicle_kind": vehicle_kind(info, params),
            "firmware": {
                "ver_sw": info.get("ver_sw"),
                "release": firmware_release(info.get("ver_sw_release")),
                "ver_sw_branch": info.get("ver_sw_branch"),
                "sys_os_name": info.get("sys_os_name"),
            },
            "board": {"ver_hw": info.get("ver_hw"), "sys_name": info.get("sys_name")},
            "airframe": {
                "SYS_AUTOSTART": params.get("SYS_AUTOSTART"),
                "MAV_TYPE": params.get("MAV_TYPE"),
                "CA_AIRFRAME": params.get("CA_AIRFRAME"),
            },
            "px4_parameters": dict(sorted(params.items())),
            "px4_parameters_changed": changed,
            "ulog_info": info,
        }
    )
    return rec
