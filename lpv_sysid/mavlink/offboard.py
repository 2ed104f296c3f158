"""PX4 offboard state machine (pure: no I/O, no clock; ``now`` is always passed in).

::

    IDLE --start--> PRESTREAM --(> prestream_time of setpoints)--> SWITCHING
    SWITCHING --(OFFBOARD confirmed)--> ARMING (arm configured, disarmed) | OFFBOARD_ACTIVE
    ARMING --(armed confirmed)--> OFFBOARD_ACTIVE
    any streaming state --abort / finish / stale input / link loss / shutdown--> HANDBACK
    HANDBACK --(a mode of the chain confirmed)--> DONE (requested) | FAILED (fault, "warn")
    HANDBACK --(chain exhausted)--> FAILED ("error": "hand-back NOT confirmed ...")
    SWITCHING --(rejected / retries exhausted)--> FAILED (HANDBACK if the vehicle shows OFFBOARD)
    ARMING --(rejected / retries exhausted)--> HANDBACK
    OFFBOARD_ACTIVE --(vehicle left OFFBOARD by itself)--> FAILED (pilot or PX4 has it)
    OFFBOARD_ACTIVE --(vehicle disarmed: landed, auto-disarm)--> HANDBACK (PX4 would keep
                                                                 reporting OFFBOARD)

PX4 facts (v1.16): setpoints must stream at >= 2 Hz for > 1 s before OFFBOARD is
accepted; the switch is MAV_CMD_DO_SET_MODE (176) with param1 = 1
(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), param2 = main mode, param3 = sub mode; arming is
MAV_CMD_COMPONENT_ARM_DISARM (400) param1 = 1. DO_SET_MODE is answered twice
(:data:`lpv_sysid.mavlink.px4.DOUBLE_ACK_COMMANDS`): ACCEPTED at once from PX4's MAVLink
receiver, then the commander's verdict some ms later (TEMPORARILY_REJECTED for POSCTL
without stick input while armed, for instance); arming is answered once or twice. A
HEARTBEAT (1 Hz) is the only proof of the mode. While disarmed PX4 accepts every mode
(even OFFBOARD without a stream); the arming verdict then decides.

Truth rules:

- every COMMAND_ACK of the pending command is kept (``status()['acks']``); a rejection,
  also one after an ACCEPTED, is a failure of that step (TEMPORARILY_REJECTED of the
  OFFBOARD switch or of arming is retried up to ``max_retries``, other rejections are not);
- a step is *confirmed* only when no ACK of the current attempt rejected it,
  ``ack_settle_s`` passed since the last ACK (and since sending) without a new one, and a
  HEARTBEAT received after the command was first sent shows exactly the requested mode
  (or arming state). If the vehicle showed that state already before the command (e.g.
  the stale OFFBOARD PX4 keeps after an auto-disarm), the HEARTBEAT proves nothing and a
  final ACCEPTED is required as well;
- hand-back: the modes of ``handback_chain`` (default HOLD, then LAND) are tried in turn;
  a rejection, ``max_retries`` unanswered resends, or no confirmation within
  ``mode_confirm_timeout`` of the ACCEPTED moves on to the next mode. DONE / FAILED name
  the confirmed mode; when nothing is confirmed the machine ends FAILED with level
  ``error`` and the reason "hand-back NOT confirmed: ...; PX4 failsafe in charge";
- while the hand-back is in progress the transport's neutral setpoint (velocity: zero =
  brake and hover) keeps streaming at ``setpoint_rate_hz``, so the hand-back itself does
  not trigger PX4's offboard-loss failsafe (COM_OF_LOSS_T -> COM_OBL_RC_ACT, which without
  stick input is an uncontrolled descent for Position/Altitude/Stabilized); the stream
  stops once a mode is confirmed or the chain is exhausted. A transport without a neutral
  setpoint (attitude_rate) streams nothing and the failsafe is the backstop.

Inputs: :meth:`~OffboardMachine.start`, :meth:`~OffboardMachine.on_command`,
:meth:`~OffboardMachine.on_heartbeat`, :meth:`~OffboardMachine.on_ack`,
:meth:`~OffboardMachine.on_link`, :meth:`~OffboardMachine.abort`,
:meth:`~OffboardMachine.finish`, :meth:`~OffboardMachine.shutdown` and
:meth:`~OffboardMachine.step` at the caller's poll rate; :meth:`~OffboardMachine.status`
for diagnostics.

``finish(now, mode)`` ends a campaign in a chosen mode (e.g. LAND): from a streaming
state it hands back with ``mode`` first (then the rest of the chain), in HANDBACK it
re-targets, from IDLE / DONE / FAILED it requests ``mode`` with the same confirmation
rules (DONE names the confirmed mode). Landing awareness: after DONE / FAILED the machine
reports once, when the HEARTBEAT shows a vehicle that was armed during the run disarmed
(PX4 auto-disarms COM_DISARM_LAND after landing): a StatusEvent "vehicle disarmed in
<mode>" and ``status()['disarmed'] == 'True'``.

Outputs of :meth:`OffboardMachine.step` and the input methods are lists of
:class:`SendSetpoint`, :class:`SendCommand` and :class:`StatusEvent`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

from lpv_sysid.errors import ConfigError
from lpv_sysid.mavlink import px4
from lpv_sysid.config_fields import check_config_keys

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
class OffboardConfig:
    """``config/mavlink_bridge.yaml`` section ``offboard``.

    ``handback_chain``: PX4 modes tried in turn on hand-back (names of
    :data:`lpv_sysid.mavlink.px4.HANDBACK_MODES`). ``handback_mode`` (optional, the
    single-mode key of earlier releases and of the bridge node's parameters): tried first,
    then the other modes of ``handback_chain``.
    """

    setpoint_rate_hz: float = 20.0
    prestream_time: float = 1.2
    arm: bool = False
    handback_chain: tuple[str, ...] = ("HOLD", "LAND")
    handback_mode: str | None = None
    input_timeout: float = 0.5  # no ROS command for longer -> hand back
    ack_timeout: float = 0.5  # per attempt, for the first COMMAND_ACK
    ack_settle_s: float = 0.2  # quiet time after the last ACK before a step counts
    max_retries: int = 3
    mode_confirm_timeout: float = 2.0  # HEARTBEAT must show the mode/arming after ACCEPTED
    send_on_command: bool = True  # forward a new command at once (latency)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "OffboardConfig":
        check_config_keys(d, cls.__dataclass_fields__, "offboard")
        kw = dict(d)
        chain = kw.get("handback_chain")
        if chain is not None:
            if isinstance(chain, (str, bytes)) or not isinstance(chain, Sequence):
                raise ConfigError(
                    f"offboard.handback_chain must be a list of PX4 mode names, got {chain!r}"
                )
            kw["handback_chain"] = tuple(chain)
        cfg = cls(**kw)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        def num(name: str, lo: float, hi: float = math.inf) -> None:
            v = getattr(self, name)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not (lo <= v <= hi)
                or v != v
            ):
                raise ConfigError(f"offboard.{name} must be a number in [{lo}, {hi}], got {v!r}")

        num("setpoint_rate_hz", 2.0001, 1000.0)  # PX4 needs > 2 Hz
        num("prestream_time", 1.0001, 60.0)  # PX4 needs > 1 s
        num("input_timeout", 0.01, 60.0)
        num("ack_timeout", 0.01, 60.0)
        num("ack_settle_s", 0.0, 10.0)
        num("mode_confirm_timeout", 0.01, 60.0)
        if self.ack_settle_s >= self.mode_confirm_timeout:
            raise ConfigError(
                f"offboard.ack_settle_s ({self.ack_settle_s}) must be below "
                f"offboard.mode_confirm_timeout ({self.mode_confirm_timeout})"
            )
        if (
            not isinstance(self.max_retries, int)
            or isinstance(self.max_retries, bool)
            or not 0 <= self.max_retries <= 100
        ):
            raise ConfigError(
                f"offboard.max_retries must be an integer 0..100, got {self.max_retries!r}"
            )
        if not isinstance(self.arm, bool) or not isinstance(self.send_on_command, bool):
            raise ConfigError("offboard.arm and offboard.send_on_command must be booleans")
        chain = self.handback_chain
        if isinstance(chain, (str, bytes)) or not isinstance(chain, Sequence) or not chain:
            raise ConfigError(
                f"offboard.handback_chain must be a non-empty list of mode names, got {chain!r}"
            )
        for name in chain:
            if not isinstance(name, str) or name.upper() not in px4.HANDBACK_MODES:
                raise ConfigError(
                    f"offboard.handback_chain: {name!r} is not a hand-back mode; use "
                    f"{sorted(px4.HANDBACK_MODES)}"
                )
        if len({n.upper() for n in chain}) != len(chain):
            raise ConfigError(f"offboard.handback_chain lists a mode twice: {list(chain)}")
        if self.handback_mode is not None and (
            not isinstance(self.handback_mode, str)
            or self.handback_mode.upper() not in px4.HANDBACK_MODES
        ):
            raise ConfigError(
                f"offboard.handback_mode must be one of {sorted(px4.HANDBACK_MODES)}, "
                f"got {self.handback_mode!r}"
            )

    @property
    def chain(self) -> tuple[px4.Px4Mode, ...]:
        """The hand-back modes in the order they are tried."""
        modes = [px4.HANDBACK_MODES[n.upper()] for n in self.handback_chain]
        if self.handback_mode is not None:
            first = px4.HANDBACK_MODES[self.handback_mode.upper()]
            modes = [first] + [m for m in modes if m != first]
        return tuple(modes)

    @property
    def handback(self) -> px4.Px4Mode:
        """The first hand-back choice."""
        return self.chain[0]


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
        self.confirmed_mode: px4.Px4Mode | None = None
        self.disarmed_after_run = False
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

    # --------------------------------------------------------------- inputs
    def start(self, now: float) -> list[Any]:
        if self.state in STREAMING or self.state == State.HANDBACK:
            return []
        self._fault = False
        self._pending = None
        self._target = None
        self.confirmed_mode = None
        self.disarmed_after_run = False
        self._was_armed = self.armed
        self._armed_active = False
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
        self.vehicle_mode, self.armed, self._t_hb = mode, armed, now
        if armed:
            self._was_armed = True
        return self.step(now)

    def on_ack(self, now: float, command: int, result: int) -> list[Any]:
        """Every COMMAND_ACK of the pending command counts (PX4 sends two, see module doc)."""
        p = self._pending
        if p is None or p.command != command:
            return []  # unrelated, or for a step already decided
        p.acks.append((now, int(result)))
        p.t_last_ack = now
        self._last_acks = ",".join(f"{px4.result_name(r)}@{t:.3f}" for t, r in p.acks[-6:])
        if result == MAV_RESULT_ACCEPTED:
            if p.t_accepted is None:
                p.t_accepted = now
            return self.step(now)
        if result == MAV_RESULT_IN_PROGRESS:
            p.t_sent = now  # keep waiting
            return []
        p.rejected = int(result)
        how = "accepted, then rejected" if p.t_accepted is not None else "rejected"
        reason = f"{p.what} (command {command}) {how}: {px4.result_name(result)}"
        if self.state == State.HANDBACK:
            return self._next_handback(now, reason)
        if result == MAV_RESULT_TEMPORARILY_REJECTED:
            return self._retry_or_fail(now, reason)
        return self._fail_step(now, reason)

    def on_link(self, now: float, up: bool) -> list[Any]:
        was, self.link_up = self.link_up, up
        if was and not up and self.state in STREAMING:
            return self._handback(
                now,
                "link lost (no HEARTBEAT); PX4 failsafe COM_OBL_RC_ACT "
                "expected after COM_OF_LOSS_T",
                fault=True,
            )
        return []

    def abort(self, now: float, reason: str = "abort requested") -> list[Any]:
        if self.state in STREAMING:
            return self._handback(now, reason, fault=False)
        if self.state == State.IDLE:
            return self._go(now, State.DONE, reason)
        return []

    def finish(self, now: float, mode: str | px4.Px4Mode = "LAND") -> list[Any]:
        """End in ``mode`` (e.g. LAND at the end of a campaign); see module docstring."""
        if isinstance(mode, px4.Px4Mode):
            m = mode
        else:
            found = px4.HANDBACK_MODES.get(str(mode).upper())
            if found is None:
                raise ConfigError(
                    f"finish mode {mode!r} is not a hand-back mode; "
                    f"use {sorted(px4.HANDBACK_MODES)}"
                )
            m = found
        reason = f"finish requested: {m.name}"
        if self.state in STREAMING:
            return self._handback(now, reason, fault=False, first=m, force=True)
        if self.state == State.HANDBACK:
            self._chain = [x for x in self.config.chain if x != m]
            self._pending = None
            self._handback_reason = reason
            return [
                StatusEvent(
                    now, self.state.value, self.state.value, f"hand-back re-targeted: {reason}"
                )
            ] + self._request_next(now, first=m)
        self._fault = False
        self.disarmed_after_run = False
        return self._handback(now, reason, fault=False, first=m, force=True)

    def shutdown(self, now: float) -> list[Any]:
        return self.abort(now, "shutdown")

    # ----------------------------------------------------------------- step
    def step(self, now: float) -> list[Any]:
        out: list[Any] = []
        st = self.state
        cfg = self.config
        fresh = now - self._t_cmd <= cfg.input_timeout
        if st in STREAMING:
            if st in (State.SWITCHING, State.ARMING) and not fresh and self.neutral is None:
                return self._handback(
                    now,
                    f"stale input during {st.value}: no command for "
                    f"{now - self._t_cmd:.3f} s and no neutral setpoint",
                    fault=True,
                )
            if st == State.OFFBOARD_ACTIVE:
                if not fresh:
                    return self._handback(
                        now,
                        f"stale input: no command for {now - self._t_cmd:.3f} s "
                        f"(> {cfg.input_timeout} s)",
                        fault=True,
                    )
                if self.vehicle_mode is not None and self.vehicle_mode != px4.OFFBOARD:
                    return self._stop(
                        now,
                        State.FAILED,
                        f"vehicle left OFFBOARD (now {self.vehicle_mode.name}); "
                        "control stays with PX4/pilot",
                        "warn",
                    )
                if self.armed:
                    self._armed_active = True
                elif cfg.arm or self._armed_active:
                    return self._handback(
                        now,
                        "vehicle disarmed during OFFBOARD (landed or auto-disarm); "
                        "handing back so PX4 does not keep reporting OFFBOARD",
                        fault=True,
                    )
        if st in STREAMING or st == State.HANDBACK:
            out += self._stream(now, fresh)
        if st == State.PRESTREAM:
            if now - self._t_stream0 > cfg.prestream_time:
                out += self._go(
                    now, State.SWITCHING, f"pre-streamed {now - self._t_stream0:.2f} s"
                )
                out += self._send(
                    now,
                    MAV_CMD_DO_SET_MODE,
                    _set_mode_params(px4.OFFBOARD),
                    "OFFBOARD",
                    self.vehicle_mode == px4.OFFBOARD,
                )
        elif st == State.SWITCHING:
            if self._confirmed(now, mode=px4.OFFBOARD):
                self._pending = None
                why = "OFFBOARD confirmed (final ACK, then HEARTBEAT)"
                if cfg.arm and not self.armed:
                    out += self._go(now, State.ARMING, why)
                    out += self._send(now, MAV_CMD_COMPONENT_ARM_DISARM, (1.0, 0.0), "arm", False)
                else:
                    out += self._go(now, State.OFFBOARD_ACTIVE, why)
            else:
                out += self._check_pending(now)
        elif st == State.ARMING:
            if self._confirmed(now, armed=True):
                self._pending = None
                out += self._go(now, State.OFFBOARD_ACTIVE, "armed (final ACK, then HEARTBEAT)")
            else:
                out += self._check_pending(now)
        elif st == State.HANDBACK:
            if self._target is not None and self._confirmed(now, mode=self._target):
                out += self._handback_confirmed(now)
            else:
                out += self._check_pending(now)
        elif st in (State.DONE, State.FAILED):
            if (
                self._was_armed
                and not self.armed
                and not self.disarmed_after_run
                and self._t_hb > self._t_state
                and self.vehicle_mode is not None
            ):
                self.disarmed_after_run = True
                out.append(
                    StatusEvent(
                        now,
                        st.value,
                        st.value,
                        f"vehicle disarmed in {self.vehicle_mode.name} (landed or auto-disarm)",
                    )
                )
        return out

    # ------------------------------------------------------------- helpers
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

    def _check_pending(self, now: float) -> list[Any]:
        p = self._pending
        if p is None:
            return []
        cfg = self.config
        if p.t_accepted is not None:
            if now - p.t_accepted > cfg.mode_confirm_timeout:
                reason = (
                    f"{p.what} (command {p.command}) accepted but the HEARTBEAT did not show it "
                    f"within {cfg.mode_confirm_timeout} s"
                )
                if self.state == State.HANDBACK:
                    return self._next_handback(now, reason)
                return self._retry_or_fail(now, reason)
            return []
        if now - p.t_sent > cfg.ack_timeout:
            return self._retry_or_fail(
                now,
                f"no COMMAND_ACK for command {p.command} within {cfg.ack_timeout} s ({p.what})",
            )
        return []

    def _retry_or_fail(self, now: float, reason: str) -> list[Any]:
        p = self._pending
        assert p is not None
        if p.attempts <= self.config.max_retries:
            p.resend(now)
            return [
                StatusEvent(
                    now,
                    self.state.value,
                    self.state.value,
                    f"{reason}; retry {p.attempts - 1}/{self.config.max_retries}",
                    "warn",
                ),
                SendCommand(p.command, p.params, p.attempts),
            ]
        return self._fail_step(now, reason)

    def _fail_step(self, now: float, reason: str) -> list[Any]:
        self._pending = None
        if self.state == State.HANDBACK:
            return self._next_handback(now, reason)
        if self.state == State.SWITCHING:
            if self.vehicle_mode == px4.OFFBOARD:
                return self._handback(now, f"switch to OFFBOARD failed: {reason}", fault=True)
            return self._stop(now, State.FAILED, f"switch to OFFBOARD failed: {reason}", "error")
        return self._handback(now, f"{self.state.value} failed: {reason}", fault=True)

    def _handback(
        self,
        now: float,
        reason: str,
        fault: bool,
        first: px4.Px4Mode | None = None,
        force: bool = False,
    ) -> list[Any]:
        if not force and self.state == State.PRESTREAM and self.vehicle_mode != px4.OFFBOARD:
            # nothing was handed over yet: just stop streaming
            return self._stop(
                now, State.FAILED if fault else State.DONE, reason, "warn" if fault else "info"
            )
        self._fault = fault
        self._handback_reason = reason
        self._failures = []
        self.confirmed_mode = None
        chain = list(self.config.chain)
        if first is not None:
            chain = [m for m in chain if m != first]
        self._chain = chain
        out = self._go(now, State.HANDBACK, reason, "warn" if fault else "info")
        return out + self._request_next(now, first=first)

    def _request_next(self, now: float, first: px4.Px4Mode | None = None) -> list[Any]:
        mode = first if first is not None else self._chain.pop(0)
        self._target = mode
        return self._send(
            now, MAV_CMD_DO_SET_MODE, _set_mode_params(mode), mode.name, self.vehicle_mode == mode
        )

    def _next_handback(self, now: float, reason: str) -> list[Any]:
        failed = self._target.name if self._target is not None else "?"
        self._failures.append(f"{failed}: {reason}")
        self._pending = None
        if self._chain:
            nxt = self._chain[0]
            return [
                StatusEvent(
                    now,
                    self.state.value,
                    self.state.value,
                    f"hand-back to {failed} failed ({reason}); trying {nxt.name}",
                    "warn",
                )
            ] + self._request_next(now)
        self._target = None
        return self._stop(
            now,
            State.FAILED,
            f"hand-back NOT confirmed: {'; '.join(self._failures)}; PX4 failsafe in charge "
            f"(COM_OF_LOSS_T -> COM_OBL_RC_ACT once the stream stops) [{self._handback_reason}]",
            "error",
        )

    def _handback_confirmed(self, now: float) -> list[Any]:
        mode = self._target
        assert mode is not None
        self.confirmed_mode = mode
        self._target = None
        before = f" after {'; '.join(self._failures)}" if self._failures else ""
        reason = f"hand-back confirmed: vehicle in {mode.name}{before}: {self._handback_reason}"
        if self._fault:
            return self._stop(now, State.FAILED, reason, "warn")
        return self._stop(now, State.DONE, reason, "info")

    def _stop(self, now: float, new: State, reason: str, level: str) -> list[Any]:
        self._pending = None
        self._fault = new == State.FAILED
        return self._go(now, new, reason, level)


def _set_mode_params(mode: px4.Px4Mode) -> tuple[float, ...]:
    return (float(px4.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(mode.main), float(mode.sub))
