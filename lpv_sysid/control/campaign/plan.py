"""The plan of the phase-1 campaign: the runs in flying order, each checked before take-off
against the altitude window, the campaign radius and the bridge's safety envelope
(:func:`plan_campaign`; the rules are in :mod:`lpv_sysid.control.campaign`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lpv_sysid.control.campaign.config import CampaignConfig
from lpv_sysid.errors import ConfigError

if TYPE_CHECKING:
    from lpv_sysid.signals.excitation import ExcitationCore

CLIMB, DESCENT, LEVEL = "climb", "descent", "level"
_NOMINAL_ACCEL = 2.0  # m/s^2, for the expected settle transient of the horizontal plan


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
    name: str  # bag / run name (:func:`run_name`, hover_validation)
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


#: margin on the speeds the box needs before PX4's limits (MPC_*_VEL_MAX) clip them
PX4_LIMIT_MARGIN = 1.1


@dataclass(frozen=True)
class Px4Need:
    """A PX4 parameter the campaign needs at least at ``needed`` (preflight NO-GO below)."""

    param: str
    needed: float
    unit: str
    why: str


def px4_needs(plan: "CampaignPlan") -> list[Px4Need]:
    """The PX4 v1.16 limits the campaign's velocity commands must stay under (PX4's position
    controller clips offboard velocity setpoints to them, so a box beyond them is flown
    smaller than planned, silently): the largest horizontal speed (|u| + excitation peak,
    |v| + peak) -> MPC_XY_VEL_MAX, climb (-w + peak) -> MPC_Z_VEL_MAX_UP, descent (w + peak)
    -> MPC_Z_VEL_MAX_DN, each x :data:`PX4_LIMIT_MARGIN`; the tilt that holds the fastest
    horizontal run against drag (``drag_estimate`` x speed) -> MPC_TILTMAX_AIR [deg], with
    the same margin."""
    cfg, ex = plan.config, plan.excitation
    runs = plan.runs
    xy = max(
        math.hypot(abs(r.vertex[0]) + ex.peak[0], abs(r.vertex[1]) + ex.peak[1]) for r in runs
    )
    up = max([cfg.climb_rate] + [-r.vertex[2] + ex.peak[2] for r in runs])
    dn = max([cfg.descent_rate] + [r.vertex[2] + ex.peak[2] for r in runs])
    tilt = math.degrees(math.atan(cfg.drag_estimate * xy / 9.80665))
    k = PX4_LIMIT_MARGIN
    return [
        Px4Need("MPC_XY_VEL_MAX", round(k * xy, 2), "m/s", f"horizontal speed {xy:.2f} m/s"),
        Px4Need("MPC_Z_VEL_MAX_UP", round(k * up, 2), "m/s", f"climb {up:.2f} m/s"),
        Px4Need("MPC_Z_VEL_MAX_DN", round(k * dn, 2), "m/s", f"descent {dn:.2f} m/s"),
        Px4Need(
            "MPC_TILTMAX_AIR",
            round(min(k * tilt, 89.0), 1),
            "deg",
            f"tilt {tilt:.1f} deg against drag {cfg.drag_estimate:g} 1/s x {xy:.2f} m/s",
        ),
    ]


def airspace(plan: "CampaignPlan") -> dict:
    """The airspace the campaign needs: the altitude window (heights above home), the
    largest horizontal distance from home of any run and the height each run climbs or
    descends through."""
    cfg = plan.config
    return {
        "altitude_window_m": [cfg.altitude_min, cfg.altitude_max],
        "radius_m": round(max(r.horizontal_extent for r in plan.runs), 1),
        "radius_limit_m": cfg.radius,
        "largest_altitude_room_m": round(max(r.altitude_room for r in plan.runs), 1),
    }


def run_name(vertex) -> str:
    """The name of the phase-1 run at a vertex (its bag directory): ``vertex_p5_m5_0``."""
    return "vertex_" + "_".join(
        f"{'p' if c > 0 else ('m' if c < 0 else '0')}{abs(c):g}" for c in vertex
    )


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
