"""The campaign sequencer (:class:`Campaign`): inputs, one ``step`` per loop period, the
summary; the method is the :mod:`lpv_sysid.control.campaign` docstring."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lpv_sysid.control.campaign.flight import CampaignFlight
from lpv_sysid.control.campaign.protocol import (
    ABORTED,
    ABORTING,
    EXCITATION,
    FINISHING,
    IDLE,
    LANDING,
    RUN_PHASES,
    STARTING,
    TAKEOFF,
    TERMINAL,
    TRIM,
    CampaignOutput,
    StartBridge,
    VehicleStatus,
)


class Campaign(CampaignFlight):
    """The sequence of the module docstring for one :class:`CampaignPlan`."""

    # ------------------------------------------------------------------ inputs
    def on_state(self, sample: Any) -> None:
        """A state sample (``t``, ``pos_ned``, ``euler``, ``v_body``, ``omega``)."""
        self.state = sample
        if self.phase in (TRIM, EXCITATION) and self.results:
            self._accumulate(sample)

    def on_rotor(self, t: float, omega: Any) -> None:
        self._rotor = (float(t), np.asarray(omega, dtype=float))
        if self.phase == TRIM and self.results:
            res = self.results[-1]
            if t >= res.t_start + self.cfg.trim_s - self.cfg.trim_average_s:
                res._trim_rotor.append(self._rotor[1])

    def start(self, now: float) -> CampaignOutput:
        out = CampaignOutput()
        if self.phase != IDLE:
            return out
        self._go(now, STARTING, f"{len(self.plan.runs)} runs planned; starting offboard", out)
        out.actions.append(StartBridge())
        return out

    def abort(self, now: float, reason: str) -> CampaignOutput:
        """External abort (operator, Ctrl-C, service): excitation off at once, hand-back
        requested by the next :meth:`step` (which knows the bridge state)."""
        out = CampaignOutput()
        if self.phase == IDLE:
            self.ok = False
            self.reason = reason
            self._go(now, ABORTED, f"{reason} (before start)", out, "warn")
        elif self.phase not in TERMINAL and self.phase != ABORTING and self._abort_request is None:
            self._abort_request = reason
            self._exc = None
        return out

    # ------------------------------------------------------------------ step
    def step(self, now: float, vs: VehicleStatus) -> CampaignOutput:
        out = CampaignOutput()
        ph = self.phase
        if ph in TERMINAL or ph == IDLE:
            return out
        if vs.home_ned is not None and self.home is None:
            self.home = np.asarray(vs.home_ned, dtype=float).copy()
        if self._abort_request is not None and ph not in (ABORTING, FINISHING, LANDING):
            reason, self._abort_request = self._abort_request, None
            self._fault(now, reason, out, vs)
            return out
        if self._abort_request is not None and ph == FINISHING:
            # the hand-back is already under way: keep waiting for its confirmation
            self.reason, self._abort_request = self._abort_request, None
            self._go(
                now,
                ABORTING,
                f"abort: {self.reason}; waiting for the hand-back confirmation",
                out,
                "warn",
            )
            ph = ABORTING
        if self._abort_request is not None and ph == LANDING:
            reason, self._abort_request = self._abort_request, None
            self.ok = False
            self.reason = reason
            self._go(
                now,
                ABORTED,
                f"{reason} while landing: vehicle stays with PX4 in {vs.mode}",
                out,
                "warn",
            )
            return out
        if ph == ABORTING:
            self._wait_handback(now, vs, out, aborting=True)
            return out
        if ph == FINISHING:
            self._wait_handback(now, vs, out, aborting=False)
            return out
        if ph == LANDING:
            self._landing(now, vs, out)
            return out
        # ---- phases in which we command the vehicle
        if ph == STARTING:
            if vs.bridge_state in ("HANDBACK", "DONE", "FAILED") or (
                vs.bridge_state == "IDLE" and now - self.t_phase > 1.0
            ):
                self._fault(
                    now,
                    f"offboard start failed: bridge {vs.bridge_state}: {vs.bridge_reason}",
                    out,
                    vs,
                )
                return out
            if now - self.t_phase > self.cfg.start_timeout:
                self._fault(
                    now,
                    f"not in OFFBOARD and armed within start_timeout {self.cfg.start_timeout:g} s "
                    f"(bridge {vs.bridge_state}, mode {vs.mode}, armed {vs.armed}"
                    + (
                        "; the bridge must arm: offboard.arm true"
                        if vs.bridge_state == "OFFBOARD_ACTIVE"
                        else ""
                    )
                    + ")",
                    out,
                    vs,
                )
                return out
            if vs.bridge_state == "OFFBOARD_ACTIVE" and vs.armed and self._fresh(now):
                if self.home is None:
                    self.home = np.asarray(self.state.pos_ned, dtype=float).copy()
                self._h_target = self.cfg.takeoff_altitude
                self._xy_target = self.home[:2].copy()
                self._go(
                    now,
                    TAKEOFF,
                    f"OFFBOARD, armed; climbing to {self.cfg.takeoff_altitude:g} m",
                    out,
                )
            self._send(now, np.zeros(3), out)
            return out
        if vs.bridge_state != "OFFBOARD_ACTIVE":
            why = f"envelope: {vs.violation}" if vs.violation else vs.bridge_reason
            self._fault(now, f"bridge left OFFBOARD_ACTIVE ({vs.bridge_state}): {why}", out, vs)
            return out
        if not self._fresh(now):
            age = now - self.state.t if self.state is not None else math.inf
            self._fault(
                now,
                f"no fresh state sample for {age:.2f} s (> state_timeout "
                f"{self.cfg.state_timeout:g} s)",
                out,
                vs,
            )
            return out
        s = self.state
        h = self._height(s)
        self._vs = vs
        if ph in RUN_PHASES:
            guard = self._guard(now, s, h)
            if guard:
                self._fault(now, guard, out, vs)
                return out
        getattr(self, "_" + ph)(now, s, h, out)
        return out

    # ------------------------------------------------------------- summary
    def summary(self) -> dict:
        def r(x, n=3):
            return round(float(x), n) if math.isfinite(x) else None

        return {
            "format": "lpv_sysid/campaign_summary@1",
            "result": self.phase,
            "ok": bool(self.ok),
            "reason": self.reason,
            "velocity_frame": self.cfg.velocity_frame,
            "t_takeoff_done": r(self.t_takeoff_done),
            "handback": {
                "requested": r(self.t_handback_request),
                "confirmed": r(self.t_handback_done),
                "duration_s": r(self.t_handback_done - self.t_handback_request),
                "mode": self.handback_mode,
            },
            "t_landed": r(self.t_land_done),
            "plan": [p.to_dict() for p in self.plan.runs],
            "runs": [res.to_dict() for res in self.results],
        }
