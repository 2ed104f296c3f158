"""Equation-error identification of the rate plant (lpv_sysid/models/rate_plant.py) from
phase-1 bags that carry PX4's own thrust/body-rate setpoints (``rate_setpoint`` topic,
``lpv-sysid fly phase1 --record-rate-setpoints``).

Phase 1 flies velocity setpoints through PX4's cascade; PX4's velocity and attitude
controllers turn them into the thrust and body-rate setpoints it streams as ATTITUDE_TARGET.
Those are exactly the inputs the phase-2 law sends, so ordinary phase-1 flights identify the
plant with the rate loop inside (seed 0 App. B equation error, with the known kinematic and
gravity terms moved to the left-hand side):

1. per bag: state (phi, theta, u, v, w, p, q, r) and setpoints (thrust, p_sp, q_sp, r_sp)
   resampled on a uniform grid (``sample_rate``; setpoints zero-order held: they are piecewise
   constant commands), both low-passed by one zero-phase Butterworth filter (``lowpass_hz``)
   and the filtered state differentiated by central differences, so regressors and
   derivatives see the same filter (a Savitzky-Golay smoother and its derivative kernel do
   not commute with the ODE: on simulated data with content up to 3 Hz they biased the rate
   bandwidth by -35 %, test/test_rate_plant.py);
2. one least-squares problem per row over the given runs -- :func:`identify` pools all of
   them; :func:`identify_vertices` (the chain, ``identify --plant px4-rate``) fits each
   corner of the box from the runs flown there (seed 0 Tables 1-2: each vertex its own
   coefficients and standard deviations, so the scheduling dependence of drag, thrust gain
   and loop poles is identified, not assumed) and falls back to the pooled fit, said per
   vertex, where a corner lacks data. The regressors are averaged like the derivative
   (:func:`_simpson`):
   ``u' - (r v - q w - g sin theta) = X_u u + c_u``, likewise v, ``w' - (...) = Z_w w + Z_T
   thrust + c_w``, ``p' = L_p p + L_sp p_sp(t - d) + c_p`` (q, r alike); the rate rows search a
   delay d in ``delays`` (the loop's lag: PX4 filtering, motors) and keep the best fit's
   coefficients (the LPV model has no delay: d is reported, not modelled). With
   ``unit_dc_gain`` (default) the rate rows are ``p' = a (p_sp - p) + c`` (L_sp = -L_p = a);
   only delays with a > 0 count (on one SIH flight the pitch row's best R^2, 0.92, came at
   0.12 s with a = -24.9: half a period of PX4's ~4 Hz pitch-setpoint oscillation, an aliased
   delay, not a loop that runs away from its setpoint):
   PX4's rate integrator leaves no steady error, and the free fit's DC gain of ~1.3-1.4
   on the first SIH flight is the closed-loop regressor bias of equation error (p_sp is
   computed by PX4's attitude loop from the same state), reported as ``unconstrained``;
3. standard deviations from the residual variance (white-residual formula scaled by the
   correlation length of the residuals, ``(1 + 2 sum rho_k)``, so coloured residuals do not
   give overconfident intervals), R^2 per row, and a one-step-free simulation check is left
   to the phase-2 flight.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import BagError, ConfigError, LpvSysidError
from lpv_sysid.models import rate_plant as rp

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RateRun:
    """One bag on the identification grid."""

    name: str
    t: np.ndarray  # (K,)
    x: np.ndarray  # (K, 8) smoothed
    xdot: np.ndarray  # (K, 8)
    u: np.ndarray  # (K, 4) zero-order held, smoothed
    u_raw: np.ndarray  # (K, 4) zero-order held


@dataclass(frozen=True)
class RateIdConfig:
    """Identification of the rate plant PX4 executes (:func:`identify`), declared once."""

    sample_rate: float = cf.number(
        50.0,
        "resampling rate of state and setpoints",
        lo=0.0,
        lo_open=True,
        hi=1000.0,
        unit=" Hz",
    )
    lowpass_hz: float = cf.number(
        5.0,
        "zero-phase Butterworth (order 2, forward-backward) on x and u",
        lo=0.0,
        lo_open=True,
        unit=" Hz",
    )
    delays: tuple = cf.numbers(
        (0.0, 0.02, 0.04, 0.06, 0.08, 0.1, 0.12),
        "candidate setpoint delays",
        lo=0.0,
        hi=1.0,
        unit=" s",
    )
    trim_edges_s: float = cf.number(
        0.5, "dropped at both ends of every run (filter edges)", lo=0.0, hi=60.0, unit=" s"
    )
    unit_dc_gain: bool = cf.flag(
        True, "rate rows p' = a (p_sp - p) + c (PX4's rate I term: no steady error)"
    )
    vertex_tolerance: float = cf.number(
        0.5,
        "a run belongs to the box corner nearest its mean body velocity when every axis is "
        "within this fraction of the box half-width of it (else it only enters the pooled fit)",
        lo=0.0,
        lo_open=True,
        hi=1.0,
    )
    min_vertex_s: float = cf.number(
        10.0,
        "a vertex needs this much data (after trimming) for its own fit; less -> pooled",
        lo=0.0,
        hi=3600.0,
        unit=" s",
    )

    def __post_init__(self) -> None:
        cf.normalize_fields(self, "rate_identification")

    def validate(self) -> None:
        """The declared fields (also checked on construction)."""
        cf.check_fields(self, "rate_identification")


def read_run(path: str | Path, cfg: RateIdConfig = RateIdConfig()) -> RateRun:
    """One phase-1 bag -> :class:`RateRun` (topics ``state`` and ``rate_setpoint``)."""
    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io import messages

    path = Path(path)
    topics = list(iobag.topic_info(str(path)))
    st_t = [t for t in topics if t.endswith("/state")]
    rs_t = [t for t in topics if t.endswith("/rate_setpoint")]
    if not st_t or not rs_t:
        raise BagError(
            f"{path}: needs topics 'state' and 'rate_setpoint' (phase 1 flown with "
            f"record_rate_setpoints: PX4's thrust and body-rate setpoints), has {sorted(topics)}"
        )
    data = iobag.read_bag(str(path), topics=[st_t[0], rs_t[0]])
    states = [messages.state_from_odometry(m) for _, m in data[st_t[0]]]
    sps = [messages.channels_from_joint_state(m, rp.INPUT_NAMES) for _, m in data[rs_t[0]]]
    if len(states) < 20 or len(sps) < 20:
        raise BagError(f"{path}: too few samples (state {len(states)}, rate_setpoint {len(sps)})")
    ts = np.array([s.t for s in states])
    xs = np.array([[s.euler[0], s.euler[1], *s.v_body, *s.omega] for s in states])
    tu = np.array([r[0] for r in sps])
    us = np.array([r[1] for r in sps])
    return run_from_arrays(path.name, ts, xs, tu, us, cfg)


def run_from_arrays(
    name: str,
    ts: np.ndarray,
    xs: np.ndarray,
    tu: np.ndarray,
    us: np.ndarray,
    cfg: RateIdConfig = RateIdConfig(),
) -> RateRun:
    """Samples (state at ``ts``: (K, 8); setpoints at ``tu``: (J, 4)) -> :class:`RateRun` on
    the identification grid (module docstring item 1)."""
    from scipy.signal import butter, sosfiltfilt

    path = name
    ts, xs, tu, us = (np.asarray(a, dtype=float) for a in (ts, xs, tu, us))
    if (
        xs.ndim != 2
        or xs.shape[1] != len(rp.STATE_NAMES)
        or us.ndim != 2
        or us.shape[1] != len(rp.INPUT_NAMES)
    ):
        raise ConfigError(
            f"{name}: states must be (K, 8) and setpoints (J, 4), got {xs.shape}, {us.shape}"
        )
    dt = 1.0 / cfg.sample_rate
    a, b = max(ts[0], tu[0]) + cfg.trim_edges_s, min(ts[-1], tu[-1]) - cfg.trim_edges_s
    if b - a < 3.0:
        raise BagError(f"{path}: state and rate_setpoint overlap only {b - a:.1f} s")
    t = np.arange(a, b, dt)
    x = np.column_stack([np.interp(t, ts, xs[:, k]) for k in range(xs.shape[1])])
    # the setpoint in force at t; 1 us of slack so a setpoint stamped on a grid instant is not
    # lost to the rounding of the two time bases (that delayed the input by a whole sample)
    idx = np.clip(np.searchsorted(tu, t + 1e-6, side="right") - 1, 0, len(tu) - 1)
    u_raw = us[idx]
    sos = butter(2, min(cfg.lowpass_hz, 0.4 * cfg.sample_rate), fs=cfg.sample_rate, output="sos")
    xf = sosfiltfilt(sos, x, axis=0)
    xd = np.gradient(xf, dt, axis=0)  # differentiation commutes with the (same) filter
    uf = sosfiltfilt(sos, u_raw, axis=0)
    return RateRun(str(name), t, xf, xd, uf, u_raw)


def _ls(y: np.ndarray, H: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """theta, std (correlation-corrected), R^2 of y = H theta."""
    theta, *_ = np.linalg.lstsq(H, y, rcond=None)
    e = y - H @ theta
    n, k = H.shape
    s2 = float(e @ e) / max(n - k, 1)
    # residual correlation length (1 + 2 sum rho_k, lags up to the first non-positive rho)
    ec = e - e.mean()
    den = float(ec @ ec)
    corr = 1.0
    if den > 0:
        for lag in range(1, min(200, n // 4)):
            rho = float(ec[lag:] @ ec[:-lag]) / den
            if rho <= 0:
                break
            corr += 2 * rho
    cov = s2 * corr * np.linalg.pinv(H.T @ H)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    sst = float(((y - y.mean()) ** 2).sum())
    r2 = 1.0 - float(e @ e) / sst if sst > 0 else float("nan")
    return theta, std, r2


def _simpson(a: np.ndarray) -> np.ndarray:
    """Mean over [t - dt, t + dt] of a sampled signal (Simpson, kernel (1, 4, 1) / 6; the
    end samples kept): the operator the central difference applies to x', since
    (x(t + dt) - x(t - dt)) / (2 dt) is exactly the mean of x' over that interval. Applied to
    the regressors it removes the derivative's attenuation sin(w dt) / (w dt) (2.4 % at 3 Hz
    and 50 Hz, which biased the rate-loop poles by ~4 %, many standard deviations)."""
    out = np.array(a, dtype=float, copy=True)
    if len(a) >= 3:
        out[1:-1] = (a[:-2] + 4.0 * a[1:-1] + a[2:]) / 6.0
    return out


def _known_terms(x: np.ndarray, g: float) -> np.ndarray:
    """The known (Coriolis, gravity) part of the u, v, w rows (module docstring), (K, 3)."""
    phi, th, ub, vb, wb, p, q, r = x.T
    return np.column_stack(
        [
            r * vb - q * wb - g * np.sin(th),
            p * wb - r * ub + g * np.cos(th) * np.sin(phi),
            q * ub - p * vb + g * np.cos(th) * np.cos(phi),
        ]
    )


def _interval_means(run: RateRun, g: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, u, known terms) of a run averaged like its derivative (:func:`_simpson`)."""
    return _simpson(run.x), _simpson(run.u), _simpson(_known_terms(run.x, g))


def identify(
    runs: Sequence[RateRun], cfg: RateIdConfig = RateIdConfig(), g: float = rp.GRAVITY
) -> tuple[rp.RatePlantParams, dict]:
    """Pooled equation-error fit (module docstring) -> (params, report dict)."""
    cfg.validate()
    if not runs:
        raise ConfigError("rate-plant identification: no runs")
    avg = [_interval_means(rn, g) for rn in runs]
    X = np.vstack([a[0] for a in avg])
    U = np.vstack([a[1] for a in avg])
    KN = np.vstack([a[2] for a in avg])
    Xd = np.vstack([r.xdot for r in runs])
    phi, th, ub, vb, wb, p, q, r = X.T
    one = np.ones(len(X))
    est: dict[str, float] = {}
    std: dict[str, float] = {}
    rows: dict[str, dict] = {}
    rep = {"rows": rows, "samples": int(len(X)), "runs": [r.name for r in runs]}

    def put(names, theta, sd, r2, row, extra=None):
        for k, nm in enumerate(names):
            est[nm], std[nm] = float(theta[k]), float(sd[k])
        rows[row] = {"r2": round(float(r2), 4), **(extra or {})}

    y = Xd[:, 2] - KN[:, 0]
    put(("X_u", "c_u"), *_ls(y, np.column_stack([ub, one])), "u")
    y = Xd[:, 3] - KN[:, 1]
    put(("Y_v", "c_v"), *_ls(y, np.column_stack([vb, one])), "v")
    y = Xd[:, 4] - KN[:, 2]
    put(("Z_w", "Z_T", "c_w"), *_ls(y, np.column_stack([wb, U[:, 0], one])), "w")
    step = 1.0 / cfg.sample_rate
    for row, col, names in (
        (5, 1, ("L_p", "L_sp", "c_p")),
        (6, 2, ("M_q", "M_sp", "c_q")),
        (7, 3, ("N_r", "N_sp", "c_r")),
    ):
        best = None
        for d in cfg.delays:
            k = int(round(d / step))
            ys, Hs = [], []
            for rn, (xa, ua, _) in zip(runs, avg):
                n = len(rn.t)
                if n - k < 10:
                    continue
                ys.append(rn.xdot[k:, row])
                Hs.append(np.column_stack([xa[k:, row], ua[: n - k, col], np.ones(n - k)]))
            y, H = np.concatenate(ys), np.vstack(Hs)
            free = _ls(y, H)
            if cfg.unit_dc_gain:
                # p' = a (p_sp - p) + c: PX4's rate integrator removes steady error (DC gain 1)
                th1, sd1, r21 = _ls(y, np.column_stack([H[:, 1] - H[:, 0], H[:, 2]]))
                theta, sd, r2 = (
                    np.array([-th1[0], th1[0], th1[1]]),
                    np.array([sd1[0], sd1[0], sd1[1]]),
                    r21,
                )
            else:
                theta, sd, r2 = free
            if theta[1] <= 0:
                continue  # the loop must follow its setpoint: a sign flip is an aliased delay
            if best is None or r2 > best[2] + 1e-9:
                best = (theta, sd, r2, k * step, free)
        if best is None:
            raise ConfigError(
                f"rate-plant identification: row {rp.STATE_NAMES[row]}: no delay in "
                f"{list(cfg.delays)} "
                "gives a positive setpoint gain (is the setpoint stream the right one?)"
            )
        theta, sd, r2, d, free = best
        put(
            names,
            theta,
            sd,
            r2,
            rp.STATE_NAMES[row],
            {
                "delay_s": round(d, 3),
                "bandwidth_rad_s": round(-float(theta[0]), 3),
                "unit_dc_gain": bool(cfg.unit_dc_gain),
                "unconstrained": {
                    "r2": round(float(free[2]), 4),
                    "L": round(float(free[0][0]), 4),
                    "L_sp": round(float(free[0][1]), 4),
                    "dc_gain": round(float(-free[0][1] / free[0][0]), 3)
                    if free[0][0] != 0
                    else None,
                },
            },
        )
    params = rp.RatePlantParams(**est, std=std)
    rep["params"] = params.as_dict()
    return params, rep


@dataclass(frozen=True)
class VertexFit:
    """The rate plant at one corner of the scheduling box (per-vertex identification)."""

    index: int  # position in ``models.lpv.box_vertices`` order (0-based)
    vertex: tuple  # the corner (u, v, w) [m/s]
    params: rp.RatePlantParams
    source: str  # "vertex" (own runs) | "pooled" (all runs: this vertex lacks data)
    runs: tuple  # names of the runs at this corner
    samples: int  # samples of this corner's runs
    reason: str  # why pooled ("" for an own fit)
    rows: dict  # per row: R^2 (own fit) or the pooled fit's


def level_velocity(x: np.ndarray) -> np.ndarray:
    """FRD body velocity of states ``x`` (K, 8) in the heading (yaw-only) frame:
    R_y(theta) R_x(phi) v_body (ZYX Euler angles with psi = 0), (K, 3)."""
    phi, th, ub, vb, wb = x[:, 0], x[:, 1], x[:, 2], x[:, 3], x[:, 4]
    sf, cf, st, ct = np.sin(phi), np.cos(phi), np.sin(th), np.cos(th)
    v1 = cf * vb - sf * wb  # R_x(phi)
    w1 = sf * vb + cf * wb
    return np.column_stack([ct * ub + st * w1, v1, -st * ub + ct * w1])


def assign_vertex(
    run: RateRun, box_min, box_max, tolerance: float = RateIdConfig().vertex_tolerance
) -> int | None:
    """Index (``box_vertices`` order) of the box corner the run was flown at: the corner
    nearest the run's mean velocity in the frame the campaign commands it (``body_ned``: the
    heading frame, body velocity rotated by roll and pitch; at 5 m/s the FRD body w of a
    level vertex is ~2 m/s off it at the ~25 deg trim pitch of PX4 SIH), if every axis lies
    within ``tolerance`` x the half-width of it (the multisine has zero mean); None (hover,
    a transit) otherwise."""
    from lpv_sysid.models.lpv import box_vertices

    corners = box_vertices(box_min, box_max)
    half = 0.5 * (np.asarray(box_max, float) - np.asarray(box_min, float))
    mean = level_velocity(run.x).mean(axis=0)
    dev = np.abs(corners - mean) / half
    k = int(np.argmin(dev.max(axis=1)))
    return k if float(dev[k].max()) <= tolerance else None


def identify_vertices(
    runs: Sequence[RateRun],
    box_min,
    box_max,
    cfg: RateIdConfig = RateIdConfig(),
    g: float = rp.GRAVITY,
) -> tuple[list[VertexFit], rp.RatePlantParams, dict]:
    """Per-vertex identification (seed 0 Tables 1-2 for the rate plant): the runs flown at
    each corner of the box (:func:`assign_vertex`) give that corner its own equation-error
    fit (:func:`identify`) with its own standard deviations, so the scheduling dependence of
    drag, thrust gain and rate-loop poles is identified, not assumed. A corner with less than
    ``min_vertex_s`` of data, or whose own fit fails, takes the pooled fit of all runs, and
    its :class:`VertexFit` says so (``source`` "pooled", ``reason``). Returns (fits in corner
    order, pooled params, report: the pooled report plus ``vertices`` and ``scheduling``,
    the spread of each coefficient over the corners with own fits in pooled standard
    deviations)."""
    from lpv_sysid.models.lpv import box_vertices

    cfg.validate()
    corners = box_vertices(box_min, box_max)
    pooled, rep = identify(runs, cfg, g)
    groups: dict[int, list[RateRun]] = {}
    unassigned = []
    for r in runs:
        k = assign_vertex(r, box_min, box_max, cfg.vertex_tolerance)
        if k is None:
            unassigned.append(r.name)
        else:
            groups.setdefault(k, []).append(r)
    fits: list[VertexFit] = []
    need = int(round(cfg.min_vertex_s * cfg.sample_rate))
    for k, corner in enumerate(corners):
        mine = groups.get(k, [])
        n = int(sum(len(r.t) for r in mine))
        vtx = tuple(float(c) for c in corner)
        names = tuple(r.name for r in mine)
        reason = ""
        if not mine:
            reason = "no run at this vertex"
        elif n < need:
            reason = f"only {n / cfg.sample_rate:.1f} s of data (< {cfg.min_vertex_s:g} s)"
        else:
            try:
                P, r_rep = identify(mine, cfg, g)
            except LpvSysidError as exc:
                reason = f"own fit failed: {exc}"
            else:
                fits.append(VertexFit(k, vtx, P, "vertex", names, n, "", r_rep["rows"]))
                continue
        log.info("rate plant vertex %d %s: pooled (%s)", k + 1, list(vtx), reason)
        fits.append(VertexFit(k, vtx, pooled, "pooled", names, n, reason, rep["rows"]))
    rep["vertices"] = [
        {
            "index": f.index + 1,
            "vertex": list(f.vertex),
            "source": f.source,
            "reason": f.reason,
            "runs": list(f.runs),
            "samples": f.samples,
            "r2": {row: d["r2"] for row, d in f.rows.items()},
            "params": f.params.as_dict(),
        }
        for f in fits
    ]
    rep["unassigned_runs"] = unassigned
    rep["scheduling"] = scheduling_spread(fits, pooled)
    return fits, pooled, rep


#: the identified coefficients whose dependence on the vertex is reported
SCHEDULED = ("X_u", "Y_v", "Z_w", "Z_T", "L_p", "M_q", "N_r")


def scheduling_spread(fits: Sequence[VertexFit], pooled: rp.RatePlantParams) -> dict:
    """Per coefficient over the corners with their own fit: min, max and the largest
    difference between two corners in units of their combined standard deviation (> 3: the
    coefficient depends on the vertex beyond its uncertainty)."""
    own = [f for f in fits if f.source == "vertex"]
    out: dict = {"vertices_with_own_fit": len(own), "vertices_pooled": len(fits) - len(own)}
    for name in SCHEDULED:
        vals = [(float(getattr(f.params, name)), float(f.params.std.get(name, 0.0))) for f in own]
        if len(vals) < 2:
            out[name] = {"pooled": float(getattr(pooled, name))}
            continue
        z = 0.0
        for i in range(len(vals)):
            for j in range(i + 1, len(vals)):
                s = math.hypot(vals[i][1], vals[j][1])
                if s > 0:
                    z = max(z, abs(vals[i][0] - vals[j][0]) / s)
        out[name] = {
            "min": min(v for v, _ in vals),
            "max": max(v for v, _ in vals),
            "max_difference_sigmas": round(z, 2),
            "pooled": float(getattr(pooled, name)),
        }
    return out


def validate(params: rp.RatePlantParams, run: RateRun, g: float = rp.GRAVITY) -> dict:
    """Equation-error check of identified ``params`` on another run (e.g. the phase-2 flight,
    where the rate setpoints are the LPV law's and not PX4's): per row the R^2 of the model's
    x' (:func:`lpv_sysid.models.rate_plant.dynamics`) against the measured derivative."""
    pred = np.array([rp.dynamics(x, u, params, g) for x, u in zip(run.x, run.u)])
    out = {}
    for k, name in enumerate(rp.STATE_NAMES):
        y = run.xdot[:, k]
        sst = float(((y - y.mean()) ** 2).sum())
        e = y - pred[:, k]
        out[name] = round(1.0 - float(e @ e) / sst, 4) if sst > 0 else None
    return out


#: output error (:func:`output_error`): the rows simulated, their state index and the
#: coefficient of the row's own state (the loop pole or drag)
OUTPUT_ERROR_ROWS = (
    ("u", 2, "X_u"),
    ("v", 3, "Y_v"),
    ("w", 4, "Z_w"),
    ("p", 5, "L_p"),
    ("q", 6, "M_q"),
    ("r", 7, "N_r"),
)
#: window of :func:`output_error` [s]: each row restarts from the measured state this often
OUTPUT_ERROR_WINDOW_S = 10.0


def output_error(
    params: rp.RatePlantParams,
    run: RateRun,
    window_s: float = OUTPUT_ERROR_WINDOW_S,
    g: float = rp.GRAVITY,
) -> dict:
    """Output-error check of ``params`` on a run (the phase-2 flight: the law's setpoints as
    PX4 echoed them): each row of the module docstring's model -- u, v, w (drag, thrust,
    Coriolis and gravity with the measured attitude and rates) and p, q, r (the rate loops) --
    is *simulated* from the recorded setpoints (zero-order held, ``run.u_raw``), the other
    states taken as measured, restarting from the measured value every ``window_s`` seconds
    (an open-loop velocity integrates any bias without bound); per row R^2 of the simulated
    against the measured state over the whole run. Unlike :func:`validate` (one-step
    derivatives) a wrong pole or gain accumulates here. Exact discretisation of the row's own
    linear term over each grid step (inputs held)."""
    if not (math.isfinite(window_s) and window_s > 0):
        raise ConfigError(f"output error: window_s must be > 0, got {window_s!r}")
    t, x, u = run.t, run.x, run.u_raw
    if len(t) < 3:
        raise ConfigError(f"{run.name}: too few samples for the output error")
    dt = float(t[1] - t[0])
    # the forcing of every row = x' minus the row's own linear term, from measured states
    forcing = np.array([rp.dynamics(xi, ui, params, g) for xi, ui in zip(x, u)])
    restart = np.floor((t - t[0]) / window_s).astype(int)
    out: dict = {"window_s": float(window_s), "samples": int(len(t))}
    for name, k, coef in OUTPUT_ERROR_ROWS:
        a = float(getattr(params, coef))
        b = forcing[:, k] - a * x[:, k]
        ea = math.exp(a * dt)
        gain = (ea - 1.0) / a if abs(a) > 1e-12 else dt
        y = np.empty(len(t))
        y[0] = x[0, k]
        for n in range(len(t) - 1):
            if restart[n + 1] != restart[n]:
                y[n + 1] = x[n + 1, k]
            else:
                y[n + 1] = ea * y[n] + gain * b[n]
        m = x[:, k]
        sst = float(((m - m.mean()) ** 2).sum())
        e = m - y
        out[name] = round(1.0 - float(e @ e) / sst, 4) if sst > 0 else None
    return out


def identify_bags(
    bags: Sequence[str | Path], cfg: RateIdConfig = RateIdConfig()
) -> tuple[rp.RatePlantParams, dict]:
    runs = [read_run(b, cfg) for b in bags]
    params, rep = identify(runs, cfg)
    rep["bags"] = [str(b) for b in bags]
    return params, rep


def models_document(
    params: rp.RatePlantParams | Sequence[rp.RatePlantParams],
    vmin,
    vmax,
    k_sigma: float,
    report: dict,
) -> dict:
    """vertex_models.yaml (MODELS_FORMAT, generic layout) of the rate plant, with the
    identification report under ``identification`` (design = rate_plant); ``params``: one
    set for all corners or one per corner (:func:`identify_vertices`)."""
    from lpv_sysid.io.formats import models_dict

    per_vertex = not isinstance(params, rp.RatePlantParams)
    model, els = rp.polytope(params, vmin, vmax, k_sigma)
    d = models_dict(model, els if k_sigma > 0 else None, rp.STATE_UNITS, rp.INPUT_UNITS)
    d["meta"] = {
        "design": rp.DESIGN,
        "design_text": rp.DESIGN_TEXT,
        "identification": {
            "method": (
                "per-vertex equation error (pooled where a vertex lacks data: "
                "vertices[].source), PX4 rate loop inside (lpv_sysid/ident/rate_plant.py)"
                if per_vertex
                else "pooled equation error, PX4 rate loop inside (lpv_sysid/ident/rate_plant.py)"
            ),
            "k_sigma": float(k_sigma),
            **_plain(report),
        },
    }
    return d


def _plain(x):
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
