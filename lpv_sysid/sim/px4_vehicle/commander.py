"""PX4's commander in the simulated vehicle: COMMAND_LONG verdicts (arming, DO_SET_MODE with
the v1.16 double ACK, message intervals, takeoff/land/return), mode changes, the offboard-loss
failsafe (COM_OBL_RC_ACT, emergency descent when a stick mode cannot run) and the automatic
disarms (COM_DISARM_PRFLT, COM_DISARM_LAND);
the behaviour is described in :mod:`lpv_sysid.sim.px4_vehicle.vehicle`."""

from __future__ import annotations

import logging
import math
from typing import Any, Callable

from lpv_sysid.mavlink import px4
from lpv_sysid.sim.px4_vehicle.config import DEFAULT_RATES
from lpv_sysid.sim.px4_vehicle.setpoints import SetpointInput
from lpv_sysid.sim.px4_vehicle.telemetry import TelemetryStreams

log = logging.getLogger(__name__)


class Commander(SetpointInput, TelemetryStreams):
    """Commands, modes, arming and failsafes."""

    def _supervise(self, t: float) -> None:
        if self.mode == px4.OFFBOARD and self.armed:  # PX4's failsafes act only while armed
            last = self.setpoint.t if self.setpoint is not None else -math.inf
            if t - last > self.param("COM_OF_LOSS_T"):
                self._offboard_lost(t)
        if self.armed and self.landed:
            prflt, land = self.param("COM_DISARM_PRFLT"), self.param("COM_DISARM_LAND")
            if not self.took_off and prflt > 0 and t - self.t_armed > prflt:
                self._disarm(t, "no takeoff within COM_DISARM_PRFLT")
            elif self.took_off and land > 0 and t - self.t_landed > land:
                self._disarm(t, "landed (COM_DISARM_LAND)")

    def _offboard_lost(self, t: float) -> None:
        act = int(self.param("COM_OBL_RC_ACT"))
        reason = (
            f"offboard lost for > COM_OF_LOSS_T = {self.param('COM_OF_LOSS_T')} s "
            f"(COM_OBL_RC_ACT={act})"
        )
        self.failsafe_reason = reason
        log.warning(reason)
        self.px4_log.append((t, "Failsafe activated"))
        target = next((mode for a, mode in px4.OBL_ACTION_MODES.items() if a == act), None)
        if target is None:  # 6 terminate, 7 disarm: motors off
            self.mode_log.append((t, self.mode.name, reason))
            self._disarm(t, reason)
            return
        self._set_mode(target, t, reason, failsafe=True)
        if target in px4.STICK_MODES and not self.sticks_available(t):
            msg = f"Matching flight task was not able to run, Nav state: {px4.NAV_STATES[target]}"
            log.error(msg)
            self.px4_log.append((t, msg))
            self.mode_log[-1] = (t, target.name, f"{reason}; {msg}: emergency descent")
            self.descending = True
            if hasattr(self.ctrl, "vel_int"):  # Descend task: no horizontal acceleration
                self.ctrl.vel_int[0] = self.ctrl.vel_int[1] = 0.0

    def _set_mode(self, mode: px4.Px4Mode, t: float, reason: str, failsafe: bool = False) -> None:
        """Enter ``mode``: a failsafe's (the user's choice is kept) or a user's (ends a
        failsafe)."""
        if mode != self.mode or self.descending:
            self.mode_log.append((t, mode.name, reason))
        self.mode = mode
        self.failsafe_active = failsafe
        if not failsafe:
            self.user_mode = mode
            self.failsafe_reason = ""
        self.descending = False
        self.hold_pos = self.x[0:3].copy()
        if self.landed:
            self.hold_pos[2] = 0.0

    def _arm(self, t: float) -> None:
        self.armed, self.t_armed, self.took_off = True, t, False
        self.ctrl = self._controller_factory()
        self.hold_pos = self.x[0:3].copy()

    def _disarm(self, t: float, reason: str) -> None:
        if self.armed:
            self.mode_log.append((t, "DISARMED", reason))
        self.armed = False
        self.x[12:16] = 0.0
        if self.failsafe_active:  # cleared on disarm: the user's mode again
            self._set_mode(self.user_mode, t, "failsafe cleared on disarm")

    def _commander(self, cmd: int, now: float, verdict: Callable[[], int]) -> None:
        """A command PX4's commander decides ``verdict_delay_s`` later; DOUBLE_ACK_COMMANDS
        are ACCEPTED at once by the MAVLink receiver as well (``double_ack``)."""
        if not self.config.double_ack:
            self._ack(cmd, verdict())
            return
        if cmd in px4.DOUBLE_ACK_COMMANDS:
            self._ack(cmd, px4.MAV_RESULT_ACCEPTED)
        self._verdicts.append((now + self.config.verdict_delay_s, cmd, verdict))

    def _run_verdicts(self, t: float) -> None:
        while self._verdicts and self._verdicts[0][0] <= t + 1e-9:
            _, cmd, verdict = self._verdicts.pop(0)
            self._ack(cmd, verdict())

    def _command(self, m: Any, now: float) -> None:
        c = m.command
        if c == px4.MAV_CMD_COMPONENT_ARM_DISARM:
            p1, p2 = float(m.param1), float(m.param2)
            return self._commander(c, now, lambda: self._arm_verdict(p1, p2))
        if c == px4.MAV_CMD_DO_SET_MODE:
            p1, p2, p3 = float(m.param1), float(m.param2), float(m.param3)
            return self._commander(c, now, lambda: self._set_mode_verdict(p1, p2, p3))
        if c == px4.MAV_CMD_SET_MESSAGE_INTERVAL:
            mid, interval = int(m.param1), m.param2
            if mid not in self._stream_ids.values():
                return self._ack(c, px4.MAV_RESULT_UNSUPPORTED)
            default = DEFAULT_RATES[next(k for k, v in self._stream_ids.items() if v == mid)]
            if interval < 0:
                self.intervals[mid] = -1.0
            elif interval == 0:
                self.intervals[mid] = 1.0 / default if default > 0 else -1.0
            else:
                self.intervals[mid] = max(interval * 1e-6, 1.0 / 400.0)
            self._next_send[mid] = now
            return self._ack(c, px4.MAV_RESULT_ACCEPTED)
        if c in (px4.MAV_CMD_REQUEST_MESSAGE, px4.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES):
            mid = 148 if c == px4.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES else int(m.param1)
            if mid == 148:
                self._ack(c, px4.MAV_RESULT_ACCEPTED)
                return self._send_autopilot_version()
            if mid in self._stream_ids.values():
                if not self._stream_has_data(mid):
                    return self._ack(c, px4.MAV_RESULT_FAILED)
                self._ack(c, px4.MAV_RESULT_ACCEPTED)
                return self._send_stream(mid, now)
            return self._ack(c, px4.MAV_RESULT_UNSUPPORTED)
        if c == px4.MAV_CMD_NAV_TAKEOFF:
            if not self.armed:
                return self._ack(c, px4.MAV_RESULT_DENIED)
            self._set_mode(px4.TAKEOFF, self.t, "NAV_TAKEOFF")
            return self._ack(c, px4.MAV_RESULT_ACCEPTED)
        if c in (px4.MAV_CMD_NAV_LAND, px4.MAV_CMD_NAV_RETURN_TO_LAUNCH):
            self._set_mode(px4.LAND if c == px4.MAV_CMD_NAV_LAND else px4.RTL, self.t, "command")
            return self._ack(c, px4.MAV_RESULT_ACCEPTED)
        return self._ack(c, px4.MAV_RESULT_UNSUPPORTED)

    def _can_run(self, mode: px4.Px4Mode) -> bool:
        """Whether the flight task of ``mode`` has what it needs (stream, stick input)."""
        if mode == px4.OFFBOARD:
            return self._stream_alive(self.t)
        if mode in px4.STICK_MODES:
            return self.sticks_available()
        return True

    def _arm_verdict(self, p1: float, p2: float) -> int:
        t = self.t
        if p1 >= 0.5:
            if self.armed:
                return px4.MAV_RESULT_ACCEPTED
            if not self.landed or self.mode in (px4.LAND, px4.RTL):
                return px4.MAV_RESULT_DENIED
            if not self._can_run(self.mode):
                msg = (
                    "Arming denied: Resolve system health failures first "
                    f"({self.mode.name} cannot run)"
                )
                log.warning(msg)
                self.px4_log.append((t, msg))
                return px4.MAV_RESULT_TEMPORARILY_REJECTED
            self._arm(t)
            return px4.MAV_RESULT_ACCEPTED
        if self.landed or int(round(p2)) == px4.FORCE_DISARM_MAGIC:
            self._disarm(t, "disarm command")
            return px4.MAV_RESULT_ACCEPTED
        return px4.MAV_RESULT_DENIED

    def _set_mode_verdict(self, p1: float, p2: float, p3: float) -> int:
        if not int(p1) & px4.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return px4.MAV_RESULT_UNSUPPORTED
        mode = px4.Px4Mode(int(p2), int(p3))
        if mode.main == px4.MAIN_AUTO and mode.sub == 0:
            mode = px4.HOLD
        if mode.name.startswith("UNKNOWN"):
            return px4.MAV_RESULT_UNSUPPORTED
        if self.armed and not self._can_run(mode):  # disarmed: PX4 always allows the change
            msg = f"Switching to {mode.name} is currently not possible"
            log.warning(msg)
            self.px4_log.append((self.t, msg))
            return px4.MAV_RESULT_TEMPORARILY_REJECTED
        self._set_mode(mode, self.t, "DO_SET_MODE")  # a user's choice also ends a failsafe
        return px4.MAV_RESULT_ACCEPTED
