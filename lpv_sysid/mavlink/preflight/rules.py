"""PX4 meaning of the preflight facts that take more than a comparison: stick input
(COM_RC_IN_MODE, SYS_STATUS, RC_CHANNELS), the offboard-loss action COM_OBL_RC_ACT and
the source of the rotor speeds (rules: :mod:`lpv_sysid.mavlink.preflight`).
"""

from __future__ import annotations

import math

from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.preflight.gather import Facts, _rc_present
from lpv_sysid.mavlink.preflight.report import GO, NOGO, WARN, Check
from lpv_sysid.mavlink.telemetry import MOTOR_OUTPUT_SOURCES, RotorEstimateConfig

MAV_SYS_STATUS_SENSOR_RC_RECEIVER = 0x10000
HOLD_FIX = (
    f"set COM_OBL_RC_ACT to {int(px4.OblAction.HOLD)} (Hold): "
    f"`param set COM_OBL_RC_ACT {int(px4.OblAction.HOLD)}`"
)


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
            "COM_OBL_RC_ACT",
            "missing",
            expected,
            NOGO,
            f"parameter not received; {HOLD_FIX}",
            missing=True,
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
            missing=cfg.enabled and not facts.motor_outputs,
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
