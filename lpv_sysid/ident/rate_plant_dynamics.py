"""Output-error identification of the rate plant's *lag* dynamics (issue 21 item 3): the
rate loops and the heave row with the motor lag and delay that PX4 + the vehicle have,
which the first-order equation-error model of :mod:`lpv_sysid.ident.rate_plant` omits.

Model (per rate axis, p shown; q, r alike; ``d`` a pure delay, ``tau`` the motor/thrust
lag, e.g. PX4 SIH's ``SIH_T_TAU``; the seed 0 rotor model Eq. (8) has ``tau = 1/a_Omega``)::

    p'  = m                                           (m: achieved angular acceleration)
    m'  = (K_sp p_sp(t - d) - K_p p + c - m) / tau    i.e. tau p'' + p' = K_sp p_sp - K_p p + c

Heave, thrust through the same lag (``T_a`` the achieved thrust, ``F_w = q u - p v + g cos
theta cos phi`` the measured Coriolis and gravity terms of models/rate_plant.py)::

    w'   = F_w + Z_w w + Z_T T_a + c_w
    T_a' = (thrust(t - d) - T_a) / tau_T

Surge and sway (no setpoint of their own: driven by the measured attitude, rates and the
other velocities, ``F_u = r v - q w - g sin theta``, ``F_v = p w - r u + g sin phi cos
theta``; drag and the attitude estimate's offset identified, not assumed)::

    u' = F_u + X_u u + c_u        v' = F_v + Y_v v + c_v

The gains are free (no unit DC gain): on data where the setpoints are excited independently
of the state (broken-loop excitation: the multisine superposed on the body-rate and thrust
setpoints of a stabilised run) equation-error regressor bias does not arise, and Z_w is not
confounded with Z_T because thrust no longer follows w. Each row is *simulated* from its
setpoint (the other states as measured) over windows of ``window_s`` seconds, each window
started at the measured state (and at the measured x' for the acceleration state, the
recorded thrust for T_a); the parameters minimise the summed squared output error
(``scipy.optimize.least_squares``, bounded ``tau``), for each candidate delay in ``delays``;
the best delay is kept. Standard deviations from the Jacobian at the optimum, scaled by the
residuals' correlation length ``(1 + 2 sum rho_k)`` like the equation-error fit. Discretisation
is exact for inputs held over each grid step (augmented matrix exponential).

:func:`output_error` scores identified lag dynamics on another run (the phase-2 flight) with
the same windows; R^2 per row of the simulated against the measured state. The offsets
``c_u``, ``c_v`` carry what the estimator's attitude is off from the vehicle's (on PX4 SIH
1-2 deg of roll/pitch against SIH's ground truth, 0.2-0.3 m/s^2 through gravity, measured
2026-12-03): identified with the rest on the same flight, they predict the next windows; an
equation-error fit on other flights does not know them. The controller's
design states stay (phi, theta, u, v, w, p, q, r): the lag and delay identified here are for
the prediction model (output-error validation) and the certificate's delay/uncertainty
(``equivalent_delay_s = d + tau`` per row, the low-frequency phase of lag + delay).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError
from lpv_sysid.models import rate_plant as rp

#: rows of the lag model: name, state index, setpoint column, parameter names
RATE_ROWS = (("p", 5, 1), ("q", 6, 2), ("r", 7, 3))
HEAVE_ROW = ("w", 4, 0)
#: surge and sway: name, state index, no setpoint (-1)
VELOCITY_ROWS = (("u", 2, -1), ("v", 3, -1))
RATE_PARAMS = ("K_sp", "K_p", "c", "tau")
HEAVE_PARAMS = ("Z_w", "Z_T", "c_w", "tau")
VELOCITY_PARAMS = {"u": ("X_u", "c_u"), "v": ("Y_v", "c_v")}
#: every row, in the state's order of the velocity and rate rows
ROWS = (*VELOCITY_ROWS, HEAVE_ROW, *RATE_ROWS)


def row_params(name: str) -> tuple:
    """Parameter names of a row of the lag model."""
    return VELOCITY_PARAMS.get(name) or (HEAVE_PARAMS if name == "w" else RATE_PARAMS)


@dataclass(frozen=True)
class LagIdConfig:
    """Output-error identification of the lag dynamics (:func:`identify`), declared once."""

    window_s: float = cf.number(
        4.0,
        "output-error window: each row restarts from the measured state this often",
        lo=0.2,
        hi=600.0,
        unit=" s",
    )
    delays: tuple = cf.numbers(
        (0.0, 0.02, 0.04, 0.06),
        "candidate setpoint delays (pure delay on top of the lag)",
        lo=0.0,
        hi=1.0,
        unit=" s",
    )
    tau_min: float = cf.number(
        0.005, "smallest lag time constant searched", lo=0.0, lo_open=True, unit=" s"
    )
    tau_max: float = cf.number(1.0, "largest lag time constant searched", lo=0.0, unit=" s")
    heave_tau_from_rates: bool = cf.flag(
        False,
        "heave row: thrust lag = mean roll/pitch loop lag (one motor time constant, e.g. "
        "SIH_T_TAU), not fitted (false: fitted from the heave row alone)",
    )
    tau_starts: tuple = cf.numbers(
        (0.03, 0.1, 0.3), "initial lag time constants (one fit from each)", lo=0.0, unit=" s"
    )

    def __post_init__(self) -> None:
        cf.normalize_fields(self, "lag_identification")
        if not self.tau_min < self.tau_max:
            raise ConfigError(
                f"lag_identification: tau_min {self.tau_min} must be < tau_max {self.tau_max}"
            )


def _rate_matrices(th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the rate row, state (p, m), inputs (p_sp, 1)."""
    k_sp, k_p, c, tau = th
    A = np.array([[0.0, 1.0], [-k_p / tau, -1.0 / tau]])
    B = np.array([[0.0, 0.0], [k_sp / tau, c / tau]])
    return A, B


def _heave_matrices(th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the heave row, state (w, T_a), inputs (thrust, F_w + c_w as two columns)."""
    z_w, z_t, c_w, tau = th
    A = np.array([[z_w, z_t], [0.0, -1.0 / tau]])
    B = np.array([[0.0, 1.0, c_w], [1.0 / tau, 0.0, 0.0]])
    return A, B


def _velocity_matrices(th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of a surge/sway row, state (u), inputs (F_u, 1)."""
    x_u, c_u = th
    return np.array([[x_u]]), np.array([[1.0, c_u]])


def _matrices(name: str, th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if name in VELOCITY_PARAMS:
        return _velocity_matrices(th)
    return (_heave_matrices if name == "w" else _rate_matrices)(th)


def _discretise(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    from scipy.linalg import expm

    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = expm(M * dt)
    return E[:n, :n], E[:n, n:]


def _windows(n: int, L: int) -> list[tuple[int, int]]:
    return [(a, min(a + L, n)) for a in range(0, n, L) if min(a + L, n) - a >= 3]


def _simulate(
    Ad: np.ndarray, Bd: np.ndarray, x0: np.ndarray, v: np.ndarray, wins: list[tuple[int, int]]
) -> np.ndarray:
    """First state of the discrete system, all windows at once (batch over windows):
    x0 (W, n) at each window start, v (N, m) inputs; returns (N,) with NaN outside."""
    N = len(v)
    out = np.full(N, np.nan)
    L = max(b - a for a, b in wins)
    W = len(wins)
    V = np.zeros((W, L, v.shape[1]))
    for i, (a, b) in enumerate(wins):
        V[i, : b - a] = v[a:b]
    X = x0.copy()
    Y = np.empty((W, L))
    for k in range(L):
        Y[:, k] = X[:, 0]
        X = X @ Ad.T + V[:, k] @ Bd.T
    for i, (a, b) in enumerate(wins):
        out[a:b] = Y[i, : b - a]
    return out


def _shift(u: np.ndarray, k: int) -> np.ndarray:
    """u(t - k dt), the first value held before the record."""
    return u if k == 0 else np.concatenate([np.repeat(u[:1], k, axis=0), u[:-k]])


@dataclass(frozen=True)
class _RowData:
    name: str
    dt: float
    y: np.ndarray  # measured output (N,)
    x0: np.ndarray  # (W, 2) window initial states
    v: np.ndarray  # (N, m) inputs (setpoint first, delayed per candidate)
    wins: list


def _row_data(run, row: tuple[str, int, int], k_delay: int, L: int, g: float) -> _RowData:
    name, ix, iu = row
    t, x, xd = run.t, run.x, run.xdot
    dt = float(t[1] - t[0])
    wins = _windows(len(t), L)
    starts = np.array([a for a, _ in wins])
    if name in VELOCITY_PARAMS:
        phi, th, ub, vb, wb, p, q, r = x.T
        if name == "u":
            f = r * vb - q * wb - g * np.sin(th)
        else:
            f = p * wb - r * ub + g * np.sin(phi) * np.cos(th)
        v = np.column_stack([f, np.ones(len(t))])
        v = 0.5 * (v + np.vstack([v[1:], v[-1:]]))  # smooth forcing: the step's mean
        return _RowData(name, dt, x[:, ix], x[starts, ix][:, None], v, wins)
    sp = _shift(run.u_raw[:, iu], k_delay)  # as sent: held between samples
    if name == "w":
        phi, th, ub, vb, _, p, q, _r = x.T
        f_w = q * ub - p * vb + g * np.cos(th) * np.cos(phi)
        v = np.column_stack([sp, f_w, np.ones(len(t))])
        x0 = np.column_stack([x[starts, ix], sp[starts]])
    else:
        v = np.column_stack([sp, np.ones(len(t))])
        x0 = np.column_stack([x[starts, ix], xd[starts, ix]])
    # the measured forcing is smooth, not held: the step's mean (trapezoid) is what the
    # held-input discretisation needs (holding v[n] would lag it by dt / 2)
    v[:, 1:] = 0.5 * (v[:, 1:] + np.vstack([v[1:, 1:], v[-1:, 1:]]))
    return _RowData(name, dt, x[:, ix], x0, v, wins)


def _residual(th: np.ndarray, rd: _RowData) -> np.ndarray:
    A, B = _matrices(rd.name, th)
    Ad, Bd = _discretise(A, B, rd.dt)
    ys = _simulate(Ad, Bd, rd.x0, rd.v, rd.wins)
    e = ys - rd.y
    return e[np.isfinite(e)]


def _measured(rd: _RowData) -> np.ndarray:
    """The measured output where :func:`_residual` has samples (inside the windows)."""
    mask = np.zeros(len(rd.y), bool)
    for a, b in rd.wins:
        mask[a:b] = True
    return rd.y[mask]


def _corr_factor(e: np.ndarray) -> float:
    ec = e - e.mean()
    den = float(ec @ ec)
    corr = 1.0
    if den > 0:
        for lag in range(1, min(200, len(e) // 4)):
            rho = float(ec[lag:] @ ec[:-lag]) / den
            if rho <= 0:
                break
            corr += 2 * rho
    return corr


def _r2(y: np.ndarray, e: np.ndarray) -> float:
    sst = float(((y - y.mean()) ** 2).sum())
    return 1.0 - float(e @ e) / sst if sst > 0 else float("nan")


def _fit_row(
    runs, row, cfg: LagIdConfig, g: float, guess: np.ndarray, fixed_tau: float | None = None
) -> dict:
    """Output-error fit of one row; with ``fixed_tau`` the lag is not fitted (the heave row
    takes the rate loops' motor lag: one motor time constant)."""
    from scipy.optimize import least_squares

    dt = float(runs[0].t[1] - runs[0].t[0])
    L = max(int(round(cfg.window_s / dt)), 3)
    tau_i = 3
    npar = len(guess)
    lo = np.full(npar, -np.inf)
    hi = np.full(npar, np.inf)
    lo[tau_i], hi[tau_i] = cfg.tau_min, cfg.tau_max
    if row[0] != "w":
        lo[0] = 0.0  # the loop follows its setpoint
    else:
        hi[1] = 0.0  # thrust accelerates up (-w)
    x0 = np.clip(guess, lo + 1e-9, hi - 1e-9)
    nfree = npar if fixed_tau is None else tau_i
    starts = cfg.tau_starts if fixed_tau is None else (fixed_tau,)

    def full(th):
        return th if fixed_tau is None else np.r_[th, fixed_tau]

    best = None
    for d in cfg.delays:
        k = int(round(d / dt))
        rds = [_row_data(r, row, k, L, g) for r in runs]

        def res(th, rds=rds):
            return np.concatenate([_residual(full(th), rd) for rd in rds])

        for tau0 in starts:  # the lag's cost has local minima: several starts
            start = x0.copy()
            start[tau_i] = min(max(tau0, cfg.tau_min * 1.01), cfg.tau_max * 0.99)
            sol = least_squares(
                res,
                start[:nfree],
                bounds=(lo[:nfree], hi[:nfree]),
                x_scale="jac",
                max_nfev=400,
            )
            cost = float(sol.fun @ sol.fun)
            if best is None or cost < best[0]:
                best = (cost, sol, k * dt, rds)
    assert best is not None
    _, sol, d, rds = best
    est = full(sol.x)
    return {
        **_fit_result(row[0], sol, est, npar - nfree, rds, d),
        "equivalent_delay_s": round(d + float(est[tau_i]), 4),
        "tau_fitted": fixed_tau is None,
    }


def _fit_result(name: str, sol, est: np.ndarray, n_fixed: int, rds: list, delay: float) -> dict:
    """A row's fit record: parameters, standard deviations from the Jacobian (white-residual
    formula scaled by the residuals' correlation length; 0 for the ``n_fixed`` trailing
    parameters not fitted), the delay, R^2 and the sample count."""
    e = sol.fun
    n = len(e)
    nfree = len(sol.x)
    cov = float(e @ e) / max(n - nfree, 1) * _corr_factor(e) * np.linalg.pinv(sol.jac.T @ sol.jac)
    std = np.r_[np.sqrt(np.maximum(np.diag(cov), 0.0)), np.zeros(n_fixed)]
    y = np.concatenate([_measured(rd) for rd in rds])
    names = row_params(name)
    return {
        "params": {nm: float(v) for nm, v in zip(names, est)},
        "std": {nm: float(v) for nm, v in zip(names, std)},
        "delay_s": round(delay, 4),
        "r2": round(_r2(y, e), 4),
        "samples": int(n),
    }


def _fit_velocity_row(runs, row, cfg: LagIdConfig, g: float) -> dict:
    """Output-error fit of a surge/sway row (drag and offset: linear in the output, one
    start suffices; drag bounded to damp, ``X_u <= 0``)."""
    from scipy.optimize import least_squares

    dt = float(runs[0].t[1] - runs[0].t[0])
    L = max(int(round(cfg.window_s / dt)), 3)
    rds = [_row_data(r, row, 0, L, g) for r in runs]

    def res(th):
        return np.concatenate([_residual(th, rd) for rd in rds])

    sol = least_squares(res, np.array([-0.3, 0.0]), bounds=([-50.0, -20.0], [0.0, 20.0]))
    return _fit_result(row[0], sol, sol.x, 0, rds, 0.0)


@dataclass(frozen=True)
class LagPlant:
    """Identified lag dynamics: ``rows[name]`` as returned per row (``params``, ``std``,
    ``delay_s``, ``r2``; ``equivalent_delay_s`` for the rows with a setpoint) for u, v, w,
    p, q and r."""

    rows: dict
    window_s: float

    def as_dict(self) -> dict:
        return {"window_s": float(self.window_s), "rows": self.rows}


def identify(
    runs: Sequence,
    cfg: LagIdConfig = LagIdConfig(),
    start: rp.RatePlantParams | None = None,
    g: float = rp.GRAVITY,
) -> LagPlant:
    """Output-error fit of the lag model (module docstring) on :class:`~lpv_sysid.ident.
    rate_plant.RateRun` runs (same grid), per row; ``start``: first-order equation-error
    params used as the initial guess (rate pole and gain, drag, thrust gain)."""
    if not runs:
        raise ConfigError("lag identification: no runs")
    # the grid step of each run (epoch-stamped grids: float spacing differs by ~1e-9 s)
    dts = sorted(float(np.median(np.diff(r.t))) for r in runs)
    if dts[-1] - dts[0] > 1e-6 * dts[0]:
        raise ConfigError(f"lag identification: runs on different grids {dts}")
    rows: dict = {}
    for name, ix, iu in RATE_ROWS:
        if start is not None:
            pole = -float(getattr(start, {"p": "L_p", "q": "M_q", "r": "N_r"}[name]))
            gain = float(getattr(start, {"p": "L_sp", "q": "M_sp", "r": "N_sp"}[name]))
            guess = np.array([max(gain, 1.0), max(pole, 1.0), 0.0, 0.05])
        else:
            guess = np.array([10.0, 10.0, 0.0, 0.05])
        rows[name] = _fit_row(runs, (name, ix, iu), cfg, g, guess)
    if start is not None:
        guess = np.array([start.Z_w, start.Z_T, start.c_w, 0.05])
    else:
        guess = np.array([-0.3, -20.0, 0.0, 0.05])
    fixed = None
    if cfg.heave_tau_from_rates:
        fixed = float(np.mean([rows[k]["params"]["tau"] for k in ("p", "q")]))
    rows["w"] = _fit_row(runs, HEAVE_ROW, cfg, g, guess, fixed_tau=fixed)
    for row in VELOCITY_ROWS:
        rows[row[0]] = _fit_velocity_row(runs, row, cfg, g)
    return LagPlant(rows=rows, window_s=float(cfg.window_s))


def output_error(plant: LagPlant, run, window_s: float | None = None, g: float = rp.GRAVITY):
    """R^2 per row (u, v, w, p, q, r) of the lag model simulated from the run's setpoints
    (and, for u and v, its measured attitude, rates and other velocities) against the
    measured state, windows of ``window_s`` (default: the identification's). A plant
    identified before the surge/sway rows existed is scored on the rows it has."""
    w = float(plant.window_s if window_s is None else window_s)
    if not (math.isfinite(w) and w > 0):
        raise ConfigError(f"lag output error: window_s must be > 0, got {window_s!r}")
    dt = float(run.t[1] - run.t[0])
    L = max(int(round(w / dt)), 3)
    out: dict = {"window_s": w}
    for row in ROWS:
        r = plant.rows.get(row[0])
        if r is None:
            continue
        th = np.array([r["params"][k] for k in row_params(row[0])])
        rd = _row_data(run, row, int(round(r["delay_s"] / dt)), L, g)
        out[row[0]] = round(_r2(_measured(rd), _residual(th, rd)), 4)
    return out
