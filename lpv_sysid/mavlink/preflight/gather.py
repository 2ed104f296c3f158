"""Gathering of the preflight facts over MAVLink within a bounded time: the autopilot
HEARTBEAT, AUTOPILOT_VERSION, the parameters the safety path depends on, the telemetry
streams, the evidence of stick input and the motor outputs (rules of the gathering and
of the checks: :mod:`lpv_sysid.mavlink.preflight`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.link import MavlinkLink
from lpv_sysid.mavlink.telemetry import (
    ATTITUDE_SOURCES,
    MOTOR_OUTPUT_SOURCES,
    MOTOR_OUTPUT_STREAMS,
    POSITION_SOURCES,
)

REQUIRED_PARAMS = ("COM_OF_LOSS_T", "COM_OBL_RC_ACT")
INFO_PARAMS = ("COM_DISARM_PRFLT", "NAV_DLL_ACT", "COM_RCL_EXCEPT", "COM_RC_IN_MODE")
#: streams waited for until the grace period ends (ATTITUDE_QUATERNION, LOCAL_POSITION_NED
#: are the preferred state sources; the others may be absent on a healthy vehicle)
TELEMETRY = ("ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "HIGHRES_IMU", "ESC_STATUS")
#: streams requested besides the link's own: stick evidence and motor outputs [Hz]
EXTRA_STREAMS = (("SYS_STATUS", 5.0), ("RC_CHANNELS", 5.0)) + MOTOR_OUTPUT_STREAMS
#: vehicle-state messages whose foreign sources are reported
STATE_TYPES = frozenset(
    ATTITUDE_SOURCES + POSITION_SOURCES + MOTOR_OUTPUT_SOURCES + ("HIGHRES_IMU", "ESC_STATUS")
)


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
    extra_params: tuple = ()  # names asked for besides REQUIRED_PARAMS + INFO_PARAMS

    def absorb(self, m: Any, target: tuple[int, int] | None) -> None:
        mt = m.get_type()
        src = (m.get_srcSystem(), m.get_srcComponent())
        if mt == "HEARTBEAT":
            if target is not None and src == target and m.autopilot != 8:
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
            and all(p in self.params for p in self.extra_params)
        )

    def all_in(self) -> bool:
        """Every answer in, including the streams that may be absent."""
        sticks_known = (
            self.sys_status is not None
            or _rc_present(self.rc_channels)
            or self.params.get("COM_RC_IN_MODE") == px4.RcInMode.DISABLED
        )
        return self.core_complete() and all(s in self.seen for s in TELEMETRY) and sticks_known


def gather(
    link: MavlinkLink,
    timeout: float = 5.0,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    grace: float = 1.5,
    extra_params: tuple = (),
) -> Facts:
    t0 = clock()
    facts = Facts(extra_params=tuple(extra_params))
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
            ok = link.target_system and not link.ambiguous_target
            target = (link.target_system, link.target_component) if ok else None
            facts.absorb(m, target)
        link.step(now)
        if facts.hb is not None and now >= next_req:
            next_req = now + 0.5
            if facts.version is None:
                link.command_long(
                    px4.MAV_CMD_REQUEST_MESSAGE, float(mod.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
                )
            for name in REQUIRED_PARAMS + INFO_PARAMS + facts.extra_params:
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
