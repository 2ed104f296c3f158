"""The per-vertex identification pipeline (:func:`identify_vertex`, :func:`identify_vertices`)
and its validation (:func:`validate`, :func:`in_sample_metrics`); the method is the
:mod:`lpv_sysid.ident.vertex` docstring."""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident import equation_error as ee
from lpv_sysid.ident import metrics
from lpv_sysid.ident.vertex import uncertainty as unc
from lpv_sysid.ident.vertex.config import IdentificationConfig, quadrotor_params
from lpv_sysid.ident.vertex.noise import design_noise, regressor_noise_var
from lpv_sysid.ident.vertex.output import vertex_order
from lpv_sysid.ident.vertex.segment import (
    equilibrium,
    prepare,
    rotor_input,
    yaw_rate_mean,
    yaw_rate_variance,
)
from lpv_sysid.ident.vertex.taylor2 import MotorPrior, RowSolution, finish, fit_rows
from lpv_sysid.ident.vertex.types import KnownModel, VertexData, VertexResult, known_from_quadrotor

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class VertexStart:
    """:func:`start_vertex`: one maneuver up to where the motor constants enter - the checked
    data, the flown trim mean, the known model and (``taylor2``) the rows' joint solution."""

    data: VertexData
    x0: np.ndarray  # flown trim mean (seed 0 Table 1)
    u0: np.ndarray
    known: KnownModel
    rows: RowSolution | None = None  # taylor2 only

    @property
    def motor_identified(self) -> bool:
        """This maneuver identified ``a_Omega, b_Omega`` (the motor rows of Eq. 8)."""
        return self.rows is not None and self.rows.motor_identified


def start_vertex(
    data: VertexData, cfg: IdentificationConfig, known: KnownModel | None = None
) -> VertexStart:
    """The checks, the flown trim, the known model and (``taylor2``) the rows' joint solution:
    everything up to where the motor constants enter (``appendix_b`` fits in
    :func:`finish_vertex`)."""
    x = np.asarray(data.x, dtype=float)
    u = np.asarray(data.u, dtype=float)
    if (
        x.ndim != 2
        or x.shape[1] != 12
        or u.ndim != 2
        or u.shape[1] != 4
        or x.shape[0] != u.shape[0]
        or x.shape[0] != np.asarray(data.t).size
    ):
        raise ConfigError(
            f"{data.name}: need t (N,), x (N, 12), u (N, 4); got {np.shape(data.t)}, "
            f"{x.shape}, {u.shape}"
        )
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u))):
        raise ConfigError(f"{data.name}: states or inputs contain NaN/inf")
    x0, u0 = equilibrium(data, cfg)
    if known is None:
        known = known_from_quadrotor(x0, cfg.quadrotor)
    if cfg.model != "taylor2":
        return VertexStart(data, x0, u0, known)
    return VertexStart(data, x0, u0, known, fit_rows(data, x0, u0, known, cfg))


def finish_vertex(
    start: VertexStart, cfg: IdentificationConfig, motor_prior: MotorPrior | None = None
) -> VertexResult:
    """The rest of the pipeline from :func:`start_vertex`: the motor prior where needed, the
    re-expansion, the uncertainty box (``appendix_b``: the whole fit).  ``motor_prior``:
    ``((a_Omega, std), (b_Omega, std))`` used when this maneuver cannot identify them (default
    with ``cfg.motor_std``: the configured vehicle's values)."""
    data, x0, u0, known = start.data, start.x0, start.u0, start.known
    x_flown, u_flown, flown, motor = x0, u0, None, {"mode": "known", "reason": "model appendix_b"}
    if cfg.model == "taylor2":
        if motor_prior is None and cfg.motor_std is not None:
            p = quadrotor_params(cfg)
            motor_prior = ((p.a_omega, cfg.motor_std[0]), (p.b_omega, cfg.motor_std[1]))
        assert start.rows is not None  # start_vertex solved the rows for taylor2
        v_target = (
            np.asarray(data.scheduling, dtype=float) if cfg.expand_at == "commanded" else None
        )
        psi_var = yaw_rate_variance(data, cfg) if cfg.fixed_intervals else 0.0
        fit, x0, u0, flown, motor = finish(
            start.rows,
            known,
            cfg,
            motor_prior,
            data.name,
            v_target,
            psi_var,
            yaw_rate_mean(data, cfg),
        )
    else:
        _, xdot, dx, du = prepare(data, cfg, x0, u0, u=rotor_input(data, quadrotor_params(cfg)))
        dt = float(np.median(np.diff(data.t)))
        var, dvar, _ = regressor_noise_var(cfg, quadrotor_params(cfg), dt)
        designs, A0, B0 = ee.row_designs(
            xdot, dx, du, known.A, known.B, known.maskA, known.maskB, cfg.intercept
        )
        designs = [
            dataclasses.replace(d, noise_var=design_noise(d.labels, var, dvar)) for d in designs
        ]
        fits, joint, dof = ee.solve_rows(designs, cfg.covariance, dt)
        fit = ee.assemble(
            fits, A0, B0, known.maskA, known.maskB, joint, dof, cfg.covariance.method
        )
    uv = unc.build(fit.A, fit.B, fit.elements(), cfg.uncertainty, dof=fit.dof)
    r2 = {a: fit.r2.get(i, float("nan")) for a, i in zip(metrics.AXES, metrics.AXIS_INDEX)}
    log.info(
        "%s: %d identified elements, M=%d uncertain systems", data.name, len(uv.intervals), uv.M
    )
    return VertexResult(
        data.name,
        np.asarray(data.scheduling, dtype=float),
        x0,
        u0,
        fit,
        uv,
        r2,
        x_flown=x_flown,
        u_flown=u_flown,
        xdot_flown=flown,
        motor=motor,
    )


def identify_vertex(
    data: VertexData, cfg: IdentificationConfig, known: KnownModel | None = None, motor_prior=None
) -> VertexResult:
    """Full pipeline for one vertex (see module docstring).  ``motor_prior``:
    ``((a_Omega, std), (b_Omega, std))`` used when this maneuver cannot identify them."""
    return finish_vertex(start_vertex(data, cfg, known), cfg, motor_prior)


def pooled_motor(
    results: Sequence[VertexResult],
) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """``((a_Omega, std), (b_Omega, std))`` over the vertices that identified them: the mean,
    with a std covering both the single-vertex errors and the scatter between vertices (the
    constants may change with the flight condition, e.g. battery voltage)."""
    vals = []
    for r in results:
        if r.motor.get("mode") == "identified":
            a, sa = -r.fit.A[8, 8], r.fit.std_A[8, 8]
            b, sb = r.fit.B[8, 0], r.fit.std_B[8, 0]
            vals.append((a, sa, b, sb))
    if not vals:
        return None
    v = np.array(vals)
    out = []
    for m, s_ in ((v[:, 0], v[:, 1]), (v[:, 2], v[:, 3])):
        spread = float(np.std(m, ddof=1)) if m.size > 1 else 0.0
        out.append((float(np.mean(m)), float(np.sqrt(np.mean(s_**2) + spread**2))))
    return out[0], out[1]


def identify_vertices(
    datas: Sequence[VertexData], cfg: IdentificationConfig
) -> list[VertexResult]:
    """:func:`identify_vertex` for every maneuver; where a maneuver cannot identify the motor
    constants (a rotor pinned at a speed limit longer than ``motor_max_pinned``, no independent
    rotor-speed measurement), they enter as uncertain with the :func:`pooled_motor` estimate of
    the maneuvers that did.  When none did, every maneuver is tried again with the pinned
    rotors only gated out (no ``motor_max_pinned`` limit) and all use the pooled estimate of
    those, whose spread between maneuvers then enters its standard error.

    Each maneuver's rows are solved once (:func:`start_vertex`): the motor constants enter only
    in :func:`finish_vertex`, so a maneuver that needs the pooled estimate is finished with it
    from the same row solution (the result of ``identify_vertex(d, cfg with motor: known,
    motor_prior=pooled)``, test_ident_vertices_reuse.py)."""
    if cfg.model != "taylor2" or cfg.motor != "identify":
        return [identify_vertex(d, cfg) for d in datas]
    starts = [start_vertex(d, cfg) for d in datas]
    done = {k: finish_vertex(s, cfg) for k, s in enumerate(starts) if s.motor_identified}
    prior = pooled_motor([done[k] for k in sorted(done)])
    if prior is None:
        relaxed = dataclasses.replace(cfg, motor_max_pinned=1.0)
        prior = pooled_motor([identify_vertex(d, relaxed) for d in datas])
    if prior is None:
        return [done[k] if k in done else finish_vertex(s, cfg) for k, s in enumerate(starts)]
    known_cfg = dataclasses.replace(cfg, motor="known")
    out = []
    for k, s in enumerate(starts):
        if k in done:  # identified its own motor constants (none did when the prior is relaxed)
            out.append(done[k])
            continue
        assert s.rows is not None  # taylor2: the rows were solved, without the motor rows
        reason = s.rows.motor_info
        log.debug(
            "%s: a_Omega, b_Omega not identifiable (%s): pooled estimate of the maneuvers",
            s.data.name,
            reason,
        )
        r = finish_vertex(s, known_cfg, motor_prior=prior)
        r.motor["reason"] = f"{reason}; pooled estimate of the maneuvers that identified them"
        out.append(r)
    return out


def validate(results: Sequence[VertexResult], data: VertexData, cfg: IdentificationConfig) -> dict:
    """Independent validation (seed 0 Table 3): modelled vs measured derivatives on ``data``.

    The LPV model (Eq. 19 at nominal theta, multilinear weights of Eq. 21 at the maneuver's
    commanded ``v_d``) is evaluated on the measured states and inputs:
    ``xdot_m = A(v_d) (x - x0(v_d)) + B(v_d) (u - u0(v_d))``; ``xdot_f`` is the smoothed
    derivative of the measured states.  Returns metrics and the time series.
    """
    from lpv_sysid.models.lpv import multilinear_weights

    order = vertex_order(results, cfg)
    w, outside = multilinear_weights(np.asarray(data.scheduling, dtype=float), cfg.vmin, cfg.vmax)
    if outside:
        raise ConfigError(f"validation maneuver v_d={list(data.scheduling)} outside the box")
    A = sum(wi * results[k].fit.A for wi, k in zip(w, order))
    B = sum(wi * results[k].fit.B for wi, k in zip(w, order))
    x0 = sum(wi * results[k].x0 for wi, k in zip(w, order))
    u0 = sum(wi * results[k].u0 for wi, k in zip(w, order))
    t, xdot_f, dx, du = prepare(data, cfg, x0, u0)
    xdot_m = dx @ A.T + du @ B.T
    out = metrics.axis_metrics(xdot_m, xdot_f)
    out.update({"t": t, "xdot_m": xdot_m, "xdot_f": xdot_f})
    return out


def free_run(
    results: Sequence[VertexResult],
    data: VertexData,
    cfg: IdentificationConfig,
    horizon_s: float = 1.0,
) -> dict:
    """Output-error (free-run) validation on ``data``: the LPV model of :func:`validate`
    simulated from the measured state, driven by the measured input only,

        dx_{k+1} = Phi dx_k + Gamma du_k,   [Phi Gamma] = expm([[A, B], [0, 0]] dt) (ZOH),

    restarted from the measured state every ``horizon_s`` seconds (an unstable vehicle's
    open-loop model diverges from any error within a few times its time to double, so an
    unbounded free run measures that instability, not the model); TIC and NRMSE of the
    simulated against the measured (smoothed) states per axis, and the time series."""
    from scipy.linalg import expm

    from lpv_sysid.models.lpv import multilinear_weights

    if not horizon_s > 0.0:
        raise ConfigError(f"free run: horizon_s must be > 0, got {horizon_s}")
    order = vertex_order(results, cfg)
    w, outside = multilinear_weights(np.asarray(data.scheduling, dtype=float), cfg.vmin, cfg.vmax)
    if outside:
        raise ConfigError(f"validation maneuver v_d={list(data.scheduling)} outside the box")
    A = sum(wi * results[k].fit.A for wi, k in zip(w, order))
    B = sum(wi * results[k].fit.B for wi, k in zip(w, order))
    x0 = sum(wi * results[k].x0 for wi, k in zip(w, order))
    u0 = sum(wi * results[k].u0 for wi, k in zip(w, order))
    t, _, dx, du = prepare(data, cfg, x0, u0)
    dt = float(np.median(np.diff(t)))
    n, m = A.shape[0], B.shape[1]
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = expm(M * dt)
    Phi, Gam = E[:n, :n], E[:n, n:]
    steps = max(1, int(round(horizon_s / dt)))
    x_sim = np.empty_like(dx)
    for k in range(dx.shape[0]):
        if k % steps == 0:
            x_sim[k] = dx[k]
        else:
            x_sim[k] = Phi @ x_sim[k - 1] + Gam @ du[k - 1]
    out: dict = dict(metrics.axis_metrics(x_sim, dx, axes=("u", "v", "w", "p", "q", "r")))
    out.update({"t": t, "x_sim": x_sim, "x_meas": dx, "horizon_s": steps * dt})
    return out


def in_sample_metrics(result: VertexResult, data: VertexData, cfg: IdentificationConfig) -> dict:
    """TIC/NRMSE (Eqs. 24-25) of the vertex model on its own maneuver (per-vertex ``fit``)."""
    t, xdot_f, dx, du = prepare(data, cfg, result.x0, result.u0)
    return metrics.axis_metrics(dx @ result.fit.A.T + du @ result.fit.B.T, xdot_f)
