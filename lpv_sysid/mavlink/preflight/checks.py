"""The preflight checks (:func:`run_checks`) and their verdicts (:func:`judge`); the method is
the :mod:`lpv_sysid.mavlink.preflight` docstring."""

from __future__ import annotations

import math
import time
from typing import Any, Callable

from lpv_sysid.mavlink import codec, px4
from lpv_sysid.mavlink.link import MavlinkLink
from lpv_sysid.control.campaign import FlightDemands
from lpv_sysid.mavlink.preflight.gather import Facts, gather
from lpv_sysid.mavlink.preflight.health import health_checks
from lpv_sysid.mavlink.preflight.report import GO, NOGO, WARN, Check
from lpv_sysid.mavlink.preflight.rules import _obl_check, _rotor_check, _sticks
from lpv_sysid.mavlink.telemetry import ATTITUDE_SOURCES, POSITION_SOURCES, RotorEstimateConfig

MIN_VERSION = (1, 14)
MULTIROTOR_TYPES = {
    2: "quadrotor",
    3: "coaxial",
    4: "helicopter",
    13: "hexarotor",
    14: "octorotor",
    15: "tricopter",
}


def run_checks(
    link: MavlinkLink,
    timeout: float = 5.0,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    grace: float = 1.5,
    rotor_estimate: RotorEstimateConfig | None = None,
    demands: FlightDemands | None = None,
    battery_needed_pct: float | None = None,
) -> list[Check]:
    """Gather the facts (at most ``timeout`` s; ends once all are in, or ``grace`` s after
    the stream requests when only possibly-absent streams are missing) and judge them;
    ``demands`` / ``battery_needed_pct``: what the planned flight asks (health.py)."""
    facts = gather(link, timeout, clock, sleep, grace)
    return judge(
        facts.hb,
        facts.version,
        facts.params,
        facts.seen,
        link,
        facts=facts,
        rotor_estimate=rotor_estimate,
        demands=demands,
        battery_needed_pct=battery_needed_pct,
    )


def judge(
    hb: Any,
    version: Any,
    params: dict[str, float | int],
    seen: set[str],
    link: MavlinkLink | None = None,
    *,
    facts: Facts | None = None,
    rotor_estimate: RotorEstimateConfig | None = None,
    demands: FlightDemands | None = None,
    battery_needed_pct: float | None = None,
) -> list[Check]:
    """Turn the gathered facts into checks (pure; tested without a vehicle). ``demands`` /
    ``battery_needed_pct``: what the planned flight asks (health.py: the PX4 limits the box
    needs, NO-GO naming the parameter and the value to set)."""
    if facts is None:
        facts = Facts(hb=hb, version=version, params=dict(params), seen=set(seen))
    cfg = rotor_estimate or RotorEstimateConfig()
    out: list[Check] = []
    if link is not None and getattr(link, "ambiguous_target", False):
        out.append(
            Check(
                "link",
                f"autopilots of systems {sorted(link.autopilots_heard)} heard with "
                "link.target_system 0",
                "one autopilot, or link.target_system set",
                NOGO,
            )
        )
        return out
    if hb is None:
        out.append(
            Check("link", "no autopilot HEARTBEAT", "HEARTBEAT received", NOGO, missing=True)
        )
        return out
    out.append(
        Check("link", f"HEARTBEAT from system {hb.get_srcSystem()}", "HEARTBEAT received", GO)
    )
    if link is not None:
        st = link.stats
        bad = st.bad_data + st.truncated
        out.append(
            Check(
                "link quality",
                f"{st.rx_messages} msgs, {bad} bad, {st.seq_lost} lost",
                "no corrupted data",
                GO if bad == 0 else WARN,
            )
        )
        if link.codec is not None and link.codec.signing.secret_key is not None:
            good = link.codec.signing.goodsig_count
            out.append(
                Check(
                    "signing",
                    f"{good} good / {link.codec.signing.badsig_count} bad signatures",
                    "vehicle signs its messages",
                    GO if good > 0 else NOGO,
                )
            )
    if facts.foreign:
        txt = ", ".join(f"system {s} comp {c}: {n}" for (s, c), n in sorted(facts.foreign.items()))
        out.append(
            Check(
                "other systems",
                txt,
                "telemetry only from the target",
                WARN,
                "vehicle-state messages from other systems on this link; the bridge ignores them "
                "(telemetry is taken from the target system/component only)",
            )
        )
    out.append(
        Check(
            "autopilot",
            "PX4" if hb.autopilot == 12 else f"MAV_AUTOPILOT {hb.autopilot}",
            "PX4",
            GO if hb.autopilot == 12 else NOGO,
        )
    )
    vt = MULTIROTOR_TYPES.get(hb.type)
    out.append(
        Check("vehicle type", vt or f"MAV_TYPE {hb.type}", "multirotor", GO if vt else NOGO)
    )
    mode = px4.decode_custom_mode(hb.custom_mode)
    armed = bool(hb.base_mode & px4.MAV_MODE_FLAG_SAFETY_ARMED)
    known = not mode.name.startswith("UNKNOWN")
    if mode == px4.OFFBOARD and not armed:
        out.append(
            Check(
                "mode",
                "OFFBOARD (disarmed: stale)",
                "known PX4 mode, not OFFBOARD",
                WARN,
                "PX4 keeps reporting OFFBOARD after an auto-disarm; no offboard session is "
                "active. "
                "Not a reason for NO-GO: the bridge switches to OFFBOARD itself after "
                "pre-streaming",
            )
        )
    elif mode == px4.OFFBOARD:
        out.append(
            Check(
                "mode",
                "OFFBOARD (armed)",
                "known PX4 mode, not OFFBOARD",
                NOGO,
                "another offboard controller is flying the vehicle",
            )
        )
    else:
        out.append(Check("mode", mode.name, "known PX4 mode, not OFFBOARD", GO if known else NOGO))
    out.append(Check("armed", "armed" if armed else "disarmed", "disarmed", NOGO if armed else GO))
    if version is None:
        out.append(
            Check(
                "firmware",
                "no AUTOPILOT_VERSION",
                f"PX4 >= {MIN_VERSION[0]}.{MIN_VERSION[1]}",
                NOGO,
                missing=True,
            )
        )
    else:
        major, minor, patch, _ = px4.decode_flight_sw_version(version.flight_sw_version)
        ok = (major, minor) >= MIN_VERSION
        out.append(
            Check(
                "firmware",
                f"{major}.{minor}.{patch}",
                f">= {MIN_VERSION[0]}.{MIN_VERSION[1]}",
                GO if ok else NOGO,
            )
        )
        mod = codec.dialect_module()
        caps = version.capabilities
        for cname in ("MAVLINK2", "SET_POSITION_TARGET_LOCAL_NED", "SET_ATTITUDE_TARGET"):
            bit = int(getattr(mod, f"MAV_PROTOCOL_CAPABILITY_{cname}"))
            out.append(
                Check(
                    f"capability {cname}",
                    "yes" if caps & bit else "no",
                    "yes",
                    GO if caps & bit else NOGO,
                )
            )
    t = params.get("COM_OF_LOSS_T")
    if t is None:
        out.append(Check("COM_OF_LOSS_T", "missing", "0 < t <= 2 s", NOGO, missing=True))
    else:
        out.append(
            Check(
                "COM_OF_LOSS_T",
                f"{float(t):g} s",
                "0 < t <= 2 s",
                GO if 0 < float(t) <= 2.0 and math.isfinite(float(t)) else NOGO,
            )
        )
    sticks, sticks_txt = _sticks(facts)
    out.append(Check("stick input", sticks_txt, "(see COM_OBL_RC_ACT)", GO))
    out.append(_obl_check(params.get("COM_OBL_RC_ACT"), sticks, sticks_txt))
    d = params.get("COM_DISARM_PRFLT")
    out.append(
        Check(
            "COM_DISARM_PRFLT",
            "missing" if d is None else f"{float(d):g} s",
            "> 0 s",
            GO if d is not None and float(d) > 0 else WARN,
            missing=d is None,
        )
    )
    out += health_checks(facts, demands, battery_needed_pct)
    for name in ("NAV_DLL_ACT", "COM_RCL_EXCEPT", "COM_RC_IN_MODE"):
        v = params.get(name)
        text = "missing" if v is None else f"{v}"
        if name == "COM_RC_IN_MODE" and v is not None and int(v) in set(px4.RcInMode):
            text = f"{int(v)} ({px4.RcInMode(int(v)).name.lower().replace('_', ' ')})"
        out.append(
            Check(name, text, "(information)", GO if v is not None else WARN, missing=v is None)
        )
    for quantity, sources in (("attitude", ATTITUDE_SOURCES), ("position", POSITION_SOURCES)):
        have = [s for s in sources if s in seen]
        if not have:
            out.append(
                Check(
                    f"telemetry {quantity}",
                    "not received",
                    sources[0],
                    NOGO,
                    f"none of {', '.join(sources)}: no state for the bridge",
                    missing=True,
                )
            )
        elif have[0] != sources[0]:
            out.append(
                Check(
                    f"telemetry {quantity}",
                    f"{have[0]} (no {sources[0]})",
                    sources[0],
                    WARN,
                    f"the bridge falls back to {have[0]}",
                )
            )
        else:
            out.append(Check(f"telemetry {quantity}", sources[0], sources[0], GO))
    out.append(
        Check(
            "telemetry HIGHRES_IMU",
            "received" if "HIGHRES_IMU" in seen else "not received",
            "received",
            GO if "HIGHRES_IMU" in seen else WARN,
            missing="HIGHRES_IMU" not in seen,
        )
    )
    out.append(_rotor_check(facts, cfg))
    return out
