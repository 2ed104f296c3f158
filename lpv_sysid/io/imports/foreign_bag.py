"""rosbag2 recordings made with other tools -> :class:`FlightRecord`: MAVROS bags
(``/mavros/...``) and PX4 uXRCE-DDS bags (``/fmu/out/...``, px4_msgs). Message types come
from the bag's own stored definitions (:func:`lpv_sysid.io.bag.read_bag`), so neither ROS
nor px4_msgs / mavros_msgs need to be installed.

px4_msgs messages carry the uORB fields, so a ``/fmu/out`` bag is flattened into uORB tables
and mapped by :mod:`~lpv_sysid.io.imports.uorb`, exactly like a ULog. MAVROS republishes in
ROS conventions (REP-103/105: ENU world, FLU body), converted here through
:mod:`lpv_sysid.io.frames` / :mod:`lpv_sysid.io.messages`:

==================================  ======================================================
MAVROS topic (any namespace)        package quantity
==================================  ======================================================
``local_position/odom``             ``state`` (nav_msgs/Odometry: ENU pose, FLU body twist)
``imu/data``                        ``imu``
``esc_status/status``               rotor speeds, measured (``esc_status[i].rpm``)
``rc/out``                          rotor speeds estimated from the PWM outputs (Eq. 8)
``setpoint_raw/target_local``,      velocity reference: the setpoint PX4 reports back
``setpoint_raw/local``,             (PositionTarget, ENU for frame 1, FLU body for 8), what
``setpoint_velocity/cmd_vel``       was sent, or a TwistStamped (ENU)
``setpoint_raw/target_attitude``    rate setpoint (AttitudeTarget ``body_rate`` FLU, ``thrust``)
``state``                           offboard segments (``mode == "OFFBOARD"``), events
==================================  ======================================================

MAVROS stamps its headers with the recording computer's ROS time, so the bag clock is that
computer's (``utc`` when it is wall-clock time).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lpv_sysid.errors import BagError
from lpv_sysid.io import frames
from lpv_sysid.io.imports.record import (
    Channels,
    Event,
    FlightRecord,
    StateSeries,
    segments,
)
from lpv_sysid.io.imports.uorb import flight_from_uorb, uorb_name

FLAVOURS = ("px4_msgs", "mavros")
#: PositionTarget.coordinate_frame values MAVROS uses
FRAME_LOCAL_NED, FRAME_BODY_NED, FRAME_BODY_OFFSET_NED = 1, 8, 9
#: a stamp above this (ns) is wall-clock time (2001-09-09), below it time since boot
EPOCH_THRESHOLD_NS = 1_000_000_000 * 1_000_000_000


def flavour_of(topics: Sequence[str]) -> str:
    """``px4_msgs`` (topics under ``/fmu/out``) or ``mavros`` (``.../mavros/...``)."""
    if any("/fmu/out/" in t for t in topics):
        return "px4_msgs"
    if any("/mavros/" in t or t.startswith("mavros/") for t in topics):
        return "mavros"
    raise BagError(
        f"bag with topics {sorted(topics)[:8]}: neither /fmu/out (px4_msgs) nor /mavros topics"
    )


def flatten(msg: Any, prefix: str = "", out: dict | None = None) -> dict[str, Any]:
    """Flattened fields of a rosbags message, pyulog style (``q[0]``, ``esc[2].esc_rpm``)."""
    out = {} if out is None else out
    for fld in dataclasses.fields(msg):
        if fld.name == "__msgtype__":
            continue
        v = getattr(msg, fld.name)
        key = f"{prefix}{fld.name}"
        if dataclasses.is_dataclass(v):
            flatten(v, key + ".", out)
        elif isinstance(v, np.ndarray):
            for i, x in enumerate(v.ravel()):
                out[f"{key}[{i}]"] = x
        elif isinstance(v, (list, tuple)):
            for i, x in enumerate(v):
                if dataclasses.is_dataclass(x):
                    flatten(x, f"{key}[{i}].", out)
                else:
                    out[f"{key}[{i}]"] = x
        else:
            out[key] = v
    return out


def _tables(data) -> dict[str, dict[str, np.ndarray]]:
    tables: dict[str, dict[str, np.ndarray]] = {}
    for topic, rows in data.items():
        if not rows:
            continue
        flat = [flatten(msg) for _, msg in rows]
        keys = [k for k in flat[0] if all(k in r for r in flat)]
        tab = {}
        for k in keys:
            try:
                tab[k] = np.array([r[k] for r in flat], dtype=float)
            except (TypeError, ValueError):
                continue  # strings
        if "timestamp" in flat[0]:
            tab["timestamp"] = np.array([r["timestamp"] for r in flat], dtype=np.int64)
        tables[uorb_name(topic)] = tab
    return tables


def read_foreign_bag(
    path: str | Path, rotor_config: Any = None, epoch_ns: int | None = None
) -> FlightRecord:
    """Read a MAVROS or ``/fmu/out`` px4_msgs rosbag2 directory."""
    from lpv_sysid.io import bag as iobag

    p = Path(path)
    if not p.is_dir():
        raise BagError(f"{p}: not a rosbag2 directory")
    topics = list(iobag.topic_info(str(p)))
    kind = flavour_of(topics)
    if kind == "px4_msgs":
        wanted = [t for t in topics if "/fmu/out/" in t]
        data = iobag.read_bag(str(p), topics=wanted)
        rec = flight_from_uorb(_tables(data), str(p), rotor_config, epoch_ns)
        rec.provenance["source"] = {"kind": "px4_msgs_bag", "path": p.name, "topics": wanted}
        return rec
    rec = _mavros(p, topics, rotor_config)
    rec.provenance["source"] = {"kind": "mavros_bag", "path": p.name, "topics": topics}
    return rec


def _find(topics: Sequence[str], *suffixes: str) -> str | None:
    for s in suffixes:
        for t in topics:
            if t.endswith("/mavros/" + s):
                return t
    return None


def _mavros(p: Path, topics: Sequence[str], rotor_config: Any) -> FlightRecord:
    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io import messages as m

    names = {
        "odom": _find(topics, "local_position/odom"),
        "imu": _find(topics, "imu/data"),
        "esc": _find(topics, "esc_status/status", "esc_status"),
        "rcout": _find(topics, "rc/out"),
        "sp": _find(
            topics,
            "setpoint_raw/target_local",
            "setpoint_raw/local",
            "setpoint_velocity/cmd_vel",
        ),
        "att_sp": _find(topics, "setpoint_raw/target_attitude"),
        "state": _find(topics, "state"),
    }
    if names["odom"] is None:
        raise BagError(f"{p}: MAVROS bag without local_position/odom (have {sorted(topics)})")
    data = iobag.read_bag(str(p), topics=[t for t in names.values() if t is not None])

    def stamps(topic: str) -> np.ndarray:
        return np.array([m.stamp_ns_of(msg) for _, msg in data[topic]], dtype=np.int64)

    odo = [
        m.state_from_odometry(msg, frame_id=None, child_frame_id=None)
        for _, msg in data[names["odom"]]
    ]
    if len(odo) < 2:
        raise BagError(f"{p}: fewer than 2 local_position/odom messages")
    base = min(int(s.stamp_ns) for s in odo)  # times relative to it: exact in float64

    def sec(ns) -> np.ndarray:
        return (np.asarray(ns, dtype=np.int64) - base) * 1e-9

    t = sec([s.stamp_ns for s in odo])
    order = np.argsort(t, kind="stable")
    state = StateSeries(
        t[order],
        np.array([s.pos_ned for s in odo])[order],
        np.array([s.euler for s in odo])[order],
        np.array([s.v_body for s in odo])[order],
        np.array([s.omega for s in odo])[order],
    )
    rec = FlightRecord(source=str(p), state=state)
    rec.clock = "utc" if base >= EPOCH_THRESHOLD_NS else "boot"
    rec.clock_offset_ns = base
    if names["imu"] is not None:
        imu = [m.imu_from_msg(msg, frame_id=None) for _, msg in data[names["imu"]]]
        rec.imu = Channels(
            sec([s.stamp_ns for s in imu]),
            np.array([[*s.specific_force, *s.omega] for s in imu]),
        )
    if names["esc"] is not None:
        rows = data[names["esc"]]
        rpm = np.array([[float(it.rpm) for it in msg.esc_status[:4]] for _, msg in rows])
        rec.rotors = Channels(sec(stamps(names["esc"])), np.abs(rpm) * 2.0 * np.pi / 60.0)
        rec.rotor_source = "esc"
    elif names["rcout"] is not None:
        from lpv_sysid.mavlink.telemetry import RotorEstimateConfig, RotorSpeedEstimator

        est = RotorSpeedEstimator.from_config(rotor_config or RotorEstimateConfig())
        rows = data[names["rcout"]]
        tr = sec(stamps(names["rcout"]))
        pwm = np.array([[float(c) for c in msg.channels[:4]] for _, msg in rows])
        rec.rotors = Channels(tr, np.array([est.update(float(a), b) for a, b in zip(tr, pwm)]))
        rec.rotor_source = "estimated"
    else:
        rec.notes.append("no esc_status/status or rc/out: no rotor_speeds")
    if names["sp"] is not None:
        rec.reference = _reference(data[names["sp"]], sec(stamps(names["sp"])), state)
    if names["att_sp"] is not None:
        rows = data[names["att_sp"]]
        y = np.array(
            [
                [
                    float(msg.thrust),
                    *frames.flu_to_frd([msg.body_rate.x, msg.body_rate.y, msg.body_rate.z]),
                ]
                for _, msg in rows
            ]
        )
        rec.rate_setpoint = Channels(sec(stamps(names["att_sp"])), y)
    if names["state"] is not None:
        rows = data[names["state"]]
        ts = sec(stamps(names["state"]))
        modes = [str(msg.mode) for _, msg in rows]
        armed = [bool(msg.armed) for _, msg in rows]
        prev = None
        for ti, mode, a in zip(ts, modes, armed):
            if (mode, a) != prev:
                rec.events.append(
                    Event(
                        float(ti),
                        "OK",
                        f"px4 {mode} {'ARMED' if a else 'DISARMED'}",
                        {"mode": mode},
                    )
                )
                prev = (mode, a)
        rec.offboard = segments(ts, np.array([md == "OFFBOARD" for md in modes]), float(t[-1]))
    return rec


def _reference(rows, t: np.ndarray, state: StateSeries) -> Channels | None:
    """Velocity setpoints (PositionTarget or TwistStamped) -> ``[u_d, v_d, w_d, r_d]`` FRD in
    the heading frame."""
    yaw = np.interp(t, state.t, np.unwrap(state.euler[:, 2]))
    out = []
    for k, (_, msg) in enumerate(rows):
        if hasattr(msg, "coordinate_frame"):
            v = np.array([msg.velocity.x, msg.velocity.y, msg.velocity.z], float)
            r_flu = float(msg.yaw_rate)
            frame = int(msg.coordinate_frame)
        else:  # TwistStamped, local ENU
            v = np.array([msg.twist.linear.x, msg.twist.linear.y, msg.twist.linear.z], float)
            r_flu = float(msg.twist.angular.z)
            frame = FRAME_LOCAL_NED
        if frame in (FRAME_BODY_NED, FRAME_BODY_OFFSET_NED):
            v_d = frames.flu_to_frd(v)
        else:
            v_d = frames.world_to_body(frames.enu_to_ned(v), [0.0, 0.0, yaw[k]])
        out.append([*v_d, -r_flu if np.isfinite(r_flu) else 0.0])
    y = np.array(out, dtype=float)
    good = np.all(np.isfinite(y), axis=1)
    return Channels(t[good], y[good]) if np.any(good) else None
