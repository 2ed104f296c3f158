"""Preflight go/no-go checks of a PX4 vehicle over MAVLink (used by ``lpv-sysid preflight``).

The checks gather, within a bounded time: an autopilot HEARTBEAT (link, autopilot type,
vehicle type, mode, arming state), AUTOPILOT_VERSION (firmware >= 1.14, MAVLink 2 and the
offboard setpoint capabilities), the parameters the safety path depends on, the
telemetry streams the bridge needs, the evidence of stick input (SYS_STATUS, RC_CHANNELS)
and the source of the rotor speeds (ESC_STATUS, else the motor outputs). Each check is
GO, WARN (does not block) or NO-GO; a check may carry a note with the reason and the fix.

Gathering ends as soon as every answer is in. Streams that may legitimately be absent
(ESC_STATUS on SIH / PWM vehicles, RC_CHANNELS without RC, HIGHRES_IMU) are waited for at
most ``grace`` seconds after the stream requests, never for the whole timeout.

Rules (PX4 v1.16, ``commander_params.c``):
- COM_OF_LOSS_T in (0, 2] s (offboard-loss detection delay; PX4 default 1 s);
- COM_OBL_RC_ACT, the action after offboard loss: 0 Position, 1 Altitude, 2 Stabilized,
  3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm. Position, Altitude and Stabilized fly
  on the pilot's sticks (``px4.STICK_MODES``): without stick input PX4 cannot run them
  ("Matching flight task was not able to run") and descends without position control
  (measured on PX4 v1.16 SIH: 17.6 m to the ground with 0, altitude held within 0.3 m
  with 5). They are NO-GO when there is no stick input; 2 is WARN even with sticks (the
  pilot must fly at once). 6 and 7 stop the motors in the air: NO-GO. 3, 4, 5: GO.
- stick input: none when COM_RC_IN_MODE = 4 (stick input disabled); else PX4's own
  verdict in SYS_STATUS (MAV_SYS_STATUS_SENSOR_RC_RECEIVER present = valid manual control
  from RC or joystick) when received, else RC_CHANNELS with channels and RSSI > 0;
- mode: OFFBOARD while disarmed is PX4's leftover after an auto-disarm (the commander
  keeps the last mode): WARN, not a reason for NO-GO (the bridge switches the mode itself
  after pre-streaming). OFFBOARD while armed means another controller flies: NO-GO;
- rotor speeds: ESC_STATUS (measured) GO; without it the bridge estimates them from
  ACTUATOR_OUTPUT_STATUS / SERVO_OUTPUT_RAW (``mavlink/rotor_estimate.py``): GO, with a
  WARN when the output values do not fit the configured mapping; neither: NO-GO;
- COM_DISARM_PRFLT > 0 (pre-flight auto disarm enabled) else WARN;
- NAV_DLL_ACT, COM_RCL_EXCEPT, COM_RC_IN_MODE reported (informational);
- telemetry from other systems on the link is reported (WARN; the bridge ignores it).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.link import MavlinkLink
from lpv_sysid.mavlink.rotor_estimate import MOTOR_OUTPUT_STREAMS, RotorEstimateConfig
from lpv_sysid.mavlink.telemetry import ATTITUDE_SOURCES, MOTOR_OUTPUT_SOURCES, POSITION_SOURCES

GO, WARN, NOGO = "GO", "WARN", "NO-GO"
REQUIRED_PARAMS = ("COM_OF_LOSS_T", "COM_OBL_RC_ACT")
INFO_PARAMS = ("COM_DISARM_PRFLT", "NAV_DLL_ACT", "COM_RCL_EXCEPT", "COM_RC_IN_MODE")
MIN_VERSION = (1, 14)
MULTIROTOR_TYPES = {
    2: "quadrotor",
    3: "coaxial",
    4: "helicopter",
    13: "hexarotor",
    14: "octorotor",
    15: "tricopter",
}
#: streams waited for until the grace period ends (ATTITUDE_QUATERNION, LOCAL_POSITION_NED
#: are the preferred state sources; the others may be absent on a healthy vehicle)
TELEMETRY = ("ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "HIGHRES_IMU", "ESC_STATUS")
#: streams requested besides the link's own: stick evidence and motor outputs [Hz]
EXTRA_STREAMS = (("SYS_STATUS", 5.0), ("RC_CHANNELS", 5.0)) + MOTOR_OUTPUT_STREAMS
#: vehicle-state messages whose foreign sources are reported
STATE_TYPES = frozenset(
    ATTITUDE_SOURCES + POSITION_SOURCES + MOTOR_OUTPUT_SOURCES + ("HIGHRES_IMU", "ESC_STATUS")
)
MAV_SYS_STATUS_SENSOR_RC_RECEIVER = 0x10000
HOLD_FIX = (
    f"set COM_OBL_RC_ACT to {int(px4.OblAction.HOLD)} (Hold): "
    f"`param set COM_OBL_RC_ACT {int(px4.OblAction.HOLD)}`"
)


@dataclass(frozen=True)
class Check:
    name: str
    value: str
    expected: str
    verdict: str
    note: str = ""  # reason and fix (printed below the table)


@dataclass
class Facts:
    """What :func:`run_checks` gathered (messages of the target system only)."""

    hb: Any = None
    version: Any = None
    params: dict[str, float | int] = field(default_factory=dict)
    seen: set[str] = field(default_factory=set)
    sys_status: Any = None
    rc_channels: Any = None
    motor_outputs: dict[str, Any] = field(default_factory=dict)  # type -> newest message
    foreign: dict[tuple[int, int], int] = field(default_factory=dict)

    def absorb(self, m: Any, target: tuple[int, int] | None) -> None:
        mt = m.get_type()
        src = (m.get_srcSystem(), m.get_srcComponent())
        if mt == "HEARTBEAT":
            if target is not None and src[0] == target[0] and m.autopilot != 8:
                self.hb = m
            return
        if target is None:
            return
        if src != target:
            if mt in STATE_TYPES:
                self.foreign[src] = self.foreign.get(src, 0) + 1
            return
        if mt == "AUTOPILOT_VERSION":
            self.version = m
        elif mt == "PARAM_VALUE":
            self.params[px4.param_id_str(m.param_id)] = px4.param_from_wire(
                m.param_value, m.param_type
            )
        elif mt == "SYS_STATUS":
            self.sys_status = m
        elif mt == "RC_CHANNELS":
            self.rc_channels = m
        elif mt in MOTOR_OUTPUT_SOURCES:
            self.motor_outputs[mt] = m
        self.seen.add(mt)

    def core_complete(self) -> bool:
        return (
            self.hb is not None
            and self.version is not None
            and all(p in self.params for p in REQUIRED_PARAMS + INFO_PARAMS)
        )

    def all_in(self) -> bool:
        """Every answer in, including the streams that may be absent."""
        sticks_known = (
            self.sys_status is not None
            or _rc_present(self.rc_channels)
            or self.params.get("COM_RC_IN_MODE") == px4.RcInMode.DISABLED
        )
        return self.core_complete() and all(s in self.seen for s in TELEMETRY) and sticks_known


def run_checks(
    link: MavlinkLink,
    timeout: float = 5.0,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    grace: float = 1.5,
    rotor_estimate: RotorEstimateConfig | None = None,
) -> list[Check]:
    """Gather the facts (at most ``timeout`` s; ends once all are in, or ``grace`` s after
    the stream requests when only possibly-absent streams are missing) and judge them."""
    facts = gather(link, timeout, clock, sleep, grace)
    return judge(
        facts.hb,
        facts.version,
        facts.params,
        facts.seen,
        link,
        facts=facts,
        rotor_estimate=rotor_estimate,
    )


def gather(
    link: MavlinkLink,
    timeout: float = 5.0,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    grace: float = 1.5,
) -> Facts:
    t0 = clock()
    facts = Facts()
    next_req = t0
    t_streams: float | None = None
    mod = link.dialect_module
    own = {name for name, _ in link.config.streams}
    extra = [
        (int(getattr(mod, f"MAVLINK_MSG_ID_{n}")), n, r) for n, r in EXTRA_STREAMS if n not in own
    ]
    while True:
        now = clock()
        if now - t0 > timeout:
            break
        for m in link.poll(now):
            target = (link.target_system, link.target_component) if link.target_system else None
            facts.absorb(m, target)
        link.step(now)
        if facts.hb is not None and now >= next_req:
            next_req = now + 0.5
            if facts.version is None:
                link.command_long(
                    px4.MAV_CMD_REQUEST_MESSAGE, float(mod.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
                )
            for name in REQUIRED_PARAMS + INFO_PARAMS:
                if name not in facts.params:
                    link.send(
                        link.codec.param_request_read_encode(
                            link.target_system, link.target_component, name.encode("ascii"), -1
                        )
                    )
            if t_streams is None:
                link.request_streams()
                t_streams = now
            for mid, name, rate in extra:
                if name not in facts.seen:
                    link.command_long(
                        px4.MAV_CMD_SET_MESSAGE_INTERVAL, float(mid), float(int(1e6 / rate))
                    )
        if facts.all_in() or (
            facts.core_complete() and t_streams is not None and now - t_streams >= grace
        ):
            break
        sleep(0.005)
    return facts


def _rc_present(rc: Any) -> bool:
    """RC_CHANNELS with channels and a signal (RSSI 0 = no signal; 255 = unknown)."""
    return rc is not None and int(rc.chancount) > 0 and int(rc.rssi) != 0


def _sticks(facts: Facts) -> tuple[bool, str]:
    """(stick input available, how it was decided)."""
    mode = facts.params.get("COM_RC_IN_MODE")
    if mode is not None and int(mode) == px4.RcInMode.DISABLED:
        return False, f"none: COM_RC_IN_MODE {int(mode)} (stick input disabled)"
    rc = facts.rc_channels
    rc_txt = (
        f"RC_CHANNELS {int(rc.chancount)} ch, RSSI {int(rc.rssi)}"
        if rc is not None
        else "no RC_CHANNELS"
    )
    if facts.sys_status is not None:
        present = bool(
            int(facts.sys_status.onboard_control_sensors_present)
            & MAV_SYS_STATUS_SENSOR_RC_RECEIVER
        )
        return present, (
            f"{'present' if present else 'none'}: SYS_STATUS manual control "
            f"{'present' if present else 'absent'} ({rc_txt})"
        )
    ok = px4.sticks_available(
        int(mode) if mode is not None else px4.RcInMode.RC_OR_JOYSTICK, _rc_present(rc), False
    )
    return ok, f"{'present' if ok else 'none'}: {rc_txt}, no SYS_STATUS"


def _obl_check(a: float | int | None, sticks: bool, sticks_txt: str) -> Check:
    expected = "Return/Land/Hold, or sticks"
    if a is None:
        return Check(
            "COM_OBL_RC_ACT", "missing", expected, NOGO, f"parameter not received; {HOLD_FIX}"
        )
    try:
        act = px4.OblAction(int(a))
    except ValueError:
        return Check("COM_OBL_RC_ACT", f"invalid ({a})", expected, NOGO, HOLD_FIX)
    value = f"{int(act)} ({act.name})"
    mode = px4.OBL_ACTION_MODES.get(act)
    if mode is None:  # Terminate / Disarm
        return Check(
            "COM_OBL_RC_ACT",
            value,
            expected,
            NOGO,
            f"offboard loss -> {act.name.lower()}: motors off in the air, the vehicle falls; "
            f"{HOLD_FIX}",
        )
    if mode in px4.STICK_MODES:
        if not sticks:
            return Check(
                "COM_OBL_RC_ACT",
                value,
                expected,
                NOGO,
                f"offboard loss -> {mode.name} needs stick input and there is none "
                f"({sticks_txt}); "
                f"PX4 cannot run it and descends without position control; {HOLD_FIX}",
            )
        if mode == px4.STABILIZED:
            return Check(
                "COM_OBL_RC_ACT",
                value,
                expected,
                WARN,
                f"offboard loss -> {mode.name}: no altitude or position hold, the pilot must fly "
                f"at once; {HOLD_FIX} unless that is intended",
            )
    return Check("COM_OBL_RC_ACT", value, expected, GO)


def _rotor_check(facts: Facts, cfg: RotorEstimateConfig) -> Check:
    expected = "ESC_STATUS or motor outputs"
    if "ESC_STATUS" in facts.seen:
        return Check("rotor speeds", "measured (ESC_STATUS)", expected, GO)
    usable = [
        s
        for s in MOTOR_OUTPUT_SOURCES
        if s in facts.motor_outputs and (cfg.source == "auto" or cfg.source == s.lower())
    ]
    if not cfg.enabled or not usable:
        why = (
            "rotor_estimate is disabled"
            if not cfg.enabled
            else "no "
            + (" / ".join(MOTOR_OUTPUT_SOURCES) if cfg.source == "auto" else cfg.source.upper())
            + " either"
        )
        return Check(
            "rotor speeds",
            "none",
            expected,
            NOGO,
            f"no ESC telemetry and {why}: rotor_speeds cannot be published "
            "(identification and the controller runtime need them)",
        )
    src = usable[0]
    m = facts.motor_outputs[src]
    chans = cfg.motor_outputs
    if src == "ACTUATOR_OUTPUT_STATUS":
        if max(chans) > int(m.active):
            return Check(
                "rotor speeds",
                f"{src}: {int(m.active)} active outputs",
                expected,
                NOGO,
                f"rotor_estimate.motor_outputs {list(chans)} needs output {max(chans)}",
            )
        vals = [float(m.actuator[c - 1]) for c in chans]
    else:
        vals = [float(getattr(m, f"servo{c}_raw")) for c in chans]
    value = f"estimated ({src})"
    note = (
        f"no ESC telemetry: estimated rotor speeds ({src}) will be used "
        f"(motor outputs now {', '.join(f'{v:g}' for v in vals)})"
    )
    lo, hi = cfg.output_range()
    span = hi - lo
    odd = [v for v in vals if math.isfinite(v) and not (lo - 0.25 * span <= v <= hi + 0.25 * span)]
    if odd:
        return Check(
            "rotor speeds",
            value,
            expected,
            WARN,
            f"{note}, but {odd} do not fit rotor_estimate.mapping {cfg.mapping!r} "
            f"({lo:g} .. {hi:g}): set mapping (pwm | dshot | normalized | symmetric) or "
            "output_min / output_max",
        )
    return Check("rotor speeds", value, expected, GO, note)


def judge(
    hb: Any,
    version: Any,
    params: dict[str, float | int],
    seen: set[str],
    link: MavlinkLink | None = None,
    *,
    facts: Facts | None = None,
    rotor_estimate: RotorEstimateConfig | None = None,
) -> list[Check]:
    """Turn the gathered facts into checks (pure; tested without a vehicle)."""
    if facts is None:
        facts = Facts(hb=hb, version=version, params=dict(params), seen=set(seen))
    cfg = rotor_estimate or RotorEstimateConfig()
    out: list[Check] = []
    if hb is None:
        out.append(Check("link", "no autopilot HEARTBEAT", "HEARTBEAT received", NOGO))
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
        mod = px4.dialect_module()
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
        out.append(Check("COM_OF_LOSS_T", "missing", "0 < t <= 2 s", NOGO))
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
        )
    )
    for name in ("NAV_DLL_ACT", "COM_RCL_EXCEPT", "COM_RC_IN_MODE"):
        v = params.get(name)
        text = "missing" if v is None else f"{v}"
        if name == "COM_RC_IN_MODE" and v is not None and int(v) in set(px4.RcInMode):
            text = f"{int(v)} ({px4.RcInMode(int(v)).name.lower().replace('_', ' ')})"
        out.append(Check(name, text, "(information)", GO if v is not None else WARN))
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
        )
    )
    out.append(_rotor_check(facts, cfg))
    return out


def verdict(checks: list[Check]) -> bool:
    return all(c.verdict != NOGO for c in checks)


def format_table(checks: list[Check]) -> str:
    w0 = max(len(c.name) for c in checks)
    w1 = max(len(c.value) for c in checks)
    w2 = max(len(c.expected) for c in checks)
    lines = [
        f"{'check':<{w0}}  {'value':<{w1}}  {'expected':<{w2}}  verdict",
        f"{'-' * w0}  {'-' * w1}  {'-' * w2}  -------",
    ]
    lines += [f"{c.name:<{w0}}  {c.value:<{w1}}  {c.expected:<{w2}}  {c.verdict}" for c in checks]
    notes = [f"  {c.verdict} {c.name}: {c.note}" for c in checks if c.note]
    if notes:
        lines += ["", "notes:"] + notes
    return "\n".join(lines)
