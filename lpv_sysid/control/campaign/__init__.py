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

The runner (``lpv_sysid/cli/vehicle/fly.py``, ``lpv_sysid/nodes/campaign_node.py``) feeds state
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
the sequencer :class:`Campaign` itself (inputs, ``step``, summary):
:mod:`~lpv_sysid.control.campaign.sequencer`.
"""

from __future__ import annotations

from lpv_sysid.control.campaign.config import CampaignConfig
from lpv_sysid.control.campaign.plan import (
    CLIMB,
    DESCENT,
    LEVEL,
    ExcitationProfile,
    Px4Need,
    airspace,
    plan_campaign,
    px4_needs,
    run_name,
)
from lpv_sysid.control.campaign.protocol import (
    ABORTED,
    ABORTING,
    DONE,
    EXCITATION,
    FAILED,
    FINISHING,
    IDLE,
    LANDING,
    REPOSITION,
    SETTLE,
    STARTING,
    TAKEOFF,
    TERMINAL,
    TRIM,
    AbortBridge,
    ActivateFloor,
    CampaignOutput,
    FinishBridge,
    RunEnded,
    RunStarted,
    StartBridge,
    VehicleStatus,
)
from lpv_sysid.control.campaign.results import trim_rows
from lpv_sysid.control.campaign.sequencer import Campaign

__all__ = [
    "ABORTED",
    "ABORTING",
    "AbortBridge",
    "ActivateFloor",
    "CLIMB",
    "Campaign",
    "CampaignConfig",
    "CampaignOutput",
    "DESCENT",
    "DONE",
    "EXCITATION",
    "ExcitationProfile",
    "Px4Need",
    "FAILED",
    "FINISHING",
    "FinishBridge",
    "IDLE",
    "LANDING",
    "LEVEL",
    "REPOSITION",
    "RunEnded",
    "RunStarted",
    "SETTLE",
    "STARTING",
    "StartBridge",
    "TAKEOFF",
    "TERMINAL",
    "TRIM",
    "VehicleStatus",
    "airspace",
    "plan_campaign",
    "px4_needs",
    "run_name",
    "trim_rows",
]
