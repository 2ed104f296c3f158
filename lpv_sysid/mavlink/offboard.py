"""PX4 offboard state machine (pure: no I/O, no clock; ``now`` is always passed in).

::

    IDLE --start--> PRESTREAM --(> prestream_time of setpoints)--> SWITCHING
    SWITCHING --(ACK accepted and HEARTBEAT shows OFFBOARD)--> ARMING (arm configured, disarmed)
                                                           \\-> OFFBOARD_ACTIVE
    ARMING --(ACK accepted and HEARTBEAT armed)--> OFFBOARD_ACTIVE
    any streaming state --abort / stale input / link loss / shutdown--> HANDBACK
    HANDBACK --(HEARTBEAT shows a mode other than OFFBOARD)--> DONE (requested) | FAILED (fault)
    SWITCHING/ARMING --(retries exhausted)--> HANDBACK -> FAILED
    OFFBOARD_ACTIVE --(vehicle left OFFBOARD by itself / disarmed)--> FAILED (pilot or PX4 has it)

PX4 facts (v1.16): setpoints must stream at >= 2 Hz for > 1 s before OFFBOARD is
accepted; the switch is MAV_CMD_DO_SET_MODE (176) with param1 = 1
(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), param2 = main mode, param3 = sub mode; arming is
MAV_CMD_COMPONENT_ARM_DISARM (400) param1 = 1. COMMAND_ACK may arrive twice: an ACK
for a command that is not pending is ignored. The stream stops the moment the machine
leaves a streaming state, so PX4's own offboard-loss failsafe (COM_OF_LOSS_T ->
COM_OBL_RC_ACT) is the second line of defence if the hand-back command is lost.

Outputs of :meth:`OffboardMachine.step` and the input methods are lists of
:class:`SendSetpoint`, :class:`SendCommand` and :class:`StatusEvent`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any, Mapping

from lpv_sysid.errors import ConfigError
from lpv_sysid.mavlink import px4
from lpv_sysid.validation import check_config_keys

MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
MAV_RESULT_FAILED = 4
MAV_RESULT_IN_PROGRESS = 5


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
class OffboardConfig:
    """``config/mavlink_bridge.yaml`` section ``offboard``."""

    setpoint_rate_hz: float = 20.0
    prestream_time: float = 1.2
    arm: bool = False
    handback_mode: str = "HOLD"           # HOLD | POSCTL | LAND
    input_timeout: float = 0.5            # no ROS command for longer -> hand back
    ack_timeout: float = 0.5
    max_retries: int = 3
    mode_confirm_timeout: float = 2.0     # HEARTBEAT must show the commanded mode/arming
    send_on_command: bool = True          # forward a new command at once (latency)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "OffboardConfig":
        check_config_keys(d, cls.__dataclass_fields__, "offboard")
        cfg = cls(**dict(d))
        cfg.validate()
        return cfg

    def validate(self) -> None:
        def num(name: str, lo: float, hi: float = math.inf) -> None:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo <= v <= hi) or v != v:
                raise ConfigError(f"offboard.{name} must be a number in [{lo}, {hi}], got {v!r}")
        num("setpoint_rate_hz", 2.0001, 1000.0)   # PX4 needs > 2 Hz
        num("prestream_time", 1.0001, 60.0)       # PX4 needs > 1 s
        num("input_timeout", 0.01, 60.0)
        num("ack_timeout", 0.01, 60.0)
        num("mode_confirm_timeout", 0.01, 60.0)
        if not isinstance(self.max_retries, int) or isinstance(self.max_retries, bool) or not 0 <= self.max_retries <= 100:
            raise ConfigError(f"offboard.max_retries must be an integer 0..100, got {self.max_retries!r}")
        if not isinstance(self.arm, bool) or not isinstance(self.send_on_command, bool):
            raise ConfigError("offboard.arm and offboard.send_on_command must be booleans")
        if str(self.handback_mode).upper() not in px4.HANDBACK_MODES:
            raise ConfigError(f"offboard.handback_mode must be one of {sorted(px4.HANDBACK_MODES)}, "
                              f"got {self.handback_mode!r}")

    @property
    def handback(self) -> px4.Px4Mode:
        return px4.HANDBACK_MODES[str(self.handback_mode).upper()]


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
    level: str = "info"       # info | warn | error


@dataclass
class _Pending:
    command: int
    params: tuple[float, ...]
    t_sent: float
    attempts: int
    accepted: bool = False
    t_accepted: float = 0.0


class OffboardMachine:
    """The state machine of the module docstring."""

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
        self._fault = False
        self._t_state = 0.0
        self._t_stream0 = math.inf
        self._next_sp = 0.0
        self._cmd: Any = None
        self._t_cmd = -math.inf
        self._pending: _Pending | None = None

    # --------------------------------------------------------------- inputs
    def start(self, now: float) -> list[Any]:
        if self.state in STREAMING or self.state == State.HANDBACK:
            return []
        self._fault = False
        self._pending = None
        self._t_stream0 = now
        self._next_sp = now
        out = self._go(now, State.PRESTREAM, "start requested")
        return out + self.step(now)

    def on_command(self, now: float, setpoint: Any) -> list[Any]:
        """A new setpoint from ROS (velocity reference or virtual actuator command)."""
        self._cmd, self._t_cmd = setpoint, now
        if self.config.send_on_command and self.state in STREAMING:
            self._next_sp = now + 1.0 / self.config.setpoint_rate_hz
            self.setpoints_sent += 1
            if self._t_stream0 == math.inf:
                self._t_stream0 = now
            return [SendSetpoint(setpoint)]
        return []

    def on_heartbeat(self, now: float, mode: px4.Px4Mode, armed: bool) -> list[Any]:
        self.vehicle_mode, self.armed = mode, armed
        return self.step(now)

    def on_ack(self, now: float, command: int, result: int) -> list[Any]:
        p = self._pending
        if p is None or p.command != command or p.accepted:
            return []                     # duplicate or unrelated ACK
        if result == MAV_RESULT_ACCEPTED:
            p.accepted, p.t_accepted = True, now
            return self.step(now)
        if result == MAV_RESULT_IN_PROGRESS:
            p.t_sent = now                # keep waiting
            return []
        reason = f"command {command} rejected (MAV_RESULT {result})"
        return self._retry_or_fail(now, reason)

    def on_link(self, now: float, up: bool) -> list[Any]:
        was, self.link_up = self.link_up, up
        if was and not up and self.state in STREAMING:
            return self._handback(now, "link lost (no HEARTBEAT); PX4 failsafe COM_OBL_RC_ACT "
                                       "expected after COM_OF_LOSS_T", fault=True)
        return []

    def abort(self, now: float, reason: str = "abort requested") -> list[Any]:
        if self.state in STREAMING:
            return self._handback(now, reason, fault=False)
        if self.state == State.IDLE:
            return self._go(now, State.DONE, reason)
        return []

    def shutdown(self, now: float) -> list[Any]:
        return self.abort(now, "shutdown")

    # ----------------------------------------------------------------- step
    def step(self, now: float) -> list[Any]:
        out: list[Any] = []
        st = self.state
        cfg = self.config
        if st in STREAMING:
            fresh = now - self._t_cmd <= cfg.input_timeout
            if st in (State.SWITCHING, State.ARMING) and not fresh and self.neutral is None:
                return self._handback(now, f"stale input during {st.value}: no command for "
                                           f"{now - self._t_cmd:.3f} s and no neutral setpoint", fault=True)
            if st == State.OFFBOARD_ACTIVE and not fresh:
                return self._handback(now, f"stale input: no command for {now - self._t_cmd:.3f} s "
                                           f"(> {cfg.input_timeout} s)", fault=True)
            if st == State.OFFBOARD_ACTIVE:
                if self.vehicle_mode is not None and self.vehicle_mode != px4.OFFBOARD:
                    return self._stop(now, State.FAILED, f"vehicle left OFFBOARD (now {self.vehicle_mode.name}); "
                                                         "control stays with PX4/pilot", "warn")
                if cfg.arm and not self.armed:
                    return self._stop(now, State.FAILED, "vehicle disarmed during OFFBOARD", "warn")
            if now >= self._next_sp:
                sp = self._cmd if fresh else self.neutral
                if sp is not None:
                    out.append(SendSetpoint(sp))
                    self.setpoints_sent += 1
                    if self._t_stream0 == math.inf:
                        self._t_stream0 = now
                else:
                    self._t_stream0 = math.inf     # nothing to stream: pre-stream restarts
                period = 1.0 / cfg.setpoint_rate_hz
                self._next_sp = self._next_sp + period if now - self._next_sp < period else now + period
        if st == State.PRESTREAM:
            if now - self._t_stream0 > cfg.prestream_time:
                out += self._go(now, State.SWITCHING, f"pre-streamed {now - self._t_stream0:.2f} s")
                out += self._send(now, MAV_CMD_DO_SET_MODE, _set_mode_params(px4.OFFBOARD))
        elif st == State.SWITCHING:
            if self.vehicle_mode == px4.OFFBOARD:       # confirmed (even if the ACK was lost)
                self._pending = None
                if cfg.arm and not self.armed:
                    out += self._go(now, State.ARMING, "OFFBOARD confirmed by HEARTBEAT")
                    out += self._send(now, MAV_CMD_COMPONENT_ARM_DISARM, (1.0, 0.0))
                else:
                    out += self._go(now, State.OFFBOARD_ACTIVE, "OFFBOARD confirmed by HEARTBEAT")
            else:
                out += self._check_pending(now)
        elif st == State.ARMING:
            if self.armed:
                self._pending = None
                out += self._go(now, State.OFFBOARD_ACTIVE, "armed (HEARTBEAT)")
            else:
                out += self._check_pending(now)
        elif st == State.HANDBACK:
            if self.vehicle_mode is not None and self.vehicle_mode != px4.OFFBOARD:
                self._pending = None
                out += self._go(now, State.FAILED if self._fault else State.DONE,
                                f"vehicle in {self.vehicle_mode.name}: {self.reason}",
                                "warn" if self._fault else "info")
            else:
                out += self._check_pending(now)
        return out

    # ------------------------------------------------------------- helpers
    def status(self, now: float) -> dict[str, str]:
        return {
            "state": self.state.value,
            "state_age_s": f"{now - self._t_state:.3f}",
            "reason": self.reason,
            "vehicle_mode": self.vehicle_mode.name if self.vehicle_mode else "unknown",
            "armed": str(self.armed),
            "link": "up" if self.link_up else "down",
            "input_age_s": f"{now - self._t_cmd:.3f}" if self._t_cmd > -math.inf else "inf",
            "setpoints_sent": str(self.setpoints_sent),
        }

    def _go(self, now: float, new: State, reason: str, level: str = "info") -> list[Any]:
        prev, self.state, self.reason, self._t_state = self.state, new, reason, now
        return [StatusEvent(now, prev.value, new.value, reason, level)]

    def _send(self, now: float, command: int, params: tuple[float, ...]) -> list[Any]:
        self._pending = _Pending(command, params, now, 1)
        return [SendCommand(command, params, 1)]

    def _check_pending(self, now: float) -> list[Any]:
        p = self._pending
        if p is None:
            return []
        if p.accepted:
            if now - p.t_accepted > self.config.mode_confirm_timeout:
                return self._retry_or_fail(now, f"command {p.command} accepted but HEARTBEAT did not "
                                                f"confirm within {self.config.mode_confirm_timeout} s")
            return []
        if now - p.t_sent > self.config.ack_timeout:
            return self._retry_or_fail(now, f"no COMMAND_ACK for command {p.command} "
                                            f"within {self.config.ack_timeout} s")
        return []

    def _retry_or_fail(self, now: float, reason: str) -> list[Any]:
        p = self._pending
        assert p is not None
        if p.attempts <= self.config.max_retries:
            p.attempts += 1
            p.t_sent = now
            p.accepted = False
            return [StatusEvent(now, self.state.value, self.state.value,
                                f"{reason}; retry {p.attempts - 1}/{self.config.max_retries}", "warn"),
                    SendCommand(p.command, p.params, p.attempts)]
        self._pending = None
        if self.state == State.HANDBACK:
            return self._go(now, State.FAILED, f"hand-back not confirmed ({reason}); PX4 offboard-loss "
                                                "failsafe COM_OBL_RC_ACT is in charge", "error")
        if self.state == State.SWITCHING:
            return self._stop(now, State.FAILED, f"switch to OFFBOARD failed: {reason}", "error")
        return self._handback(now, f"{self.state.value} failed: {reason}", fault=True)

    def _handback(self, now: float, reason: str, fault: bool) -> list[Any]:
        if self.state == State.PRESTREAM and self.vehicle_mode != px4.OFFBOARD:
            # nothing was handed over yet: just stop streaming
            return self._stop(now, State.FAILED if fault else State.DONE, reason,
                              "warn" if fault else "info")
        self._fault = fault
        out = self._go(now, State.HANDBACK, reason, "warn" if fault else "info")
        mode = self.config.handback
        self._pending = None
        return out + self._send(now, MAV_CMD_DO_SET_MODE, _set_mode_params(mode))

    def _stop(self, now: float, new: State, reason: str, level: str) -> list[Any]:
        self._pending = None
        self._fault = new == State.FAILED
        return self._go(now, new, reason, level)


def _set_mode_params(mode: px4.Px4Mode) -> tuple[float, ...]:
    return (float(px4.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(mode.main), float(mode.sub))
