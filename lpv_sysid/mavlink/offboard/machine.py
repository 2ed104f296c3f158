"""The PX4 offboard state machine (:class:`OffboardMachine`); the method is the
:mod:`lpv_sysid.mavlink.offboard` docstring."""

from __future__ import annotations

import math
from typing import Any

from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.offboard.handback import HandbackChain
from lpv_sysid.mavlink.offboard.state import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_IN_PROGRESS,
    MAV_RESULT_TEMPORARILY_REJECTED,
    STREAMING,
    SendCommand,
    SendSetpoint,
    State,
    StatusEvent,
    _set_mode_params,
)


class OffboardMachine(HandbackChain):
    """The state machine of the module docstring: its inputs, the periodic step and the
    timeouts and retries of a pending command (state and evidence:
    :class:`~lpv_sysid.mavlink.offboard.state.OffboardState`; hand-back chain:
    :class:`~lpv_sysid.mavlink.offboard.handback.HandbackChain`)."""

    # --------------------------------------------------------------- inputs
    def start(self, now: float) -> list[Any]:
        if self.state in STREAMING or self.state == State.HANDBACK:
            return []
        self._fault = False
        self._pending = None
        self._target = None
        self.confirmed_mode = None
        self.disarmed_after_run = False
        self._left_offboard = False
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
            out += self._offboard_after_end(now, st)
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

    def _offboard_after_end(self, now: float, st: State) -> list[Any]:
        """DONE/FAILED: a HEARTBEAT (after the end) showing OFFBOARD once the vehicle was
        seen out of it (the confirmed hand-back mode, a pilot's mode) is reported, level
        ``error``, every time it happens: nobody streams setpoints any more, so PX4's
        offboard-loss failsafe (COM_OF_LOSS_T -> COM_OBL_RC_ACT) is in charge."""
        mode = self.vehicle_mode
        if mode is None or self._t_hb < self._t_state:
            return []
        if mode != px4.OFFBOARD:
            self._left_offboard = True
            return []
        if not self._left_offboard:
            return []  # never left OFFBOARD (e.g. an unconfirmed hand-back): FAILED said it
        self._left_offboard = False
        self.reverted_to_offboard += 1
        return [
            StatusEvent(
                now,
                st.value,
                st.value,
                f"vehicle back in OFFBOARD after the run ended ({st.value}: {self.reason}); "
                "nothing streams setpoints: PX4's offboard-loss failsafe (COM_OF_LOSS_T -> "
                "COM_OBL_RC_ACT) is in charge",
                "error",
            )
        ]

    # ------------------------------------------------------- pending command
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
