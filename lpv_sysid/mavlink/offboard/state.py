"""State, outputs and step evidence of the PX4 offboard machine.

:class:`OffboardState` holds what the machine knows (its state, the vehicle's mode and
arming state from the HEARTBEAT, the setpoint stream, the pending command with every
COMMAND_ACK of its current attempt) and applies the confirmation rule of a step. The
transitions and the truth rules are documented in :mod:`lpv_sysid.mavlink.offboard`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any

from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.offboard.config import OffboardConfig

MAV_CMD_DO_SET_MODE = px4.MAV_CMD_DO_SET_MODE
MAV_CMD_COMPONENT_ARM_DISARM = px4.MAV_CMD_COMPONENT_ARM_DISARM
MAV_RESULT_ACCEPTED = px4.MAV_RESULT_ACCEPTED
MAV_RESULT_TEMPORARILY_REJECTED = px4.MAV_RESULT_TEMPORARILY_REJECTED
MAV_RESULT_DENIED = px4.MAV_RESULT_DENIED
MAV_RESULT_UNSUPPORTED = px4.MAV_RESULT_UNSUPPORTED
MAV_RESULT_FAILED = px4.MAV_RESULT_FAILED
MAV_RESULT_IN_PROGRESS = px4.MAV_RESULT_IN_PROGRESS


class State(enum.Enum):
    IDLE = "IDLE"
    PRESTREAM = "PRESTREAM"
    SWITCHING = "SWITCHING"
    ARMING = "ARMING"
    OFFBOARD_ACTIVE = "OFFBOARD_ACTIVE"
    HANDBACK = "HANDBACK"
    DONE = "DONE"
    FAILED = "FAILED"


STREAMING = (State.PRESTREAM, State.SWITCHING, State.ARMING, State.OFFBOARD_ACTIVE)


@dataclass(frozen=True)
class SendSetpoint:
    setpoint: Any


@dataclass(frozen=True)
class SendCommand:
    command: int
    params: tuple[float, ...]
    attempt: int = 1


@dataclass(frozen=True)
class StatusEvent:
    t: float
    previous: str
    state: str
    reason: str
    level: str = "info"  # info | warn | error


@dataclass
class _Pending:
    """One step (a command and what it must achieve) and every ACK of its current attempt."""

    command: int
    params: tuple[float, ...]
    what: str  # "OFFBOARD", "arm", "HOLD", ...
    t_first: float  # first attempt sent
    t_sent: float  # current attempt sent
    already: bool = False  # the vehicle showed the wanted state before the command
    attempts: int = 1
    acks: list[tuple[float, int]] = field(default_factory=list)
    t_last_ack: float = -math.inf
    t_accepted: float | None = None
    rejected: int | None = None

    def resend(self, now: float) -> None:
        self.attempts += 1
        self.t_sent = now
        self.acks = []
        self.t_last_ack = -math.inf
        self.t_accepted = None
        self.rejected = None


class OffboardState:
    """What the offboard machine knows, its outputs' bookkeeping and the confirmation
    rule of a pending step (transitions: :class:`lpv_sysid.mavlink.offboard.OffboardMachine`)."""

    def __init__(self, config: OffboardConfig | None = None, neutral_setpoint: Any = None) -> None:
        self.config = config or OffboardConfig()
        self.config.validate()
        self.neutral = neutral_setpoint
        self.state = State.IDLE
        self.reason = ""
        self.vehicle_mode: px4.Px4Mode | None = None
        self.armed = False
        self.link_up = False
        self.setpoints_sent = 0
        self.confirmed_mode: px4.Px4Mode | None = None
        self.disarmed_after_run = False
        self.reverted_to_offboard = 0  # times the vehicle went back to OFFBOARD after the end
        self._left_offboard = False  # seen out of OFFBOARD since DONE/FAILED
        self._fault = False
        self._t_state = 0.0
        self._t_stream0 = math.inf
        self._next_sp = 0.0
        self._cmd: Any = None
        self._t_cmd = -math.inf
        self._t_hb = -math.inf
        self._pending: _Pending | None = None
        self._target: px4.Px4Mode | None = None
        self._chain: list[px4.Px4Mode] = []
        self._failures: list[str] = []
        self._handback_reason = ""
        self._was_armed = False
        self._armed_active = False
        self._last_acks = ""

    def status(self, now: float) -> dict[str, str]:
        p = self._pending
        return {
            "state": self.state.value,
            "state_age_s": f"{now - self._t_state:.3f}",
            "reason": self.reason,
            "vehicle_mode": self.vehicle_mode.name if self.vehicle_mode else "unknown",
            "armed": str(self.armed),
            "link": "up" if self.link_up else "down",
            "input_age_s": f"{now - self._t_cmd:.3f}" if self._t_cmd > -math.inf else "inf",
            "setpoints_sent": str(self.setpoints_sent),
            "pending": f"{p.what} (attempt {p.attempts})" if p is not None else "",
            "acks": self._last_acks,
            "handback_target": self._target.name if self._target is not None else "",
            "confirmed_mode": self.confirmed_mode.name if self.confirmed_mode is not None else "",
            "disarmed": str(self.disarmed_after_run),
            "reverted_to_offboard": str(self.reverted_to_offboard),
        }

    def _stream(self, now: float, fresh: bool) -> list[Any]:
        if now < self._next_sp:
            return []
        out: list[Any] = []
        sp = self.neutral if (self.state == State.HANDBACK or not fresh) else self._cmd
        if sp is not None:
            out.append(SendSetpoint(sp))
            self.setpoints_sent += 1
            if self._t_stream0 == math.inf:
                self._t_stream0 = now
        else:
            self._t_stream0 = math.inf  # nothing to stream: pre-stream restarts
        period = 1.0 / self.config.setpoint_rate_hz
        self._next_sp = self._next_sp + period if now - self._next_sp < period else now + period
        return out

    def _confirmed(
        self, now: float, mode: px4.Px4Mode | None = None, armed: bool | None = None
    ) -> bool:
        p = self._pending
        if p is None or p.rejected is not None or self._t_hb <= p.t_first:
            return False
        if mode is not None and self.vehicle_mode != mode:
            return False
        if armed is not None and self.armed != armed:
            return False
        if p.already and p.t_accepted is None:
            return False  # the HEARTBEAT showed this before the command
        return now - max(p.t_sent, p.t_last_ack) >= self.config.ack_settle_s

    def _go(self, now: float, new: State, reason: str, level: str = "info") -> list[Any]:
        prev, self.state, self.reason, self._t_state = self.state, new, reason, now
        return [StatusEvent(now, prev.value, new.value, reason, level)]

    def _send(
        self, now: float, command: int, params: tuple[float, ...], what: str, already: bool
    ) -> list[Any]:
        self._pending = _Pending(command, params, what, now, now, already)
        self._last_acks = ""
        return [SendCommand(command, params, 1)]

    def _stop(self, now: float, new: State, reason: str, level: str) -> list[Any]:
        self._pending = None
        self._fault = new == State.FAILED
        return self._go(now, new, reason, level)


def _set_mode_params(mode: px4.Px4Mode) -> tuple[float, ...]:
    return (float(px4.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(mode.main), float(mode.sub))
