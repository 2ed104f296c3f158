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
#: tilt beyond the trim tilt the velocity loop needs to accelerate onto the multisine [deg]
TILT_MARGIN_DEG = 10.0
#: hover endurance of one battery assumed by ``fly --dry-run`` (``--endurance-min``) [s]
DEFAULT_ENDURANCE_S = 15 * 60.0
#: charge kept in reserve at landing [%]: the battery preflight asks for is use + reserve
BATTERY_RESERVE_PCT = 25.0
#: PX4's MPC_LAND_SPEED default [m/s] (the landing at the end)
LAND_SPEED = 0.7


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

    def demands(self, model=None) -> "FlightDemands":
        """What flying the plan asks of the vehicle (checked by preflight against PX4's
        limits): see :class:`FlightDemands`. ``model``: the quadrotor whose gravity is used
        (default: the package's FlameWheel-450-like model)."""
        from lpv_sysid.models.quadrotor import Quadrotor

        cfg, ex = self.config, self.excitation
        model = model or Quadrotor()
        pu, pv, pw = ex.peak
        horizontal = max(
            math.hypot(abs(r.vertex[0]) + pu, abs(r.vertex[1]) + pv) for r in self.runs
        )
        climb = max([cfg.climb_rate, cfg.hold_max] + [-r.vertex[2] + pw for r in self.runs])
        descent = max([cfg.descent_rate, cfg.hold_max] + [r.vertex[2] + pw for r in self.runs])
        # the tilt that holds the fastest horizontal speed against the drag prior D
        # (campaign.drag_estimate, mass-normalised): tan(tilt) = D v / g
        tilt = math.degrees(math.atan(cfg.drag_estimate * horizontal / model.params.g))
        return FlightDemands(horizontal, climb, descent, tilt + TILT_MARGIN_DEG)

    def budget(self, endurance_s: float = DEFAULT_ENDURANCE_S) -> "FlightBudget":
        """Time, battery and airspace of the whole flight (``fly --dry-run``)."""
        cfg = self.config
        takeoff = cfg.takeoff_altitude / cfg.climb_rate
        landing = cfg.altitude_max / LAND_SPEED
        # after each run the vehicle is back in the next run's start window: at worst the
        # height the run swept, at the slower of climb and descent rate
        reposition = sum(r.altitude_room for r in self.runs) / min(
            cfg.climb_rate, cfg.descent_rate
        )
        nominal = takeoff + sum(r.duration_nominal for r in self.runs) + reposition + landing
        worst = takeoff + sum(r.duration_worst for r in self.runs) + reposition + landing
        radius = max(r.horizontal_extent for r in self.runs)
        return FlightBudget(
            runs=len(self.runs),
            time_nominal_s=nominal,
            time_worst_s=worst,
            battery_nominal_pct=100.0 * nominal / endurance_s,
            battery_worst_pct=100.0 * worst / endurance_s,
            endurance_s=endurance_s,
            radius_m=radius,
            floor_m=cfg.altitude_min,
            ceiling_m=cfg.altitude_max,
        )


@dataclass(frozen=True)
class FlightDemands:
    """What the planned box asks of PX4 (preflight checks each against its parameter):
    horizontal speed (largest ``hypot(|u| + peak_u, |v| + peak_v)`` of the runs:
    MPC_XY_VEL_MAX), climb and descent speed (vertex plus excitation peak, the campaign's
    climb / descent rates: MPC_Z_VEL_MAX_UP / _DN), and tilt (``atan(D v / g)`` at that
    horizontal speed with the drag prior ``campaign.drag_estimate`` D, plus
    :data:`TILT_MARGIN_DEG`: MPC_TILTMAX_AIR) [m/s, deg]."""

    horizontal_speed: float
    climb_speed: float
    descent_speed: float
    tilt_deg: float


@dataclass(frozen=True)
class FlightBudget:
    """The whole flight: time (take-off at climb_rate, every run, repositioning between
    runs over the height each run swept, landing from altitude_max at PX4's 0.7 m/s),
    battery as a share of the hover endurance, and the airspace (a cylinder around home)."""

    runs: int
    time_nominal_s: float
    time_worst_s: float
    battery_nominal_pct: float
    battery_worst_pct: float
    endurance_s: float
    radius_m: float
    floor_m: float
    ceiling_m: float

    @property
    def battery_needed_pct(self) -> float:
        """The charge preflight asks for: worst-case use plus the reserve."""
        return self.battery_worst_pct + BATTERY_RESERVE_PCT

    def describe(self) -> str:
        e = self.endurance_s / 60.0
        lines = [
            f"total time: {self.time_nominal_s / 60:.1f} min expected, "
            f"{self.time_worst_s / 60:.1f} min worst case ({self.runs} runs)",
            f"battery: {self.battery_nominal_pct:.0f} % expected, {self.battery_worst_pct:.0f} % "
            f"worst case of a pack that hovers {e:g} min (--endurance-min); preflight asks "
            f"for {self.battery_needed_pct:.0f} % (worst case + "
            f"{BATTERY_RESERVE_PCT:g} % reserve)",
            f"airspace: a cylinder of radius {self.radius_m:.0f} m around the take-off point, "
            f"{self.floor_m:g} m to {self.ceiling_m:g} m above it (plus the envelope's margins)",
        ]
        if self.battery_needed_pct > 100.0:
            lines.append(
                "NOT ON ONE BATTERY: split the campaign (campaign.vertices: a subset per "
                "flight) or shorten the runs"
            )
        return "\n".join(lines)


#: what the columns of :meth:`CampaignPlan.describe` mean (printed by ``fly --dry-run``)
PLAN_COLUMNS = """\
columns: # = flying order; run = bag name; kind = climb | descent | level (sign of w);
  vertex = commanded body velocity (u, v, w) [m/s, FRD: w > 0 descends];
  start h = heights above home [m] where the run may start so it stays in the window;
  room = height the run sweeps: |w| x T_worst + excitation displacement + 2 margins [m];
  extent = worst horizontal distance from home during the run: speed x T_worst (halved
    when center_runs repositions first) + excitation displacement + margin [m];
  T_worst = settle_timeout + trim_s + excitation [s] (the longest the run can take)."""


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
