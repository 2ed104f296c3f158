"""Hand-back chain of the PX4 offboard machine.

The modes of ``handback_chain`` are requested in turn until a HEARTBEAT confirms one
(DONE / FAILED name it) or the chain is exhausted (FAILED, level ``error``: PX4's
failsafe is in charge); ``finish`` ends a campaign in a chosen mode with the same
rules. The rules are documented in :mod:`lpv_sysid.mavlink.offboard`.
"""

from __future__ import annotations

from typing import Any

from lpv_sysid.errors import ConfigError
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.offboard.state import (
    MAV_CMD_DO_SET_MODE,
    STREAMING,
    OffboardState,
    State,
    StatusEvent,
    _set_mode_params,
)


class HandbackChain(OffboardState):
    """The hand-back of :class:`lpv_sysid.mavlink.offboard.OffboardMachine`: which mode is
    requested next, and how the chain ends."""

    def finish(self, now: float, mode: str | px4.Px4Mode = "LAND") -> list[Any]:
        """End in ``mode`` (e.g. LAND at the end
        of a campaign); see :mod:`lpv_sysid.mavlink.offboard`."""
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
