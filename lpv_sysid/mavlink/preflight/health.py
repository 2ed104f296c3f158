"""The vehicle's health and limits against the planned flight: battery (SYS_STATUS), GPS fix
(GPS_RAW_INT), EKF2 (ESTIMATOR_STATUS), home position (HOME_POSITION) -- over MAVROS the
same facts from its topics (:mod:`~lpv_sysid.mavlink.preflight.mavros`) -- and PX4's velocity and
tilt limits (MPC_XY_VEL_MAX, MPC_Z_VEL_MAX_UP, MPC_Z_VEL_MAX_DN, MPC_TILTMAX_AIR) against
what the box asks (:class:`~lpv_sysid.control.campaign.FlightDemands`).

Rules (PX4 v1.16):
- battery: ``battery_remaining`` >= the charge the plan needs (worst-case use + reserve,
  :class:`~lpv_sysid.control.campaign.FlightBudget`; without a plan: the reserve alone),
  NO-GO below; unknown (-1, no SYS_STATUS): NO-GO;
- GPS: a 3D fix (``fix_type`` >= 3) GO (satellites shown unless 255, unknown); without
  one, GO is left to the EKF check (indoor flight on vision / flow: WARN when the EKF has
  a relative horizontal position), NO-GO when the EKF has no horizontal position either;
- EKF: attitude, horizontal and vertical velocity, relative horizontal position and
  vertical position valid, no GPS glitch or accelerometer error flag, else NO-GO (the
  velocity loop of PX4 and the bridge's state both come from it);
- home: HOME_POSITION received, else NO-GO (the envelope's floor, ceiling and geofence are
  heights and distances from home);
- limits: each parameter >= the plan's demand, else NO-GO with the value that flies the
  box; PX4 would otherwise clip the commanded velocity or tilt and the vertex is never
  reached (settle timeout) -- or, for MPC_TILTMAX_AIR, the excitation not flown as designed.
"""

from __future__ import annotations

import math
from typing import Any

from lpv_sysid.control.campaign import BATTERY_RESERVE_PCT, FlightDemands
from lpv_sysid.mavlink.preflight.gather import Facts
from lpv_sysid.mavlink.preflight.report import GO, NOGO, WARN, Check

#: ESTIMATOR_STATUS flags (MAVLink ESTIMATOR_STATUS_FLAGS) the flight needs
EKF_NEEDED = {
    1: "attitude",
    2: "horizontal velocity",
    4: "vertical velocity",
    8: "relative horizontal position",
    32: "vertical position",
}
EKF_BAD = {1024: "GPS glitch", 2048: "accelerometer error"}
EKF_HORIZ_POS = 8 | 16  # relative | absolute horizontal position

#: parameter -> (FlightDemands field, unit, what it limits)
LIMITS = {
    "MPC_XY_VEL_MAX": ("horizontal_speed", "m/s", "horizontal speed"),
    "MPC_Z_VEL_MAX_UP": ("climb_speed", "m/s", "climb speed"),
    "MPC_Z_VEL_MAX_DN": ("descent_speed", "m/s", "descent speed"),
    "MPC_TILTMAX_AIR": ("tilt_deg", "deg", "tilt"),
}


def health_checks(
    facts: Facts, demands: FlightDemands | None = None, battery_needed_pct: float | None = None
) -> list[Check]:
    """Battery, GPS, EKF, home and the PX4 limits (module docstring); ``demands`` and
    ``battery_needed_pct`` come from the plan (None: ``lpv-sysid preflight`` without one)."""
    return [
        _battery(facts.battery, battery_needed_pct),
        _gps(facts.gps, facts.estimator),
        _ekf(facts.estimator),
        _home(facts.home),
        *_limits(facts.params, demands),
    ]


def _battery(battery: Any, needed: float | None) -> Check:
    need = BATTERY_RESERVE_PCT if needed is None else needed
    expected = f">= {need:.0f} %" + (" (plan + reserve)" if needed is not None else " (reserve)")
    if battery is None or int(battery.battery_remaining) < 0:
        return Check(
            "battery",
            "unknown",
            expected,
            NOGO,
            "no battery state (none received, or remaining -1)",
            missing=battery is None,
        )
    pct = int(battery.battery_remaining)
    value = f"{pct} % ({battery.voltage_battery / 1000:.2f} V)"
    if pct < need:
        fix = (
            "charge or swap the battery, or fly fewer runs (campaign.vertices) "
            "(`lpv-sysid fly phase1 --dry-run` prints the estimate)"
        )
        if need > 100:
            fix = "the plan needs more than one battery: split it (campaign.vertices)"
        return Check("battery", value, expected, NOGO, f"{pct} % < {need:.0f} %: {fix}")
    return Check("battery", value, expected, GO)


def _gps(gps: Any, est: Any) -> Check:
    expected = "3D fix"
    if gps is not None and int(gps.fix_type) >= 3:
        sats = int(gps.satellites_visible)  # 255: unknown (GPS_RAW_INT)
        value = f"fix type {int(gps.fix_type)}" + (f", {sats} sats" if sats != 255 else "")
        return Check("GPS", value, expected, GO)
    value = "no GPS_RAW_INT" if gps is None else f"fix type {int(gps.fix_type)} (no 3D fix)"
    if est is not None and int(est.flags) & EKF_HORIZ_POS:
        return Check(
            "GPS",
            value,
            expected,
            WARN,
            "no GPS fix, but the EKF has a horizontal position (vision / flow): fine indoors",
            missing=gps is None,
        )
    return Check(
        "GPS",
        value,
        expected,
        NOGO,
        "no GPS fix and no other horizontal position: wait for a fix",
        missing=gps is None,
    )


def _ekf(est: Any) -> Check:
    expected = "attitude, velocity, position valid"
    if est is None:
        return Check(
            "EKF", "no ESTIMATOR_STATUS", expected, NOGO, "EKF health unknown", missing=True
        )
    flags = int(est.flags)
    missing = [name for bit, name in EKF_NEEDED.items() if not flags & bit]
    bad = [name for bit, name in EKF_BAD.items() if flags & bit]
    if missing or bad:
        what = "; ".join(
            x for x in (f"not valid: {', '.join(missing)}" if missing else "", ", ".join(bad)) if x
        )
        return Check(
            "EKF",
            f"flags 0x{flags:x}",
            expected,
            NOGO,
            f"EKF2: {what}; wait for the estimator to converge (QGC: Estimator status)",
        )
    return Check("EKF", f"flags 0x{flags:x} (healthy)", expected, GO)


def _home(home: Any) -> Check:
    if home is None:
        return Check(
            "home position",
            "not set",
            "set",
            NOGO,
            "no HOME_POSITION: the envelope's floor, ceiling and geofence are relative to "
            "home; wait until PX4 sets it (GPS / EKF origin)",
            missing=True,
        )
    lat, lon, alt = home.latitude * 1e-7, home.longitude * 1e-7, home.altitude * 1e-3
    return Check("home position", f"{lat:.6f}, {lon:.6f}, {alt:.1f} m", "set", GO)


def _limits(params: dict, demands: FlightDemands | None) -> list[Check]:
    out = []
    for name, (key, unit, what) in LIMITS.items():
        v = params.get(name)
        if demands is None:
            text = "missing" if v is None else f"{float(v):g} {unit}"
            out.append(
                Check(
                    name, text, "(information)", GO if v is not None else WARN, missing=v is None
                )
            )
            continue
        need = getattr(demands, key)
        expected = f">= {need:.2f} {unit}"
        if v is None or not math.isfinite(float(v)):
            out.append(
                Check(
                    name,
                    "missing",
                    expected,
                    NOGO,
                    f"cannot check the {what} limit",
                    missing=v is None,
                )
            )
        elif float(v) + 1e-6 < need:
            fix = math.ceil(need * 10.0) / 10.0
            out.append(
                Check(
                    name,
                    f"{float(v):g} {unit}",
                    expected,
                    NOGO,
                    f"the planned box needs {what} {need:.2f} {unit}; PX4 would clip it: "
                    f"`param set {name} {fix:g}` (or --set-param {name}={fix:g}), or shrink "
                    "the box",
                )
            )
        else:
            out.append(Check(name, f"{float(v):g} {unit}", expected, GO))
    return out
