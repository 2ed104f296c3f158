"""How a campaign ends: a fault turns the excitation off, stops commanding and requests the
hand-back; the sequencer then waits for the bridge's confirmation (``aborted`` or
``failed``), or after the last run for the finish mode and, with LAND, for the disarm
(``done``). The sequence is described in :mod:`lpv_sysid.control.campaign`."""

from __future__ import annotations

from lpv_sysid.control.campaign.protocol import (
    ABORTED,
    ABORTING,
    DONE,
    FAILED,
    LANDING,
    SETTLE,
    TERMINAL,
    AbortBridge,
    CampaignOutput,
    RunEnded,
    VehicleStatus,
)
from lpv_sysid.control.campaign.state import CampaignState


class CampaignHandback(CampaignState):
    """The ending of :class:`lpv_sysid.control.campaign.Campaign`: faults, ``aborting``,
    ``finishing`` and ``landing``."""

    def _fault(self, now: float, reason: str, out: CampaignOutput, vs: VehicleStatus) -> None:
        """Excitation off, stop commanding, and: bridge streaming -> request the hand-back
        and wait (``aborting``); already handing back -> wait; hand-back already confirmed
        (DONE) -> ``aborted``; FAILED -> ``failed``; never started (IDLE) -> ``aborted``."""
        if self.phase in TERMINAL or self.phase == ABORTING:
            return
        if self._recording and self.results:
            res = self.results[-1]
            res.reason = reason
            res.t_end = now
            self._finish_tracking(res)
            out.actions.append(RunEnded(self._active_run, now, False, res))
            self._recording = False
        elif self.phase == SETTLE and self.results:
            self.results[-1].reason = reason
        self.reason = reason
        self._exc = None
        self.ok = False
        self.t_handback_request = now
        st = vs.bridge_state
        if st == "IDLE":
            self._go(now, ABORTED, f"abort: {reason}; offboard never started", out, "error")
        elif st == "DONE":
            self.t_handback_done = now
            self.handback_mode = vs.mode or ""
            self._go(
                now,
                ABORTED,
                f"abort: {reason}; control already back with PX4 ({vs.mode})",
                out,
                "error",
            )
        elif st == "FAILED" and vs.confirmed_mode:
            self.t_handback_done = now
            self.handback_mode = vs.confirmed_mode
            self._go(
                now,
                ABORTED,
                f"abort: {reason}; control already back with PX4 ({vs.confirmed_mode}, "
                f"{vs.bridge_reason})",
                out,
                "error",
            )
        elif st == "FAILED":
            self._go(
                now,
                FAILED,
                f"abort: {reason}; HAND-BACK NOT CONFIRMED ({vs.bridge_reason}); "
                f"PX4's offboard-loss failsafe is in charge",
                out,
                "error",
            )
        else:
            self._go(now, ABORTING, f"abort: {reason}; excitation off, handing back", out, "error")
            if st != "HANDBACK":
                out.actions.append(AbortBridge(reason))

    def _wait_handback(
        self, now: float, vs: VehicleStatus, out: CampaignOutput, aborting: bool
    ) -> None:
        """DONE, or FAILED with a confirmed mode (the bridge ends a *fault* hand-back, e.g.
        stale input or link loss, in FAILED even when PX4 confirmed the mode): control is
        back with PX4. FAILED without a confirmed mode: nothing confirmed, failsafe."""
        if vs.bridge_state == "FAILED" and vs.confirmed_mode:
            self.t_handback_done = now
            self.handback_mode = vs.confirmed_mode
            self.ok = False
            if not aborting:
                self.reason = (
                    self.reason + "; " if self.reason else ""
                ) + f"bridge: {vs.bridge_reason}"
            self._go(
                now,
                ABORTED,
                f"hand-back confirmed in {now - self.t_handback_request:.2f} s after a "
                f"fault, vehicle in {vs.confirmed_mode}: {self.reason}",
                out,
                "error",
            )
            return
        if vs.bridge_state == "DONE":
            self.t_handback_done = now
            self.handback_mode = vs.confirmed_mode or vs.mode or ""
            dt = now - self.t_handback_request
            if aborting:
                self.ok = False
                self._go(
                    now,
                    ABORTED,
                    f"hand-back confirmed in {dt:.2f} s, vehicle in {vs.mode}: {self.reason}",
                    out,
                    "error",
                )
                return
            want = str(self.cfg.finish).upper()
            ended = vs.confirmed_mode or vs.mode
            if ended != want:
                self.ok = False
                self.reason = f"finish {want} not confirmed: the hand-back ended in {ended}"
                self._go(
                    now,
                    FAILED,
                    self.reason + ("; land the vehicle manually" if want == "LAND" else ""),
                    out,
                    "error",
                )
                return
            if want == "LAND":
                self._go(
                    now,
                    LANDING,
                    f"LAND confirmed {dt:.2f} s after the request; waiting for disarm",
                    out,
                )
                return self._landing(now, vs, out)
            self.ok = True
            self._go(
                now, DONE, f"campaign complete; vehicle in {vs.mode} (hand-back {dt:.2f} s)", out
            )
            return
        if vs.bridge_state == "FAILED" or vs.bridge_state in ("IDLE",):
            self.ok = False
            why = vs.bridge_reason
            self.reason = (self.reason + "; " if self.reason else "") + f"hand-back FAILED: {why}"
            self._go(
                now,
                FAILED,
                f"HAND-BACK NOT CONFIRMED: {why} (vehicle mode {vs.mode}, armed "
                f"{vs.armed}); PX4's offboard-loss failsafe is in charge",
                out,
                "error",
            )
            return
        if now - self.t_handback_request > self.cfg.handback_timeout:
            self.ok = False
            self.reason = (self.reason + "; " if self.reason else "") + "hand-back timeout"
            self._go(
                now,
                FAILED,
                f"HAND-BACK NOT CONFIRMED within {self.cfg.handback_timeout:g} s "
                f"(bridge {vs.bridge_state}, mode {vs.mode})",
                out,
                "error",
            )

    def _landing(self, now: float, vs: VehicleStatus, out: CampaignOutput) -> None:
        """LAND is confirmed (bridge DONE in LAND): wait for PX4 to land and disarm."""
        cfg = self.cfg
        if not vs.armed:
            self.t_land_done = now
            self.ok = True
            self._go(
                now,
                DONE,
                f"landed and disarmed {now - self.t_phase:.1f} s after LAND was confirmed",
                out,
            )
            return
        if vs.mode != "LAND":
            self.ok = False
            self.reason = f"vehicle left LAND for {vs.mode} before disarming"
            self._go(now, FAILED, self.reason + "; pilot or PX4 has control", out, "error")
            return
        if now - self.t_phase > cfg.land_timeout:
            self.ok = False
            self.reason = (
                f"not disarmed within land_timeout {cfg.land_timeout:g} s (mode {vs.mode})"
            )
            self._go(now, FAILED, self.reason, out, "error")
