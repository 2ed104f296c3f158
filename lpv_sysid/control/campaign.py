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
"""

from __future__ import annotations

import itertools
import logging
import math
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.io import frames
from lpv_sysid.config_fields import check_keys, is_count, is_finite_number

if TYPE_CHECKING:
    from lpv_sysid.signals.excitation import ExcitationCore

log = logging.getLogger(__name__)

IDLE, STARTING, TAKEOFF, REPOSITION, SETTLE = "idle", "starting", "takeoff", "reposition", "settle"
TRIM, EXCITATION, RECOVER, FINISHING, LANDING = (
    "trim",
    "excitation",
    "recover",
    "finishing",
    "landing",
)
DONE, ABORTING, ABORTED, FAILED = "done", "aborting", "aborted", "failed"
TERMINAL = (DONE, ABORTED, FAILED)
FLYING = (TAKEOFF, REPOSITION, SETTLE, TRIM, EXCITATION, RECOVER)
RUN_PHASES = (SETTLE, TRIM, EXCITATION)

CLIMB, DESCENT, LEVEL = "climb", "descent", "level"
#: the campaign commands in MAV_FRAME_BODY_NED (PX4 rotates by yaw only; seed 0's frame). In
#: ``local_ned`` the bridge rotates an FRD body reference by the full attitude, so a w = 0
#: vertex is not level flight: at pitch theta it sinks u sin(theta) (issue 10: 0.7-1.1 m/s,
#: into the ground), and holding altitude would move the recorded reference off the vertex.
FRAMES = ("body_ned",)
FINISH_MODES = ("LAND", "HOLD")
ORDERS = ("alternate", "table")
#: tolerance [m/s] with which ``lpv-sysid identify`` snaps a trim reference to the box
#: (lpv_sysid.ident.dataprep.snap_to_box)
IDENTIFY_SNAP_TOLERANCE = 0.25
_NOMINAL_ACCEL = 2.0  # m/s^2, for the expected settle transient of the horizontal plan


# =============================================================================== config
@dataclass(frozen=True)
class CampaignConfig:
    """``campaign`` section of ``config/campaign.yaml`` (heights above home, m; m/s; s)."""

    box_min: tuple = (-3.0, -3.0, -0.7)
    box_max: tuple = (3.0, 3.0, 0.7)
    vertices: tuple | None = None  # 1-based seed 0 Table 1 indices; None: all 8
    hover_validation: bool = True
    order: str = "alternate"  # alternate | table
    velocity_frame: str = "body_ned"  # the bridge's velocity_frame (body_ned only, see FRAMES)
    rate_hz: float = 50.0  # velocity reference rate
    takeoff_altitude: float = 20.0
    altitude_min: float = 15.0  # campaign altitude window
    altitude_max: float = 70.0
    altitude_margin: float = 2.0  # kept free at both ends of every segment
    altitude_tolerance: float = 1.0  # reached a target height
    position_tolerance: float = 3.0  # reached a horizontal start point
    climb_rate: float = 1.5  # take-off / reposition limits
    descent_rate: float = 1.0
    horizontal_speed: float = 3.0
    position_gain: float = 0.5  # 1/s, take-off / reposition P loop
    hold_gain: float = 0.2  # 1/s, altitude hold on level runs
    hold_max: float = 0.2  # m/s
    radius: float = 250.0  # m, campaign horizontal limit around home
    center_runs: bool = True  # reposition so each run is centred on home
    settle_tolerance: tuple = (0.3, 0.3, 0.3)
    settle_dwell: float = 1.0
    settle_timeout: float = 20.0
    hover_tolerance: float = 0.3  # m/s speed: hover reached (take-off, recover)
    trim_s: float = 10.0
    trim_average_s: float = 5.0  # end of the trim averaged for the equilibrium
    ramp_s: float = 1.0  # excitation raised-cosine ramps
    periods: int = 1  # excitation periods per run
    start_timeout: float = 20.0
    takeoff_timeout: float = 60.0
    reposition_timeout: float = 90.0
    recover_timeout: float = 20.0
    state_timeout: float = 0.5
    handback_timeout: float = 15.0
    finish: str = "LAND"  # LAND | HOLD
    land_timeout: float = 180.0
    arm_length: float | None = None  # m, for the Table 1 delta columns; None: quadrotor default

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "CampaignConfig":
        check_keys(d, {f.name for f in fields(cls)}, "campaign", list_allowed=True)
        kw = dict(d)
        for name in ("box_min", "box_max", "settle_tolerance", "vertices"):
            if name in kw and isinstance(kw[name], list):
                kw[name] = tuple(kw[name])
        cfg = cls(**kw)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        def num(name: str, lo: float = 0.0, strict: bool = True) -> None:
            v = getattr(self, name)
            if not is_finite_number(v) or (v <= lo if strict else v < lo):
                raise ConfigError(
                    f"campaign.{name} must be a finite number {'>' if strict else '>='} "
                    f"{lo:g}, got {v!r}"
                )

        for name, n in (("box_min", 3), ("box_max", 3), ("settle_tolerance", 3)):
            v = getattr(self, name)
            if not (isinstance(v, tuple) and len(v) == n and all(is_finite_number(x) for x in v)):
                raise ConfigError(f"campaign.{name} must be {n} finite numbers, got {v!r}")
        if any(a >= b for a, b in zip(self.box_min, self.box_max)):
            raise ConfigError(
                f"campaign.box_min {list(self.box_min)} must be below box_max "
                f"{list(self.box_max)} in every component"
            )
        if any(x <= 0 for x in self.settle_tolerance):
            raise ConfigError("campaign.settle_tolerance must be positive")
        if self.vertices is not None:
            v = self.vertices
            if not (
                isinstance(v, tuple)
                and v
                and all(is_count(i, 1) and i <= 8 for i in v)
                and len(set(v)) == len(v)
            ):
                raise ConfigError(
                    f"campaign.vertices must be distinct seed 0 Table 1 indices 1..8, got {v!r}"
                )
        for name in ("hover_validation", "center_runs"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"campaign.{name} must be true or false")
        if self.order not in ORDERS:
            raise ConfigError(f"campaign.order must be one of {list(ORDERS)}, got {self.order!r}")
        if self.velocity_frame not in FRAMES:
            raise ConfigError(
                f"campaign.velocity_frame must be 'body_ned', got {self.velocity_frame!r}: with "
                "local_ned the bridge rotates the FRD vertex by the full attitude, so a w = 0 "
                "vertex "
                "sinks u sin(theta) at pitch theta and no altitude hold can keep the vertex"
            )
        if str(self.finish).upper() not in FINISH_MODES:
            raise ConfigError(
                f"campaign.finish must be one of {list(FINISH_MODES)}, got {self.finish!r}"
            )
        for name in (
            "rate_hz",
            "takeoff_altitude",
            "altitude_max",
            "altitude_tolerance",
            "position_tolerance",
            "climb_rate",
            "descent_rate",
            "horizontal_speed",
            "position_gain",
            "hold_gain",
            "hold_max",
            "radius",
            "settle_dwell",
            "settle_timeout",
            "hover_tolerance",
            "trim_s",
            "trim_average_s",
            "start_timeout",
            "takeoff_timeout",
            "reposition_timeout",
            "recover_timeout",
            "state_timeout",
            "handback_timeout",
            "land_timeout",
        ):
            num(name)
        for name in ("altitude_min", "altitude_margin", "ramp_s"):
            num(name, strict=False)
        if not is_count(self.periods, 1):
            raise ConfigError(f"campaign.periods must be an integer >= 1, got {self.periods!r}")
        if self.arm_length is not None:
            num("arm_length")
        if self.altitude_min >= self.altitude_max:
            raise ConfigError(
                f"campaign.altitude_min ({self.altitude_min} m) must be below "
                f"altitude_max ({self.altitude_max} m)"
            )
        if not self.altitude_min <= self.takeoff_altitude <= self.altitude_max:
            raise ConfigError(
                f"campaign.takeoff_altitude {self.takeoff_altitude} m must lie in the "
                f"window [{self.altitude_min}, {self.altitude_max}] m"
            )
        if self.hold_max >= IDENTIFY_SNAP_TOLERANCE:
            raise ConfigError(
                f"campaign.hold_max {self.hold_max} m/s must stay below "
                f"{IDENTIFY_SNAP_TOLERANCE} m/s: the altitude correction is part of the "
                "recorded trim reference that `lpv-sysid identify` snaps to the box"
            )
        if self.trim_average_s > self.trim_s:
            raise ConfigError(
                f"campaign.trim_average_s ({self.trim_average_s} s) must not exceed "
                f"trim_s ({self.trim_s} s)"
            )
        if self.settle_dwell >= self.settle_timeout:
            raise ConfigError(
                f"campaign.settle_dwell ({self.settle_dwell} s) must be shorter than "
                f"settle_timeout ({self.settle_timeout} s)"
            )

    def corners(self) -> list[tuple[float, float, float]]:
        """The 2^3 box corners in seed 0 Table 1 order (u fastest, then v, then w)."""
        lo, hi = self.box_min, self.box_max
        return [
            (u, v, w)
            for w, v, u in itertools.product((lo[2], hi[2]), (lo[1], hi[1]), (lo[0], hi[0]))
        ]


# ============================================================================= planning
@dataclass(frozen=True)
class ExcitationProfile:
    """What the planner needs to know about the phase-1 excitation of one run."""

    duration: float  # s, including both ramps
    peak: tuple  # per-axis |v| peak (u, v, w) [m/s]
    peak_norm: float  # max |v| [m/s]
    yaw_peak: float  # [rad/s]
    span: tuple  # per-axis max - min of the displacement int v dt [m]

    @classmethod
    def from_table(cls, t, u, names, ramp: float, periods: int = 1) -> "ExcitationProfile":
        core = make_excitation(t, u, names, start_time=0.0, ramp=ramp, periods=periods)
        dt = min(core.dt, 0.01)
        tg = np.arange(0.0, core.duration + dt, dt)
        v, r, _ = core.evaluate(tg)
        disp = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (v[1:] + v[:-1]) * dt, axis=0)])
        return cls(
            float(core.duration),
            tuple(float(x) for x in np.max(np.abs(v), axis=0)),
            float(np.max(np.linalg.norm(v, axis=1))),
            float(np.max(np.abs(r))),
            tuple(float(x) for x in disp.max(axis=0) - disp.min(axis=0)),
        )


def make_excitation(
    t, u, names, *, start_time: float, ramp: float, periods: int = 1
) -> ExcitationCore:
    """The phase-1 excitation core of one run: the multisine part only (the vertex is
    added by the campaign), channels ``u_ref, v_ref, w_ref, r_ref``."""
    from lpv_sysid.signals.excitation import PHASE1_CHANNELS, PHASE1_YAW_CHANNEL, ExcitationCore

    return ExcitationCore(
        t,
        u,
        names,
        start_time=start_time,
        velocity_channels=PHASE1_CHANNELS,
        yaw_rate_channel=PHASE1_YAW_CHANNEL,
        ramp=ramp,
        periods=periods,
    )


@dataclass(frozen=True)
class PlannedRun:
    order: int  # 1-based position in the campaign
    name: str  # bag / run name (sim.phase1.run_name, hover_validation)
    table_index: int | None  # seed 0 Table 1 index of the vertex (None: hover)
    vertex: tuple  # commanded (u, v, w) [m/s] in the command frame
    kind: str  # climb | descent | level
    start_window: tuple  # allowed start heights above home [m]
    altitude_room: float  # height the segment needs [m]
    horizontal_extent: float  # worst distance from home during the run [m]
    duration_worst: float  # settle_timeout + trim + excitation [s]
    duration_nominal: float  # expected settle + trim + excitation [s]

    def to_dict(self) -> dict:
        return {
            "order": self.order,
            "name": self.name,
            "table_index": self.table_index,
            "vertex": list(self.vertex),
            "kind": self.kind,
            "start_window_m": [round(x, 3) for x in self.start_window],
            "altitude_room_m": round(self.altitude_room, 3),
            "horizontal_extent_m": round(self.horizontal_extent, 3),
            "duration_worst_s": round(self.duration_worst, 3),
            "duration_nominal_s": round(self.duration_nominal, 3),
        }


@dataclass(frozen=True)
class CampaignPlan:
    config: CampaignConfig
    runs: tuple
    excitation: ExcitationProfile

    def describe(self) -> str:
        lines = [
            f"{'#':>2} {'run':<22} {'kind':<8} {'vertex [m/s]':<20} {'start h [m]':<14} "
            f"{'room [m]':>8} {'extent [m]':>10} {'T_worst [s]':>11}"
        ]
        for r in self.runs:
            vtx = "[" + " ".join(f"{c:+.2g}" for c in r.vertex) + "]"
            win = f"{r.start_window[0]:.1f}-{r.start_window[1]:.1f}"
            lines.append(
                f"{r.order:>2} {r.name:<22} {r.kind:<8} {vtx:<20} {win:<14} "
                f"{r.altitude_room:8.1f} {r.horizontal_extent:10.1f} {r.duration_worst:11.1f}"
            )
        return "\n".join(lines)


def run_name(vertex) -> str:
    from lpv_sysid.sim.phase1 import run_name as _run_name

    return _run_name(vertex)


def plan_campaign(
    cfg: CampaignConfig, excitation: ExcitationProfile, envelope=None
) -> CampaignPlan:
    """Order the runs and check that each fits the altitude window, the radius and the
    envelope (``lpv_sysid.control.envelope.EnvelopeConfig``, optional); raises
    ConfigError naming the run and the numbers otherwise (module docstring)."""
    cfg.validate()
    ex = excitation
    corners = cfg.corners()
    idx = list(cfg.vertices) if cfg.vertices is not None else list(range(1, 9))
    entries = [(i, corners[i - 1]) for i in idx]
    m = cfg.altitude_margin
    win = (cfg.altitude_min, cfg.altitude_max)
    planned = []

    def plan_one(table_index, vertex, name):
        vertex = tuple(float(c) for c in vertex)
        w = vertex[2]
        kind = LEVEL if w == 0 else (DESCENT if w > 0 else CLIMB)
        t_exc = ex.duration
        t_worst = cfg.settle_timeout + cfg.trim_s + t_exc
        uv = math.hypot(vertex[0], vertex[1])
        t_nom = cfg.settle_dwell + math.hypot(*vertex) / _NOMINAL_ACCEL + cfg.trim_s + t_exc
        travel = abs(w) * t_worst
        room = travel + ex.span[2] + 2 * m
        if kind == DESCENT:
            sw = (win[0] + m + travel + ex.span[2], win[1] - m)
        elif kind == CLIMB:
            sw = (win[0] + m, win[1] - m - travel - ex.span[2])
        else:
            sw = (win[0] + m + ex.span[2], win[1] - m - ex.span[2])
        if sw[0] > sw[1]:
            raise ConfigError(
                f"campaign: run {name} ({kind}, vertex {list(vertex)} m/s) does not fit the "
                "altitude "
                f"window [{win[0]:g}, {win[1]:g}] m ({win[1] - win[0]:g} m): it needs "
                f"|w| x (settle_timeout + trim_s + excitation) = {abs(w):g} m/s x "
                f"({cfg.settle_timeout:g} + "
                f"{cfg.trim_s:g} + {t_exc:.4g}) s = {travel:.1f} m + excitation displacement "
                f"{ex.span[2]:.2f} m + 2 x altitude_margin {m:g} m = {room:.1f} m; widen the "
                "window, "
                f"shorten the segment or reduce |w|"
            )
        h_ext = (
            (0.5 if cfg.center_runs else 1.0) * uv * t_worst
            + math.hypot(ex.span[0], ex.span[1])
            + m
        )
        if h_ext > cfg.radius:
            raise ConfigError(
                f"campaign: run {name} (vertex {list(vertex)} m/s) needs {h_ext:.1f} m of "
                "horizontal "
                f"room ({'half of ' if cfg.center_runs else ''}{uv:.3g} m/s x {t_worst:.4g} s + "
                f"excitation {math.hypot(ex.span[0], ex.span[1]):.2f} m + margin {m:g} m) but "
                f"campaign.radius is {cfg.radius:g} m"
            )
        return dict(
            name=name,
            table_index=table_index,
            vertex=vertex,
            kind=kind,
            start_window=sw,
            altitude_room=room,
            horizontal_extent=h_ext,
            duration_worst=t_worst,
            duration_nominal=t_nom,
        )

    for i, vtx in entries:
        planned.append(plan_one(i, vtx, run_name(vtx)))
    order = _order_runs(planned, cfg) if cfg.order == "alternate" else planned
    if cfg.hover_validation:
        # `lpv-sysid identify` takes the run at the box centre as the validation maneuver
        centre = tuple(0.5 * (a + b) for a, b in zip(cfg.box_min, cfg.box_max))
        order.append(
            plan_one(None, centre, "hover_validation" if not any(centre) else "centre_validation")
        )
    runs = tuple(PlannedRun(order=k + 1, **p) for k, p in enumerate(order))
    if envelope is not None:
        _check_envelope(cfg, runs, ex, envelope)
    return CampaignPlan(cfg, runs, ex)


def _order_runs(planned: list[dict], cfg: CampaignConfig) -> list[dict]:
    """Greedy: climbs and descents alternate; consecutive horizontal directions oppose
    (their displacements cancel); ties keep seed 0 Table 1 order. The first run is the
    one that can start closest to the take-off height."""
    left = list(planned)
    out: list[dict] = []
    h = cfg.takeoff_altitude

    def start_cost(p):
        lo, hi = p["start_window"]
        return max(lo - h, 0.0, h - hi)

    while left:
        if not out:
            best = min(left, key=lambda p: (start_cost(p), left.index(p)))
        else:
            last = out[-1]

            def cost(p):
                alt = 0.0
                if p["kind"] != LEVEL and last["kind"] != LEVEL and p["kind"] == last["kind"]:
                    alt = 10.0
                a, b = np.asarray(last["vertex"][:2]), np.asarray(p["vertex"][:2])
                na, nb = np.linalg.norm(a), np.linalg.norm(b)
                dot = float(a @ b / (na * nb)) if na > 0 and nb > 0 else 0.0
                return (alt + dot, left.index(p))

            best = min(left, key=cost)
        out.append(best)
        left.remove(best)
    return out


def _check_envelope(cfg: CampaignConfig, runs, ex: ExcitationProfile, env) -> None:
    """The campaign's commands and window against the bridge's safety envelope."""
    max_down = max([cfg.descent_rate, cfg.hold_max] + [r.vertex[2] + ex.peak[2] for r in runs])
    max_up = max([cfg.climb_rate, cfg.hold_max] + [-r.vertex[2] + ex.peak[2] for r in runs])
    if env.enabled:
        lo = env.floor + max_down * env.lookahead
        if cfg.altitude_min - cfg.altitude_margin < lo:
            raise ConfigError(
                f"campaign: altitude_min {cfg.altitude_min:g} m - altitude_margin "
                f"{cfg.altitude_margin:g} m "
                f"is too close to the envelope floor: descending at up to {max_down:.2f} m/s, the "
                f"predictive floor (floor {env.floor:g} m + {max_down:.2f} m/s x lookahead "
                f"{env.lookahead:g} s = {lo:.1f} m) would trip; raise altitude_min"
            )
        if cfg.takeoff_altitude <= env.floor + env.floor_arm_margin:
            raise ConfigError(
                f"campaign: takeoff_altitude {cfg.takeoff_altitude:g} m must be above the "
                f"envelope floor + floor_arm_margin ({env.floor + env.floor_arm_margin:g} m)"
            )
        hi = env.ceiling - max_up * env.lookahead
        if cfg.altitude_max + cfg.altitude_margin > hi:
            raise ConfigError(
                f"campaign: altitude_max {cfg.altitude_max:g} m + altitude_margin "
                f"{cfg.altitude_margin:g} m "
                f"is too close to the envelope ceiling: climbing at up to {max_up:.2f} m/s the "
                f"predictive ceiling trips above {hi:.1f} m (ceiling {env.ceiling:g} m - "
                f"{max_up:.2f} m/s x "
                f"{env.lookahead:g} s); lower altitude_max"
            )
        if cfg.radius > env.radius:
            raise ConfigError(
                f"campaign.radius {cfg.radius:g} m exceeds the envelope radius {env.radius:g} m"
            )
        for r in runs:
            top = math.hypot(*r.vertex) + ex.peak_norm + cfg.hold_max
            lim = min(env.max_setpoint, env.max_speed)
            if top > lim:
                raise ConfigError(
                    f"campaign: run {r.name} commands up to |v| = {math.hypot(*r.vertex):.2f} + "
                    "excitation "
                    f"{ex.peak_norm:.2f} + hold {cfg.hold_max:g} = {top:.2f} m/s, above the "
                    "envelope's "
                    f"min(max_setpoint, max_speed) = {lim:g} m/s"
                )
            h_ext = r.horizontal_extent + math.hypot(*r.vertex[:2]) * env.lookahead
            if h_ext > env.radius:
                raise ConfigError(
                    f"campaign: run {r.name} reaches {r.horizontal_extent:.1f} m from home; "
                    f"with the envelope's predictive fence (lookahead {env.lookahead:g} s) "
                    f"that needs {h_ext:.1f} m > radius {env.radius:g} m"
                )
        if ex.yaw_peak > env.max_setpoint_yaw_rate:
            raise ConfigError(
                f"campaign: excitation yaw-rate peak {ex.yaw_peak:.3g} rad/s exceeds the "
                f"envelope's max_setpoint_yaw_rate {env.max_setpoint_yaw_rate:g} rad/s"
            )
        if cfg.horizontal_speed > min(env.max_setpoint, env.max_speed):
            raise ConfigError(
                f"campaign.horizontal_speed {cfg.horizontal_speed:g} m/s exceeds the envelope"
            )


# ============================================================================ runtime
@dataclass(frozen=True)
class VehicleStatus:
    """What the runner knows about the bridge and the vehicle at ``step`` time."""

    bridge_state: str  # OffboardMachine state value (IDLE ... FAILED)
    bridge_reason: str = ""
    mode: str | None = None  # PX4 mode name from the HEARTBEAT
    armed: bool = False
    home_ned: Any = None  # the envelope's home (NED), when armed
    violation: str | None = None  # the envelope's latched violation, if any
    confirmed_mode: str | None = None  # hand-back mode the bridge confirmed (DONE, or FAILED
    # after a fault hand-back that PX4 confirmed)


@dataclass(frozen=True)
class StartBridge:
    pass


@dataclass(frozen=True)
class AbortBridge:
    reason: str


@dataclass(frozen=True)
class ActivateFloor:
    reason: str


@dataclass(frozen=True)
class FinishBridge:
    """End the offboard session in ``mode`` (HOLD or LAND) with the bridge's confirmation
    rules (``BridgeCore.finish``)."""

    mode: str


@dataclass(frozen=True)
class RunStarted:
    run: PlannedRun
    t: float


@dataclass(frozen=True)
class RunEnded:
    run: PlannedRun
    t: float
    complete: bool
    result: "RunResult"


@dataclass(frozen=True)
class CampaignEvent:
    t: float
    phase: str
    message: str
    level: str = "info"  # info | warn | error


@dataclass
class CampaignOutput:
    command: tuple | None = None  # (v (3,) in the command frame [m/s], yaw rate [rad/s])
    actions: list = field(default_factory=list)
    events: list = field(default_factory=list)


@dataclass
class RunResult:
    """Per-run numbers for the summary (and the trim table)."""

    name: str
    vertex: tuple
    kind: str
    complete: bool = False
    reason: str = ""
    t_command: float = math.nan  # vertex first commanded
    settle_time: float = math.nan  # s from the vertex command to the settled dwell start
    t_start: float = math.nan  # recorded run (trim) start
    t_excite: float = math.nan  # excitation start
    t_end: float = math.nan
    height_start: float = math.nan
    height_min: float = math.inf
    height_max: float = -math.inf
    distance_max: float = 0.0
    tracking_rms: dict = field(default_factory=dict)  # u, v, w [m/s], r [rad/s] (trim+excitation)
    achieved: dict = field(default_factory=dict)  # Table 1 columns (FRD) over the trim average
    achieved_frame: tuple = ()  # mean velocity in the command frame
    hold_correction: float = 0.0  # frozen trim correction (NED z) [m/s]
    _sq: np.ndarray = field(default_factory=lambda: np.zeros(4))
    _n: int = 0
    _trim_v: list = field(default_factory=list)
    _trim_vf: list = field(default_factory=list)
    _trim_e: list = field(default_factory=list)
    _trim_rotor: list = field(default_factory=list)

    def to_dict(self) -> dict:
        def r(x, n=4):
            return (
                None
                if x is None or (isinstance(x, float) and not math.isfinite(x))
                else round(float(x), n)
            )

        return {
            "name": self.name,
            "vertex": list(self.vertex),
            "kind": self.kind,
            "complete": self.complete,
            "reason": self.reason,
            "settle_time_s": r(self.settle_time),
            "t_command": r(self.t_command, 3),
            "t_start": r(self.t_start, 3),
            "t_excite": r(self.t_excite, 3),
            "t_end": r(self.t_end, 3),
            "height_start_m": r(self.height_start, 2),
            "height_min_m": r(self.height_min, 2),
            "height_max_m": r(self.height_max, 2),
            "distance_max_m": r(self.distance_max, 2),
            "tracking_rms": {k: r(v) for k, v in self.tracking_rms.items()},
            "achieved_frame": [r(v) for v in self.achieved_frame],
            "achieved": {k: r(v) for k, v in self.achieved.items()},
            "hold_correction_m_s": r(self.hold_correction),
        }


class Campaign:
    """The sequence of the module docstring for one :class:`CampaignPlan`."""

    def __init__(self, plan: CampaignPlan, excitation_table: tuple) -> None:
        self.plan = plan
        self.cfg = plan.config
        self.table = excitation_table
        self.phase = IDLE
        self.reason = ""
        self.ok: bool | None = None
        self.results: list[RunResult] = []
        self.run_index = -1
        self.state: Any = None
        self.home: np.ndarray | None = None
        self.t_phase = 0.0
        self.t_handback_request = math.nan
        self.t_handback_done = math.nan
        self.handback_mode = ""
        self.t_land_done = math.nan
        self.t_takeoff_done = math.nan
        self._next_cmd = -math.inf
        self._dwell_since: float | None = None
        self._h_target = math.nan
        self._xy_target: np.ndarray | None = None
        self._frozen = np.zeros(3)  # the trim/hold offset of the run, set when it settles
        self._ff = 0.0
        self._bias_sum, self._bias_n = 0.0, 0
        self._exc: ExcitationCore | None = None
        self._last_cmd: tuple | None = None
        self._recording = False
        self._rotor: tuple | None = None
        self._abort_request: str | None = None
        self._vs = VehicleStatus("IDLE")
        self._arm_length = self.cfg.arm_length if self.cfg.arm_length is not None else None

    # ------------------------------------------------------------------ inputs
    @property
    def finished(self) -> bool:
        return self.phase in TERMINAL

    @property
    def run(self) -> PlannedRun | None:
        return (
            self.plan.runs[self.run_index] if 0 <= self.run_index < len(self.plan.runs) else None
        )

    @property
    def _active_run(self) -> PlannedRun:
        """The run of a run phase (REPOSITION to EXCITATION), which always has one."""
        run = self.run
        if run is None:
            raise RuntimeError(f"campaign: phase {self.phase} has no current run")
        return run

    @property
    def _home_ned(self) -> np.ndarray:
        """Home (NED, m), known before the take-off starts."""
        if self.home is None:
            raise RuntimeError(f"campaign: phase {self.phase} needs the home position")
        return self.home

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

    # ------------------------------------------------------------------ phases
    def _takeoff(self, now, s, h, out) -> None:
        cfg = self.cfg
        if now - self.t_phase > cfg.takeoff_timeout:
            return self._fault(
                now,
                f"take-off not complete within {cfg.takeoff_timeout:g} s "
                f"(height {h:.2f} m of {self._h_target:g} m)",
                out,
                self._vs,
            )
        v = self._goto(s, h)
        if self._dwell(
            now,
            abs(h - self._h_target) < cfg.altitude_tolerance
            and self._speed(s) < cfg.hover_tolerance,
        ):
            self.t_takeoff_done = now
            out.actions.append(ActivateFloor(f"take-off complete at {h:.1f} m"))
            self._next_run(now, s, h, out)
            return
        self._send(now, v, out)

    def _reposition(self, now, s, h, out) -> None:
        cfg = self.cfg
        if now - self.t_phase > cfg.reposition_timeout:
            return self._fault(
                now,
                f"{self._active_run.name}: start point not reached within reposition_timeout "
                f"{cfg.reposition_timeout:g} s (height {h:.1f} m, target "
                f"{self._h_target:.1f} m)",
                out,
                self._vs,
            )
        v = self._goto(s, h)
        d = float(np.linalg.norm(np.asarray(s.pos_ned)[:2] - self._xy_target))
        if self._dwell(
            now,
            abs(h - self._h_target) < cfg.altitude_tolerance
            and d < cfg.position_tolerance
            and self._speed(s) < cfg.hover_tolerance,
        ):
            run = self._active_run
            res = RunResult(run.name, run.vertex, run.kind, t_command=now, height_start=h)
            self.results.append(res)
            self._h_target = h
            self._ff = 0.0
            self._go(now, SETTLE, f"{run.name}: commanding vertex {list(run.vertex)} m/s", out)
            self._send(now, self._vertex_command(s, h), out)
            return
        self._send(now, v, out)

    def _settle(self, now, s, h, out) -> None:
        cfg = self.cfg
        run, res = self._active_run, self.results[-1]
        cmd = self._vertex_command(s, h)
        err = self._frame_velocity(s) - cmd
        inside = bool(np.all(np.abs(err) <= np.asarray(cfg.settle_tolerance)))
        if inside and self._dwell_since is None:
            self._dwell_since = now
            self._bias_sum, self._bias_n = 0.0, 0
        elif not inside:
            self._dwell_since = None
        if inside and self._last_cmd is not None:
            self._bias_sum += float(self._frame_velocity(s)[2] - self._last_cmd[0][2])
            self._bias_n += 1
        if self._dwell_since is not None and now - self._dwell_since >= cfg.settle_dwell:
            res.settle_time = self._dwell_since - res.t_command
            self._dwell_since = None
            if run.kind == LEVEL:
                # vertical velocity beyond the command over the dwell -> feedforward (docstring)
                bias = self._bias_sum / self._bias_n if self._bias_n else 0.0
                self._h_target = h
                self._ff = min(max(-bias, -cfg.hold_max), cfg.hold_max)
                self._frozen = np.array([0.0, 0.0, self._hold_dz(h)])
            else:
                self._frozen = np.zeros(3)
            res.hold_correction = float(self._frozen[2])
            res.t_start = now
            self._go(
                now,
                TRIM,
                f"{run.name}: settled after {res.settle_time:.2f} s; trim {cfg.trim_s:g} s",
                out,
            )
            out.actions.append(RunStarted(run, now))
            self._recording = True
            self._send(now, np.asarray(run.vertex) + self._frozen, out, force=True)
            return
        if now - res.t_command > cfg.settle_timeout:
            vf = self._frame_velocity(s)
            return self._fault(
                now,
                f"{run.name}: not settled within settle_timeout {cfg.settle_timeout:g} s: "
                f"velocity ({', '.join(f'{x:.2f}' for x in vf)}) of commanded "
                f"({', '.join(f'{x:.2f}' for x in cmd)}) m/s ({cfg.velocity_frame}), "
                f"tolerance {list(cfg.settle_tolerance)}",
                out,
                self._vs,
            )
        self._send(now, cmd, out)

    def _trim(self, now, s, h, out) -> None:
        run, res = self._active_run, self.results[-1]
        if now - res.t_start >= self.cfg.trim_s:
            self._finish_trim(res)
            t, u, names = self.table
            exc = make_excitation(
                t, u, names, start_time=now, ramp=self.cfg.ramp_s, periods=self.cfg.periods
            )
            self._exc = exc
            res.t_excite = now
            self._go(now, EXCITATION, f"{run.name}: excitation {exc.duration:.1f} s", out)
            return self._excitation(now, s, h, out)
        self._send(now, np.asarray(run.vertex) + self._frozen, out)

    def _excitation(self, now, s, h, out) -> None:
        run, res = self._active_run, self.results[-1]
        exc = self._exc
        if exc is None:  # abort() dropped it; the next step() runs the abort
            return
        if now >= exc.end_time:
            res.t_end = now
            res.complete = True
            self._finish_tracking(res)
            self._recording = False
            out.actions.append(RunEnded(run, now, True, res))
            self._h_target = min(max(h, self.cfg.altitude_min), self.cfg.altitude_max)
            self._ff = 0.0
            self._go(now, RECOVER, f"{run.name}: complete; returning to hover", out)
            return self._recover(now, s, h, out)
        ex = exc.sample(now)
        base = np.asarray(run.vertex) + (self._hold_vector(s, h) if run.kind == LEVEL else 0.0)
        self._send(now, base + ex.velocity, out, yaw_rate=float(ex.yaw_rate))

    def _recover(self, now, s, h, out) -> None:
        cfg = self.cfg
        if now - self.t_phase > cfg.recover_timeout:
            return self._fault(
                now,
                f"hover not regained within recover_timeout {cfg.recover_timeout:g} s "
                f"(speed {self._speed(s):.2f} m/s)",
                out,
                self._vs,
            )
        v = np.zeros(3) + self._hold_vector(s, h)
        if self._dwell(now, self._speed(s) < cfg.hover_tolerance):
            return self._next_run(now, s, h, out)
        self._send(now, v, out)

    # ------------------------------------------------------------- transitions
    def _next_run(self, now, s, h, out) -> None:
        self.run_index += 1
        run = self.run
        if run is None:
            mode = str(self.cfg.finish).upper()
            self._go(
                now,
                FINISHING,
                f"all {len(self.plan.runs)} runs complete; handing back in {mode}",
                out,
            )
            self.t_handback_request = now
            out.actions.append(FinishBridge(mode))
            return
        lo, hi = run.start_window
        self._h_target = min(max(h, lo), hi)
        if self.cfg.center_runs:
            psi = float(np.asarray(s.euler)[2])
            uv = np.asarray(run.vertex[:2], dtype=float)
            c, sn = math.cos(psi), math.sin(psi)
            d = np.array([c * uv[0] - sn * uv[1], sn * uv[0] + c * uv[1]]) * run.duration_nominal
            self._xy_target = self._home_ned[:2] - 0.5 * d
        else:
            self._xy_target = np.asarray(s.pos_ned, dtype=float)[:2].copy()
        self._go(
            now,
            REPOSITION,
            f"run {run.order}/{len(self.plan.runs)} {run.name}: start at "
            f"{self._h_target:.1f} m, {np.linalg.norm(self._xy_target - self._home_ned[:2]):.1f} "
            "m "
            "from home",
            out,
        )
        self._send(now, self._goto(s, h), out)

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

    def _go(
        self, now: float, phase: str, message: str, out: CampaignOutput, level: str = "info"
    ) -> None:
        self.phase = phase
        self.t_phase = now
        self._dwell_since = None
        log.debug("campaign %s: %s (%s)", phase, message, level)  # the runners present events
        out.events.append(CampaignEvent(now, phase, message, level))

    # ------------------------------------------------------------- helpers
    def _fresh(self, now: float) -> bool:
        return self.state is not None and now - float(self.state.t) <= self.cfg.state_timeout

    def _height(self, s) -> float:
        return float(self._home_ned[2] - float(s.pos_ned[2]))

    def _vel_ned(self, s) -> np.ndarray:
        v = getattr(s, "vel_ned", None)
        return (
            np.asarray(v, dtype=float)
            if v is not None
            else frames.body_to_world(s.v_body, s.euler)
        )

    def _speed(self, s) -> float:
        return float(np.linalg.norm(self._vel_ned(s)))

    def _frame_velocity(self, s) -> np.ndarray:
        """Measured velocity in the command frame: NED rotated by yaw (MAV_FRAME_BODY_NED)."""
        psi = float(np.asarray(s.euler)[2])
        v = self._vel_ned(s)
        c, sn = math.cos(psi), math.sin(psi)
        return np.array([c * v[0] + sn * v[1], -sn * v[0] + c * v[1], v[2]])

    def _to_frame(self, s, v_ned: np.ndarray) -> np.ndarray:
        psi = float(np.asarray(s.euler)[2])
        c, sn = math.cos(psi), math.sin(psi)
        return np.array([c * v_ned[0] + sn * v_ned[1], -sn * v_ned[0] + c * v_ned[1], v_ned[2]])

    def _goto(self, s, h) -> np.ndarray:
        """P loop to (xy target, height target) in NED, limited, in the command frame."""
        cfg = self.cfg
        pos = np.asarray(s.pos_ned, dtype=float)
        v = np.zeros(3)
        if self._xy_target is not None:
            e = cfg.position_gain * (self._xy_target - pos[:2])
            n = float(np.linalg.norm(e))
            v[:2] = e * (cfg.horizontal_speed / n) if n > cfg.horizontal_speed else e
        up = min(max(cfg.position_gain * (self._h_target - h), -cfg.descent_rate), cfg.climb_rate)
        v[2] = -up
        return self._to_frame(s, v)

    def _hold_dz(self, h: float) -> float:
        dz = self._ff + self.cfg.hold_gain * (h - self._h_target)
        return min(max(dz, -self.cfg.hold_max), self.cfg.hold_max)

    def _hold_vector(self, s, h) -> np.ndarray:
        """The altitude correction in the command frame (MAV_FRAME_BODY_NED keeps NED z)."""
        return np.array([0.0, 0.0, self._hold_dz(h)])

    def _vertex_command(self, s, h) -> np.ndarray:
        run = self._active_run
        v = np.asarray(run.vertex, dtype=float)
        return v + self._hold_vector(s, h) if run.kind == LEVEL else v

    def _dwell(self, now: float, ok: bool) -> bool:
        if not ok:
            self._dwell_since = None
            return False
        if self._dwell_since is None:
            self._dwell_since = now
        return now - self._dwell_since >= self.cfg.settle_dwell

    def _guard(self, now, s, h) -> str:
        cfg = self.cfg
        tol = cfg.altitude_margin
        if h < cfg.altitude_min - tol or h > cfg.altitude_max + tol:
            return (
                f"{self._active_run.name}: height {h:.1f} m left the altitude window "
                f"[{cfg.altitude_min:g}, {cfg.altitude_max:g}] m (+- margin {tol:g} m)"
            )
        d = float(np.linalg.norm(np.asarray(s.pos_ned)[:2] - self._home_ned[:2]))
        if d > cfg.radius:
            return (
                f"{self._active_run.name}: {d:.1f} m from home, outside campaign.radius "
                f"{cfg.radius:g} m"
            )
        if self.results:
            res = self.results[-1]
            res.height_min = min(res.height_min, h)
            res.height_max = max(res.height_max, h)
            res.distance_max = max(res.distance_max, d)
        return ""

    def _send(
        self,
        now: float,
        v: np.ndarray,
        out: CampaignOutput,
        yaw_rate: float = 0.0,
        force: bool = False,
    ) -> None:
        if not force and now < self._next_cmd:
            return
        period = 1.0 / self.cfg.rate_hz
        self._next_cmd = (
            self._next_cmd + period if 0 <= now - self._next_cmd < period else now + period
        )
        cmd = (np.asarray(v, dtype=float).copy(), float(yaw_rate))
        self._last_cmd = cmd
        out.command = cmd

    # ------------------------------------------------------------- statistics
    def _accumulate(self, s) -> None:
        res = self.results[-1]
        if self._last_cmd is None:
            return
        vf = self._frame_velocity(s)
        e = np.r_[vf - self._last_cmd[0], float(np.asarray(s.omega)[2]) - self._last_cmd[1]]
        res._sq += e * e
        res._n += 1
        if (
            self.phase == TRIM
            and float(s.t) >= res.t_start + self.cfg.trim_s - self.cfg.trim_average_s
        ):
            res._trim_v.append(np.asarray(s.v_body, dtype=float))
            res._trim_vf.append(vf)
            res._trim_e.append(np.asarray(s.euler, dtype=float))

    def _finish_trim(self, res: RunResult) -> None:
        if not res._trim_v:
            return
        v = np.mean(res._trim_v, axis=0)
        e = np.degrees(np.mean(res._trim_e, axis=0))
        res.achieved_frame = tuple(float(x) for x in np.mean(res._trim_vf, axis=0))
        ach = {"u0": v[0], "v0": v[1], "w0": v[2], "phi0_deg": e[0], "theta0_deg": e[1]}
        if res._trim_rotor:
            from lpv_sysid.models.quadrotor import QuadrotorParams, mixer

            arm = (
                self._arm_length if self._arm_length is not None else QuadrotorParams().arm_length
            )
            delta = mixer(arm) @ np.mean(res._trim_rotor, axis=0)
            ach.update(dict(zip(("dt0", "da0", "de0", "dr0"), delta)))
        res.achieved = {k: float(x) for k, x in ach.items()}

    def _finish_tracking(self, res: RunResult) -> None:
        if res._n:
            rms = np.sqrt(res._sq / res._n)
            res.tracking_rms = {k: float(x) for k, x in zip(("u", "v", "w", "r"), rms)}

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


def trim_rows(results: Sequence[RunResult]) -> list[dict]:
    """Rows for :func:`lpv_sysid.sim.phase1.write_trim_table` (achieved equilibria of the
    complete runs; seed 0 Table 1 values where the vertex is one of the seed's)."""
    from lpv_sysid.sim.phase1 import SEED0_TABLE1, TRIM_COLUMNS

    rows = []
    for res in results:
        if not res.complete or not res.achieved:
            continue
        ach = {k: float(res.achieved.get(k, math.nan)) for k in TRIM_COLUMNS}
        row = {"run": res.name, "vertex": [float(c) for c in res.vertex], "achieved": ach}
        u, v, w = (int(round(c)) for c in res.vertex)  # a vertex is (u, v, w)
        key = (u, v, w)
        if key in SEED0_TABLE1 and np.allclose(res.vertex, key):
            row["seed0_table1"] = dict(zip(TRIM_COLUMNS, SEED0_TABLE1[key]))
        rows.append(row)
    return rows
