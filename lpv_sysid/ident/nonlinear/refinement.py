"""Step 2 of :mod:`lpv_sysid.ident.nonlinear` (method: that module's docstring): output-error
refinement of the Eq. (6) parameters over short segments (seed 2 Sec. 4)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.ident.nonlinear.data import (
    AXES,
    REGRESSORS,
    FlightData,
    NonlinearResult,
    _check,
    gravity_body,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OutputErrorConfig:
    """Output-error refinement of the regression estimate (seed 2 Sec. 4.3)."""

    segment_s: float = cf.number(
        2.0, "length of one simulated segment", lo=0.0, lo_open=True, hi=600.0, unit=" s"
    )
    max_segments: int = cf.count(40, "segments simulated (evenly picked)", lo=1, hi=100_000)
    max_nfev: int = cf.count(60, "function evaluations of the least-squares search", lo=1)
    free: tuple[str, ...] | None = cf.texts(
        None, "K names to refine (null: all regression ones)", optional=True
    )
    bounds_sigma: float | None = cf.number(
        5.0,
        "search box K0 +/- bounds_sigma * std0 (seed 2 Eq. 89); null: unbounded",
        lo=0.0,
        lo_open=True,
        optional=True,
    )
    estimate_initial: bool = cf.flag(
        True, "segment initial states projected out (see output_error)"
    )

    def __post_init__(self) -> None:
        cf.normalize_fields(self, "output_error")


def _segments(n: int, seg: int, max_segments: int) -> np.ndarray:
    starts = np.arange(0, n - seg, seg)
    if starts.size == 0:
        raise ConfigError(
            f"record of {n} samples is shorter than one output-error segment ({seg})"
        )
    if starts.size > max_segments:
        starts = starts[np.linspace(0, starts.size - 1, max_segments).astype(int)]
    return starts


def simulate_segments(
    K: dict[str, float],
    params,
    data: FlightData,
    starts: np.ndarray,
    seg: int,
    nu0: np.ndarray | None = None,
) -> np.ndarray:
    """RK4 integration of Eqs. (3c)-(3d) + (6) over each segment, vectorised over segments;
    attitude and rotor speeds are the measured ones (linearly interpolated at the half step).
    Returns (S, seg, 6) predicted ``nu = (v, omega)``."""
    from lpv_sysid.models.quadrotor import mixer

    mix = mixer(params.arm_length)
    m, g = params.mass, params.g
    inertia = np.asarray(params.inertia, dtype=float)
    Ii = np.linalg.inv(inertia)
    dt = float(data.t[1] - data.t[0])
    grav = gravity_body(data.euler[:, 0], data.euler[:, 1], g)
    # rotor reaction torque J_z delta_r': the step mean (delta_r(k+1) - delta_r(k)) / dt, which
    # integrates exactly over the step whatever the rotor speed does inside it
    dr = data.Omega @ mix[3]
    ddr_step = np.diff(dr) / dt

    kk = {nm: float(K[nm]) for ax in AXES for nm, _ in REGRESSORS[ax]}
    l2 = params.arm_length**2
    Id = np.diag(inertia)
    diag_inertia = bool(np.allclose(inertia, np.diag(Id)))

    def f(nu, Om, gr, dd):
        # Eq. (6) written out (same terms as :func:`regressors` @ K, without building the
        # regressor matrices: this is the inner loop of the output-error fit)
        u, v, w, p, q, r = (nu[:, i] for i in range(6))
        d = Om @ mix.T
        d2 = (Om * Om) @ mix.T
        dt_, da, de, dr = d[:, 0], d[:, 1], d[:, 2], d[:, 3]
        Fx = u * (kk["x_mu0"] + kk["x_muw"] * w + kk["x_muh"] * dt_)
        Fy = v * (kk["y_mu0"] + kk["y_muw"] * w + kk["y_muh"] * dt_)
        Fz = (
            kk["z_T0"] * d2[:, 0]
            + kk["z_mu0"] * dt_
            + kk["z_mu"] * (u * u + v * v)
            + kk["z_muw"] * (4 * w * dt_ - p * da - q * de)
        )
        Mx = (
            kk["l_T0"] * d2[:, 1]
            + kk["l_mu0"] * da
            + kk["l_muw"] * (w * da - 2 * l2 * p * dt_ - 0.5 * l2 * q * dr)
            + kk["l_muh"] * v * dt_
            + kk["l_muh_mu0"] * v
            + kk["l_muh_muw"] * v * w
            + kk["l_dr"] * u * dr
        )
        My = (
            kk["m_T0"] * d2[:, 2]
            + kk["m_mu0"] * de
            + kk["m_muw"] * (w * de - 2 * l2 * q * dt_ - 0.5 * l2 * p * dr)
            + kk["m_muh"] * u * dt_
            + kk["m_muh_mu0"] * u
            + kk["m_muh_muw"] * u * w
            + kk["m_dr"] * v * dr
        )
        Mz = (
            kk["n_Q0"] * d2[:, 3]
            + kk["n_mu0"] * dr
            + kk["n_muw"] * (w * dr + p * de + q * da)
            + kk["n_muw2"] * p * q
            + kk["n_muh"] * (u * da + v * de)
            + kk["n_muh_muw"] * (u * p + v * q)
            + params.j_rotor * dd
        )
        out = np.empty_like(nu)
        # v x omega + g R^T e3 + F / m  (Eq. 3c)
        out[:, 0] = v * r - w * q + gr[:, 0] + Fx / m
        out[:, 1] = w * p - u * r + gr[:, 1] + Fy / m
        out[:, 2] = u * q - v * p + gr[:, 2] + Fz / m
        # I^-1 ((I omega) x omega + M)  (Eq. 3d)
        if diag_inertia:
            h0, h1, h2 = Id[0] * p, Id[1] * q, Id[2] * r
            out[:, 3] = (h1 * r - h2 * q + Mx) / Id[0]
            out[:, 4] = (h2 * p - h0 * r + My) / Id[1]
            out[:, 5] = (h0 * q - h1 * p + Mz) / Id[2]
        else:
            wv = nu[:, 3:]
            out[:, 3:] = (np.cross(wv @ inertia.T, wv) + np.stack([Mx, My, Mz], axis=1)) @ Ii.T
        return out

    nu = (
        np.concatenate([data.v[starts], data.omega[starts]], axis=1)
        if nu0 is None
        else np.array(nu0)
    )
    out = np.empty((starts.size, seg, 6))
    out[:, 0] = nu
    for k in range(seg - 1):
        a, b = starts + k, starts + k + 1
        ins0 = (data.Omega[a], grav[a], ddr_step[a])
        ins1 = (data.Omega[b], grav[b], ddr_step[a])
        insh = tuple(0.5 * (p0 + p1) for p0, p1 in zip(ins0, ins1))
        k1 = f(nu, *ins0)
        k2 = f(nu + 0.5 * dt * k1, *insh)
        k3 = f(nu + 0.5 * dt * k2, *insh)
        k4 = f(nu + dt * k3, *ins1)
        nu = nu + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        if not np.all(np.isfinite(nu)) or np.max(np.abs(nu)) > 1e3:
            nu = np.where(np.isfinite(nu), np.clip(nu, -1e3, 1e3), 1e3)
        out[:, k + 1] = nu
    return out


def output_error(
    data: FlightData,
    params,
    K0: dict[str, float],
    cfg: OutputErrorConfig = OutputErrorConfig(),
    std0: dict[str, float] | None = None,
    smoother=None,
) -> NonlinearResult:
    """Step 2: refine K by output-error NLS over short segments (seed 2 Sec. 4).

    As in seed 2 Eqs. (89), (95), (101), the preliminary estimates bound the search: with
    ``std0`` (the regression's standard errors) every parameter is kept inside
    ``K0 +/- cfg.bounds_sigma * std0`` - parameters the data hardly determine (flat
    directions of the cost, e.g. the nearly collinear delta / delta^2 regressors of Fig. 10)
    cannot wander off to compensate for measurement noise in the segment initial states.
    ``smoother`` (the filter of :func:`flight_data`) gives the segments' initial states from
    the smoothed ``v, omega``.  A noisy initial rate persists over a weakly damped segment and
    biases the fit; with ``cfg.estimate_initial`` the initial state of every segment is a
    nuisance parameter eliminated by variable projection: the trajectory sensitivity to the
    6 initial states is obtained by finite differences (the 7 perturbed simulations run
    vectorised with the nominal one) and the residual is projected onto the orthogonal
    complement of that sensitivity (one Gauss-Newton step, exact for the locally linear
    dependence on the initial state).
    """
    n = _check(data)
    dt = float(data.t[1] - data.t[0])
    seg = max(3, int(round(cfg.segment_s / dt)))
    starts = _segments(n, seg, cfg.max_segments)
    free = (
        list(cfg.free) if cfg.free is not None else [nm for ax in AXES for nm, _ in REGRESSORS[ax]]
    )
    unknown = [nm for nm in free if nm not in K0]
    if unknown:
        raise ConfigError(f"output error: no initial value for {unknown}")
    meas = np.stack(
        [np.concatenate([data.v[s : s + seg], data.omega[s : s + seg]], axis=1) for s in starts]
    )
    scale_out = np.maximum(meas.reshape(-1, 6).std(axis=0), 1e-6)
    x0 = np.array([K0[nm] for nm in free])
    xs = np.where(np.abs(x0) > 0, np.abs(x0), 1e-6)  # parameter scaling
    nu0 = None
    if smoother is not None:
        nus = smoother(np.concatenate([data.v, data.omega], axis=1))
        nu0 = nus[starts]

    n_seg = starts.size
    base0 = np.concatenate([data.v[starts], data.omega[starts]], axis=1) if nu0 is None else nu0
    h = 1e-4 * np.maximum(scale_out, 1e-3)
    if cfg.estimate_initial:
        pert = [base0] + [base0 + h[j] * np.eye(6)[j] for j in range(6)]
        nu_all, starts_all = np.concatenate(pert), np.tile(starts, 7)
    else:
        nu_all, starts_all = base0, starts

    def resid(z):
        K = dict(K0)
        K.update(dict(zip(free, z * xs)))
        pred = simulate_segments(K, params, data, starts_all, seg, nu_all)
        r0 = (pred[:n_seg, 1:] - meas[:, 1:]) / scale_out  # (S, seg-1, 6)
        if not cfg.estimate_initial:
            return r0.ravel()
        sens = np.stack(
            [
                (pred[(j + 1) * n_seg : (j + 2) * n_seg, 1:] - pred[:n_seg, 1:]) / scale_out / h[j]
                for j in range(6)
            ],
            axis=-1,
        ).reshape(n_seg, -1, 6)
        r = r0.reshape(n_seg, -1)
        StS = np.einsum("snj,snk->sjk", sens, sens) + 1e-12 * np.eye(6)
        delta = np.linalg.solve(StS, -np.einsum("snj,sn->sj", sens, r)[..., None])[..., 0]
        return (r + np.einsum("snj,sj->sn", sens, delta)).ravel()

    lo = np.full(len(free), -np.inf)
    hi = np.full(len(free), np.inf)
    if std0 is not None and cfg.bounds_sigma is not None:
        for i, nm in enumerate(free):
            s = float(std0.get(nm, 0.0))
            if s > 0 and np.isfinite(s):
                lo[i] = (x0[i] - cfg.bounds_sigma * s) / xs[i]
                hi[i] = (x0[i] + cfg.bounds_sigma * s) / xs[i]
    from scipy.optimize import least_squares  # here: scipy.optimize costs ~0.1 s to import

    sol = least_squares(
        resid, x0 / xs, method="trf", x_scale="jac", max_nfev=cfg.max_nfev, bounds=(lo, hi)
    )
    if not np.all(np.isfinite(sol.x)):
        raise SolverError("output-error refinement diverged")
    Kr = dict(K0)
    Kr.update(dict(zip(free, sol.x * xs)))
    J = sol.jac
    dof = max(sol.fun.size - len(free) - (6 * n_seg if cfg.estimate_initial else 0), 1)
    s2 = float(sol.fun @ sol.fun) / dof
    try:
        cov = s2 * np.linalg.pinv(J.T @ J)
        rstd = {nm: float(np.sqrt(max(cov[i, i], 0.0)) * xs[i]) for i, nm in enumerate(free)}
    except np.linalg.LinAlgError:
        rstd = {}
    log.info(
        "output error: cost %.4g -> %.4g in %d evaluations",
        0.5 * float(resid(x0 / xs) @ resid(x0 / xs)),
        sol.cost,
        sol.nfev,
    )
    return NonlinearResult(
        Kr, {}, {}, method="output-error", cost=float(sol.cost), refined_std=rstd
    )
