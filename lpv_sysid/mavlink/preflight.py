"""Preflight go/no-go checks of a PX4 vehicle over MAVLink (used by ``lpv-sysid preflight``).

The checks gather, within a bounded time: an autopilot HEARTBEAT (link, autopilot type,
vehicle type, mode, arming state), AUTOPILOT_VERSION (firmware >= 1.14, MAVLink 2 and the
offboard setpoint capabilities), the parameters the safety path depends on and the
telemetry streams the bridge needs. Each check is GO, WARN (does not block) or NO-GO.

Parameter rules (PX4 v1.16):
- COM_OF_LOSS_T in (0, 2] s (offboard-loss detection delay; PX4 default 1 s);
- COM_OBL_RC_ACT in {0 Position, 1 Altitude, 3 Return, 4 Land, 5 Hold}: NO-GO for
  2 Manual (no pilot input in an offboard experiment), 6 Terminate, 7 Disarm;
- COM_DISARM_PRFLT > 0 (pre-flight auto disarm enabled) else WARN;
- NAV_DLL_ACT, COM_RCL_EXCEPT, COM_RC_IN_MODE reported (informational).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Callable

from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.link import MavlinkLink

GO, WARN, NOGO = "GO", "WARN", "NO-GO"
REQUIRED_PARAMS = ("COM_OF_LOSS_T", "COM_OBL_RC_ACT")
INFO_PARAMS = ("COM_DISARM_PRFLT", "NAV_DLL_ACT", "COM_RCL_EXCEPT", "COM_RC_IN_MODE")
MIN_VERSION = (1, 14)
MULTIROTOR_TYPES = {2: "quadrotor", 3: "coaxial", 4: "helicopter", 13: "hexarotor", 14: "octorotor",
                    15: "tricopter"}
TELEMETRY = ("ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "HIGHRES_IMU", "ESC_STATUS")


@dataclass(frozen=True)
class Check:
    name: str
    value: str
    expected: str
    verdict: str


def run_checks(link: MavlinkLink, timeout: float = 5.0, clock: Callable[[], float] = time.monotonic,
               sleep: Callable[[float], None] = time.sleep) -> list[Check]:
    """Gather the facts (at most ``timeout`` seconds of polling) and judge them."""
    t0 = clock()
    hb: Any = None
    version: Any = None
    params: dict[str, float | int] = {}
    seen: set[str] = set()
    next_req = t0
    streams_requested = False
    mod = link.dialect_module
    while True:
        now = clock()
        if now - t0 > timeout:
            break
        for m in link.poll(now):
            mt = m.get_type()
            if mt == "HEARTBEAT" and m.get_srcSystem() == link.target_system and m.autopilot != 8:
                hb = m
            elif mt == "AUTOPILOT_VERSION":
                version = m
            elif mt == "PARAM_VALUE":
                name = px4.param_id_str(m.param_id)
                params[name] = px4.param_from_wire(m.param_value, m.param_type)
            seen.add(mt)
        link.step(now)
        if hb is not None and now >= next_req:
            next_req = now + 0.5
            if version is None:
                link.command_long(512, float(mod.MAVLINK_MSG_ID_AUTOPILOT_VERSION))
            for name in REQUIRED_PARAMS + INFO_PARAMS:
                if name not in params:
                    link.send(link.codec.param_request_read_encode(
                        link.target_system, link.target_component, name.encode("ascii"), -1))
            if not streams_requested:
                link.request_streams()
                streams_requested = True
        done = (hb is not None and version is not None
                and all(p in params for p in REQUIRED_PARAMS + INFO_PARAMS)
                and all(s in seen for s in TELEMETRY))
        if done:
            break
        sleep(0.005)
    return judge(hb, version, params, seen, link)


def judge(hb: Any, version: Any, params: dict[str, float | int], seen: set[str],
          link: MavlinkLink | None = None) -> list[Check]:
    """Turn the gathered facts into checks (pure; tested without a vehicle)."""
    out: list[Check] = []
    if hb is None:
        out.append(Check("link", "no autopilot HEARTBEAT", "HEARTBEAT received", NOGO))
        return out
    out.append(Check("link", f"HEARTBEAT from system {hb.get_srcSystem()}", "HEARTBEAT received", GO))
    if link is not None:
        st = link.stats
        bad = st.bad_data + st.truncated
        out.append(Check("link quality", f"{st.rx_messages} msgs, {bad} bad, {st.seq_lost} lost",
                         "no corrupted data", GO if bad == 0 else WARN))
        if link.codec is not None and link.codec.signing.secret_key is not None:
            good = link.codec.signing.goodsig_count
            out.append(Check("signing", f"{good} good / {link.codec.signing.badsig_count} bad signatures",
                             "vehicle signs its messages", GO if good > 0 else NOGO))
    out.append(Check("autopilot", "PX4" if hb.autopilot == 12 else f"MAV_AUTOPILOT {hb.autopilot}",
                     "PX4", GO if hb.autopilot == 12 else NOGO))
    vt = MULTIROTOR_TYPES.get(hb.type)
    out.append(Check("vehicle type", vt or f"MAV_TYPE {hb.type}", "multirotor", GO if vt else NOGO))
    mode = px4.decode_custom_mode(hb.custom_mode)
    armed = bool(hb.base_mode & px4.MAV_MODE_FLAG_SAFETY_ARMED)
    known = not mode.name.startswith("UNKNOWN")
    out.append(Check("mode", mode.name, "known PX4 mode, not OFFBOARD",
                     GO if known and mode != px4.OFFBOARD else NOGO))
    out.append(Check("armed", "armed" if armed else "disarmed", "disarmed", NOGO if armed else GO))
    if version is None:
        out.append(Check("firmware", "no AUTOPILOT_VERSION", f"PX4 >= {MIN_VERSION[0]}.{MIN_VERSION[1]}", NOGO))
    else:
        major, minor, patch, _ = px4.decode_flight_sw_version(version.flight_sw_version)
        ok = (major, minor) >= MIN_VERSION
        out.append(Check("firmware", f"{major}.{minor}.{patch}", f">= {MIN_VERSION[0]}.{MIN_VERSION[1]}",
                         GO if ok else NOGO))
        mod = px4.dialect_module()
        caps = version.capabilities
        for cname in ("MAVLINK2", "SET_POSITION_TARGET_LOCAL_NED", "SET_ATTITUDE_TARGET"):
            bit = int(getattr(mod, f"MAV_PROTOCOL_CAPABILITY_{cname}"))
            out.append(Check(f"capability {cname}", "yes" if caps & bit else "no", "yes",
                             GO if caps & bit else NOGO))
    t = params.get("COM_OF_LOSS_T")
    if t is None:
        out.append(Check("COM_OF_LOSS_T", "missing", "0 < t <= 2 s", NOGO))
    else:
        out.append(Check("COM_OF_LOSS_T", f"{float(t):g} s", "0 < t <= 2 s",
                         GO if 0 < float(t) <= 2.0 and math.isfinite(float(t)) else NOGO))
    a = params.get("COM_OBL_RC_ACT")
    if a is None:
        out.append(Check("COM_OBL_RC_ACT", "missing", "Position/Altitude/Return/Land/Hold", NOGO))
    else:
        try:
            name = px4.OblAction(int(a)).name
        except ValueError:
            name = f"invalid ({a})"
        ok = int(a) in (0, 1, 3, 4, 5)
        out.append(Check("COM_OBL_RC_ACT", f"{int(a)} ({name})", "Position/Altitude/Return/Land/Hold",
                         GO if ok else NOGO))
    d = params.get("COM_DISARM_PRFLT")
    out.append(Check("COM_DISARM_PRFLT", "missing" if d is None else f"{float(d):g} s", "> 0 s",
                     GO if d is not None and float(d) > 0 else WARN))
    for name in ("NAV_DLL_ACT", "COM_RCL_EXCEPT", "COM_RC_IN_MODE"):
        v = params.get(name)
        out.append(Check(name, "missing" if v is None else f"{v}", "(information)", GO if v is not None else WARN))
    for s in TELEMETRY:
        need = NOGO if s in ("ATTITUDE_QUATERNION", "LOCAL_POSITION_NED") else WARN
        out.append(Check(f"telemetry {s}", "received" if s in seen else "not received", "received",
                         GO if s in seen else need))
    return out


def verdict(checks: list[Check]) -> bool:
    return all(c.verdict != NOGO for c in checks)


def format_table(checks: list[Check]) -> str:
    w0 = max(len(c.name) for c in checks)
    w1 = max(len(c.value) for c in checks)
    w2 = max(len(c.expected) for c in checks)
    lines = [f"{'check':<{w0}}  {'value':<{w1}}  {'expected':<{w2}}  verdict",
             f"{'-' * w0}  {'-' * w1}  {'-' * w2}  -------"]
    lines += [f"{c.name:<{w0}}  {c.value:<{w1}}  {c.expected:<{w2}}  {c.verdict}" for c in checks]
    return "\n".join(lines)
