"""PX4 uORB topics -> :class:`~lpv_sysid.io.imports.record.FlightRecord`: the one mapping
shared by the ULog importer (every uORB topic as logged) and the ``/fmu/out`` px4_msgs bag
importer (the same topics over uXRCE-DDS; px4_msgs fields are the uORB fields).

Input: ``{topic: {field: array}}`` with uORB topic names and flattened field names as
pyulog gives them (``q[0]`` .. ``q[3]``, ``esc[2].esc_rpm``); ``timestamp`` in microseconds
since PX4 booted. Frames: uORB is NED world / FRD body already (PX4 conventions), so no
ENU/FLU conversion is involved; quaternions are ``(w, x, y, z)`` body -> NED.

================================  =============================================================
package quantity                   uORB source (first present wins)
================================  =============================================================
attitude                          ``vehicle_attitude.q``, ``vehicle_odometry.q``
body velocity                     ``vehicle_local_position.v[xyz]`` (NED, rotated to FRD),
                                  ``vehicle_odometry.velocity`` (``velocity_frame`` 1 NED, 3 FRD)
body rates                        ``vehicle_angular_velocity.xyz``,
                                  ``vehicle_odometry.angular_velocity``,
                                  ``sensor_combined.gyro_rad``
position                          ``vehicle_local_position.[xyz]``, ``vehicle_odometry.position``
imu                               ``sensor_combined`` (``accelerometer_m_s2``, ``gyro_rad``)
rotor speeds                      ``esc_status.esc[i].esc_rpm`` (measured), else the motor outputs
                                  ``actuator_motors.control`` (0..1) or ``actuator_outputs.output``
                                  (PWM) through seed 0 Eq. (8)
velocity reference                ``trajectory_setpoint.velocity`` (NED) rotated by the yaw,
                                  ``yawspeed``
rate setpoint                     ``vehicle_rates_setpoint`` (``roll, pitch, yaw``, thrust
                                  ``-thrust_body[2]``)
offboard segments, events         ``vehicle_status.nav_state`` (14: offboard), ``arming_state``
wall clock                        ``vehicle_gps_position`` / ``sensor_gps`` ``time_utc_usec``
battery                           ``battery_status`` (``voltage_v``, ``remaining``) first / last
site                              ``home_position`` (``lat``, ``lon``, ``alt`` AMSL; ``x y z``
                                  local NED) first valid and last
================================  =============================================================

Times are taken from ``timestamp_sample`` where a topic has it (when the data were sampled),
else ``timestamp``.
"""

from __future__ import annotations

import logging
import math
import re
from typing import Any, Mapping

import numpy as np

from lpv_sysid.errors import BagError
from lpv_sysid.io import frames
from lpv_sysid.io.imports.record import (
    Channels,
    Event,
    FlightRecord,
    StateSeries,
    interp_rows,
    segments,
)

log = logging.getLogger(__name__)

Tables = Mapping[str, Mapping[str, np.ndarray]]

NAV_STATE_OFFBOARD = 14
#: vehicle_status.nav_state names (PX4 v1.14+ ``VehicleStatus.msg``)
NAV_STATES = {
    0: "MANUAL",
    1: "ALTCTL",
    2: "POSCTL",
    3: "AUTO_MISSION",
    4: "AUTO_LOITER",
    5: "AUTO_RTL",
    10: "ACRO",
    12: "DESCEND",
    13: "TERMINATION",
    14: "OFFBOARD",
    15: "STAB",
    17: "AUTO_TAKEOFF",
    18: "AUTO_LAND",
    19: "AUTO_FOLLOW_TARGET",
    20: "AUTO_PRECLAND",
    21: "ORBIT",
    22: "AUTO_VTOL_TAKEOFF",
}
ARMING_STATES = {1: "DISARMED", 2: "ARMED"}
VELOCITY_FRAME_NED, VELOCITY_FRAME_FRD = 1, 3
RPM_TO_RAD_S = 2.0 * math.pi / 60.0


def uorb_name(topic: str) -> str:
    """``/fmu/out/vehicle_status_v1`` -> ``vehicle_status`` (the uORB topic a DDS topic
    carries; PX4 >= 1.16 appends a message version)."""
    name = topic.rstrip("/").split("/")[-1]
    return re.sub(r"_v\d+$", "", name)


def times(table: Mapping[str, np.ndarray]) -> np.ndarray:
    """Sample times (s since boot) of a uORB table."""
    key = "timestamp_sample" if "timestamp_sample" in table else "timestamp"
    t = np.asarray(table[key], dtype=float)
    if key == "timestamp_sample":  # 0 where a publisher leaves it unset
        t = np.where(t > 0, t, np.asarray(table["timestamp"], float))
    return t * 1e-6


def vec(table: Mapping[str, np.ndarray], name: str, n: int) -> np.ndarray:
    """Field ``name`` of ``n`` elements as an (N, n) array (``name`` or ``name[i]`` keys)."""
    if name in table:
        a = np.asarray(table[name], dtype=float)
        return a.reshape(a.shape[0], -1)[:, :n]
    keys = [f"{name}[{i}]" for i in range(n)]
    missing = [k for k in keys if k not in table]
    if missing:
        raise BagError(f"uORB field {name}: missing {missing[:3]}")
    return np.column_stack([np.asarray(table[k], dtype=float) for k in keys])


def _first(tables: Tables, *names: str) -> tuple[str, Mapping[str, np.ndarray]] | None:
    for n in names:
        tab = tables.get(n)
        if tab is not None and len(np.asarray(tab.get("timestamp", ()))) >= 2:
            return n, tab
    return None


def _sorted(t: np.ndarray, *ys: np.ndarray):
    order = np.argsort(t, kind="stable")
    t = t[order]
    keep = np.r_[True, np.diff(t) > 0]
    return (t[keep], *(y[order][keep] for y in ys))


def state_of(tables: Tables, where: str) -> StateSeries:
    """The ``state`` series on the attitude's time base (other sources linearly
    interpolated onto it)."""
    att = _first(tables, "vehicle_attitude", "vehicle_odometry")
    if att is None:
        raise BagError(f"{where}: no attitude (vehicle_attitude or vehicle_odometry)")
    t, q = _sorted(times(att[1]), vec(att[1], "q", 4))
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    euler = frames.euler_from_quaternion(q)
    # velocity
    lp = _first(tables, "vehicle_local_position")
    odo = _first(tables, "vehicle_odometry")
    if lp is not None:
        tv, v_ned = _sorted(times(lp[1]), vec_fields(lp[1], ("vx", "vy", "vz")))
        v_body = frames.world_to_body(interp_rows(t, tv, v_ned), euler)
        tp, p_ned = _sorted(times(lp[1]), vec_fields(lp[1], ("x", "y", "z")))
        pos = interp_rows(t, tp, p_ned)
    elif odo is not None:
        tab = odo[1]
        tv, v, fr = _sorted(
            times(tab),
            vec(tab, "velocity", 3),
            np.asarray(tab.get("velocity_frame", np.full(len(tab["timestamp"]), 1)), float),
        )
        v = interp_rows(t, tv, v)
        frame = int(fr[0]) if fr.size else VELOCITY_FRAME_NED
        if frame == VELOCITY_FRAME_FRD:
            v_body = v
        elif frame == VELOCITY_FRAME_NED:
            v_body = frames.world_to_body(v, euler)
        else:
            raise BagError(f"{where}: vehicle_odometry.velocity_frame {frame} not supported")
        tp, p = _sorted(times(tab), vec(tab, "position", 3))
        pos = interp_rows(t, tp, p)
    else:
        raise BagError(f"{where}: no velocity (vehicle_local_position or vehicle_odometry)")
    # rates
    rate_src = _first(tables, "vehicle_angular_velocity")
    if rate_src is not None:
        tw, w = _sorted(times(rate_src[1]), vec(rate_src[1], "xyz", 3))
    elif odo is not None:
        tw, w = _sorted(times(odo[1]), vec(odo[1], "angular_velocity", 3))
    elif _first(tables, "sensor_combined") is not None:
        sc = tables["sensor_combined"]
        tw, w = _sorted(times(sc), vec(sc, "gyro_rad", 3))
    else:
        raise BagError(f"{where}: no body rates (vehicle_angular_velocity, ...)")
    omega = interp_rows(t, tw, w)
    good = np.all(np.isfinite(np.column_stack([pos, euler, v_body, omega])), axis=1)
    if not np.all(good):
        log.info("%s: %d state sample(s) with NaN dropped", where, int(np.sum(~good)))
    return StateSeries(t[good], pos[good], euler[good], v_body[good], omega[good])


def vec_fields(table: Mapping[str, np.ndarray], names) -> np.ndarray:
    missing = [n for n in names if n not in table]
    if missing:
        raise BagError(f"uORB fields missing: {missing}")
    return np.column_stack([np.asarray(table[n], dtype=float) for n in names])


def imu_of(tables: Tables) -> Channels | None:
    sc = _first(tables, "sensor_combined")
    if sc is None:
        return None
    t, a, w = _sorted(
        np.asarray(sc[1]["timestamp"], float) * 1e-6,
        vec(sc[1], "accelerometer_m_s2", 3),
        vec(sc[1], "gyro_rad", 3),
    )
    y = np.column_stack([a, w])
    good = np.all(np.isfinite(y), axis=1)
    return Channels(t[good], y[good])


def rotors_of(tables: Tables, rotor_config: Any = None) -> tuple[Channels, str] | None:
    """Omega_1..4 (rad/s): measured (``esc_status``, any rpm non-zero) or estimated from the
    motor outputs with :class:`~lpv_sysid.mavlink.telemetry.RotorSpeedEstimator`."""
    esc = _first(tables, "esc_status")
    if esc is not None:
        tab = esc[1]
        try:
            rpm = np.column_stack([np.asarray(tab[f"esc[{i}].esc_rpm"], float) for i in range(4)])
        except KeyError:
            rpm = None
        if rpm is not None and np.any(rpm != 0):
            t, r = _sorted(np.asarray(tab["timestamp"], float) * 1e-6, rpm)
            return Channels(t, np.abs(r) * RPM_TO_RAD_S), "esc"
    from lpv_sysid.mavlink.telemetry import RotorEstimateConfig, RotorSpeedEstimator

    motors = _first(tables, "actuator_motors")
    outputs = _first(tables, "actuator_outputs")
    if motors is not None:
        cfg = rotor_config or RotorEstimateConfig(mapping="normalized")
        tab, key = motors[1], "control"
    elif outputs is not None:
        cfg = rotor_config or RotorEstimateConfig()
        tab, key = outputs[1], "output"
    else:
        return None
    t, u = _sorted(np.asarray(tab["timestamp"], float) * 1e-6, vec(tab, key, 4))
    est = RotorSpeedEstimator.from_config(cfg)
    omega = np.array([est.update(float(ti), ui) for ti, ui in zip(t, u)])
    return Channels(t, omega), "estimated"


def reference_of(tables: Tables, state: StateSeries) -> Channels | None:
    """``[u_d, v_d, w_d, r_d]``: PX4's velocity setpoint (NED) in the heading frame."""
    ts = _first(tables, "trajectory_setpoint")
    if ts is None:
        return None
    tab = ts[1]
    t, v = _sorted(np.asarray(tab["timestamp"], float) * 1e-6, vec(tab, "velocity", 3))
    r = np.asarray(tab.get("yawspeed", np.zeros(len(tab["timestamp"]))), float)
    r = _sorted(np.asarray(tab["timestamp"], float) * 1e-6, r)[1]
    good = np.all(np.isfinite(v), axis=1)
    if not np.any(good):
        return None
    t, v, r = t[good], v[good], np.where(np.isfinite(r[good]), r[good], 0.0)
    psi = np.unwrap(state.euler[:, 2])
    yaw = np.interp(t, state.t, psi)
    heading = np.column_stack([np.zeros_like(yaw), np.zeros_like(yaw), yaw])
    v_d = frames.world_to_body(v, heading)
    return Channels(t, np.column_stack([v_d, r]))


def rate_setpoint_of(tables: Tables) -> Channels | None:
    rs = _first(tables, "vehicle_rates_setpoint")
    if rs is None:
        return None
    tab = rs[1]
    t, pqr, thr = _sorted(
        np.asarray(tab["timestamp"], float) * 1e-6,
        vec_fields(tab, ("roll", "pitch", "yaw")),
        vec(tab, "thrust_body", 3)[:, 2],
    )
    y = np.column_stack([-thr, pqr])
    good = np.all(np.isfinite(y), axis=1)
    return Channels(t[good], y[good])


def status_of(tables: Tables, t_end: float) -> tuple[list[Event], list[tuple[float, float]]]:
    """Events at every nav_state / arming_state change and the offboard segments."""
    vs = _first(tables, "vehicle_status")
    if vs is None:
        return [], []
    tab = vs[1]
    t = np.asarray(tab["timestamp"], float) * 1e-6
    nav = np.asarray(tab.get("nav_state", np.zeros(t.size)), int)
    arm = np.asarray(tab.get("arming_state", np.zeros(t.size)), int)
    t, nav, arm = _sorted(t, nav, arm)
    events = []
    prev = None
    for ti, n, a in zip(t, nav, arm):
        if (n, a) != prev:
            name = NAV_STATES.get(int(n), str(int(n)))
            armed = ARMING_STATES.get(int(a), str(int(a)))
            events.append(
                Event(
                    float(ti),
                    "OK",
                    f"px4 {name} {armed}",
                    {"nav_state": int(n), "arming_state": int(a)},
                )
            )
            prev = (n, a)
    return events, segments(t, nav == NAV_STATE_OFFBOARD, t_end)


def utc_offset_us(tables: Tables) -> int | None:
    """``time_utc_usec - timestamp`` of the first GPS sample with a UTC time."""
    for name in ("vehicle_gps_position", "sensor_gps"):
        tab = tables.get(name)
        if tab is None or "time_utc_usec" not in tab:
            continue
        utc = np.asarray(tab["time_utc_usec"], dtype=np.int64)
        ts = np.asarray(tab["timestamp"], dtype=np.int64)
        ok = np.nonzero(utc > 0)[0]
        if ok.size:
            return int(utc[ok[0]] - ts[ok[0]])
    return None


def battery_of(tables: Tables) -> dict | None:
    bat = _first(tables, "battery_status")
    if bat is None:
        return None
    tab = bat[1]
    out = {}
    for key in ("voltage_v", "remaining"):
        if key in tab:
            a = np.asarray(tab[key], float)
            out[key] = {"start": float(a[0]), "end": float(a[-1])}
    return out or None


def site_of(tables: Tables) -> dict | None:
    """The site: PX4's home position (``home_position``: WGS-84 ``lat``/``lon`` deg, ``alt``
    m AMSL, local NED ``x y z`` m) -- the first one with a valid global position, and how far
    the last one moved from it (a home reset in flight)."""
    tab = tables.get("home_position")
    if tab is None or "lat" not in tab or "lon" not in tab:
        return None
    lat, lon = np.asarray(tab["lat"], float), np.asarray(tab["lon"], float)
    alt = np.asarray(tab.get("alt", np.full(lat.shape, np.nan)), float)
    ok = np.isfinite(lat) & np.isfinite(lon) & ((lat != 0.0) | (lon != 0.0))
    if "valid_hpos" in tab:
        ok &= np.asarray(tab["valid_hpos"]).astype(bool)
    idx = np.nonzero(ok)[0]
    if not idx.size:
        return None
    i, j = int(idx[0]), int(idx[-1])
    local = [float(np.asarray(tab[k], float)[i]) if k in tab else None for k in "xyz"]
    return {
        "source": "px4 home_position",
        "latitude_deg": float(lat[i]),
        "longitude_deg": float(lon[i]),
        "altitude_amsl_m": float(alt[i]),
        "local_ned_m": local,
        "t_s": round(float(times(tab)[i]), 6),
        "updates": int(idx.size),
        "last": {
            "latitude_deg": float(lat[j]),
            "longitude_deg": float(lon[j]),
            "altitude_amsl_m": float(alt[j]),
        },
    }


def flight_from_uorb(
    tables: Tables, source: str, rotor_config: Any = None, epoch_ns: int | None = None
) -> FlightRecord:
    """The :class:`FlightRecord` of uORB ``tables``. The bag clock: UTC from the GPS time
    when the log has it, else ``epoch_ns`` (declared epoch of the boot), else boot time."""
    state = state_of(tables, source)
    if state.t.size < 2:
        raise BagError(f"{source}: fewer than 2 state samples")
    rot = rotors_of(tables, rotor_config)
    events, offboard = status_of(tables, float(state.t[-1]))
    rec = FlightRecord(
        source=source,
        state=state,
        imu=imu_of(tables),
        rotors=None if rot is None else rot[0],
        rotor_source="esc" if rot is None else rot[1],
        reference=reference_of(tables, state),
        rate_setpoint=rate_setpoint_of(tables),
        events=events,
        offboard=offboard,
    )
    if rot is None:
        rec.notes.append("no esc_status, actuator_motors or actuator_outputs: no rotor_speeds")
    off = utc_offset_us(tables)
    if off is not None:
        rec.clock_offset_ns, rec.clock = off * 1000, "utc"
    elif epoch_ns is not None:
        rec.clock_offset_ns, rec.clock = int(epoch_ns), "declared"
    battery = battery_of(tables)
    if battery is not None:
        rec.provenance["battery"] = battery
    site = site_of(tables)
    if site is not None:
        rec.provenance["site"] = site
    return rec
