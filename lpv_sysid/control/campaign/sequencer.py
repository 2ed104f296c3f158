"""Phase-1 flight campaign sequencer (pure: no I/O, no clock; every call carries its time).

What a flight-test engineer flies for seed 0 Sec. IV on a real PX4, as one sequence:

1. ``starting``: the bridge pre-streams zero velocity, switches PX4 to OFFBOARD and arms
   (PX4 accepts arming in OFFBOARD while setpoints stream);
2. ``takeoff``: velocity setpoints from an altitude P loop climb to ``takeoff_altitude``
   above home; then the envelope's floor is activated explicitly;
3. for each planned run (the vertices of the body-velocity box, then the hover
   validation run):

   - ``reposition``: P loop to a start point: a height that leaves room for the whole
     segment inside the altitude window, and (``center_runs``) a horizontal point such
     that the straight run at the vertex velocity is centred on home;
   - ``settle``: command the vertex; wait until the measured velocity *in the frame the
     setpoint is commanded in* (PX4 MAV_FRAME_BODY_NED = NED rotated by yaw only, the
     bridge's ``velocity_frame: body_ned``; :data:`FRAMES` says why not ``local_ned``) is
     within ``settle_tolerance`` on every axis for ``settle_dwell`` seconds;
     ``settle_timeout`` -> abort with the errors in the reason;
   - ``trim`` (``trim_s``, constant reference; the recorded run starts here) then
     ``excitation``: the phase-1 multisine of :mod:`lpv_sysid.signals.excitation`
     (channels ``u_ref, v_ref, w_ref, r_ref``, raised-cosine ramps) superposed on the
     vertex; the recorded run ends with the excitation;
   - ``recover``: zero velocity (hover) until the speed is below ``hover_tolerance`` for
     ``settle_dwell``;

4. ``finishing``: the bridge ends the session in ``finish`` (HOLD or LAND) and must
   confirm that mode; with LAND then ``landing``: the vehicle must disarm (landed) within
   ``land_timeout``.

Altitude is held: on a w = 0 vertex (and hover) a slow correction
``dw = clip(dw_ff + hold_gain (h - h_target), +-hold_max)`` (NED, positive down) is added to
the commanded w and recorded in ``velocity_reference`` as flown. During ``settle`` the
target is the height where the vertex was first commanded and ``dw_ff = 0``; when the
vehicle has settled, the target becomes the height at that moment and ``dw_ff`` the
opposite of the vertical velocity the vehicle showed *beyond* its command over the settled
dwell (a vehicle sinking 0.1 m/s more than commanded gets dw_ff = -0.1). The correction is
then frozen at ``dw_ff`` during the trim segment (the identification takes the trim mean as
the scheduling vertex and finds the excitation start where the reference first leaves its
trim value; ``hold_max`` therefore stays below the 0.25 m/s with which ``lpv-sysid identify``
snaps a trim reference to the box) and active again during the excitation. A w != 0 vertex is a
climb (w < 0, NED) or descent segment bounded by the altitude
window: the plan (:func:`plan_campaign`) orders the vertices so that climbs and descents
alternate (and consecutive horizontal directions oppose, so the runs return towards
home), and refuses at load time, with the numbers, a window that cannot hold a segment of
``|w| (settle_timeout + trim_s + excitation) + excitation displacement + 2 margins``.

Any fault (bridge left OFFBOARD, envelope violation reported by the bridge, settle or
phase timeout, stale state, leaving the altitude window or the campaign radius, external
abort) turns the excitation off and stops commanding: ``aborting`` requests the
hand-back (unless the bridge already gave control back) and waits for the bridge's
confirmation: ``aborted`` (hand-back confirmed) or ``failed`` (not confirmed).

The runner (``lpv_sysid/cli/fly.py``, ``lpv_sysid/nodes/campaign_node.py``) feeds state
and rotor samples (:meth:`Campaign.on_state`, :meth:`Campaign.on_rotor`) and calls
:meth:`Campaign.step` with a :class:`VehicleStatus`; it carries out the returned actions
(:class:`StartBridge`, :class:`AbortBridge`, :class:`FinishBridge`, :class:`ActivateFloor`,
:class:`RunStarted`, :class:`RunEnded`) and sends ``output.command`` as the velocity
reference.

Modules: the configuration (:mod:`~lpv_sysid.control.campaign.config`), the plan
(:mod:`~lpv_sysid.control.campaign.plan`), the runner interface
(:mod:`~lpv_sysid.control.campaign.protocol`), the per-run results
(:mod:`~lpv_sysid.control.campaign.results`), the sequencer's state
(:mod:`~lpv_sysid.control.campaign.state`), its ending and flying phases
(:mod:`~lpv_sysid.control.campaign.handback`, :mod:`~lpv_sysid.control.campaign.flight`);
this module holds the public :class:`Campaign` (inputs, ``step``, summary) and re-exports
the public names of the others.
"""

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
