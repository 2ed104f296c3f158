"""The ``taylor2`` vertex fit (seed 0 App. B with Eq. 6 nonlinear,
:mod:`lpv_sysid.ident.vertex.taylor`): equation error with the known part nonlinear and the
second-order remainders as nuisance regressors, the motor rows
(:mod:`lpv_sysid.ident.vertex.motor_rows`), then the re-expansion about the identified equilibrium
(seed 0 Eq. 13).

Two stages: :func:`fit_rows` solves all rows jointly about the flown trim (everything that does
not depend on how the motor constants enter); :func:`finish` adds the motor prior where the
maneuver cannot identify them and re-expands.  :func:`lpv_sysid.ident.vertex.identify_vertices`
finishes a maneuver's row solution with the prior pooled over the others without solving its
rows again.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident import equation_error as ee
from lpv_sysid.ident.vertex import taylor
from lpv_sysid.ident.vertex.config import IdentificationConfig, quadrotor_params
from lpv_sysid.ident.vertex.motor_rows import motor_design, motor_response
from lpv_sysid.ident.vertex.noise import design_noise, regressor_noise_var
from lpv_sysid.ident.vertex.segment import fit_indices, prepare, rotor_input
from lpv_sysid.ident.vertex.types import KnownModel, VertexData

log = logging.getLogger(__name__)

#: ``((a_Omega, std), (b_Omega, std))`` of the motor constants where a maneuver lacks them
MotorPrior = tuple[tuple[float, float], tuple[float, float]]


@dataclass(frozen=True)
class RowSolution:
    """:func:`fit_rows`: the rows' joint equation-error solution about the flown trim."""

    x0: np.ndarray  # flown trim mean (the expansion point of the regressors)
    u0: np.ndarray
    params: object  # QuadrotorParams of the known part
    fits: tuple  # ee.RowFit per row (state rows, then the motor rows when identified)
    joint: np.ndarray  # joint covariance of all rows' parameters
    dof: float | None  # Student-t degrees of freedom
    nuis_kept: dict  # row -> the nuisance regressors kept (taylor.IdentifiedModel)
    motor_identified: bool  # the motor rows were identified from this maneuver
    motor_info: object  # latency tau [s] when identified, else why they were not


def fit_taylor2(
    data: VertexData,
    x0,
    u0,
    known: KnownModel,
    cfg: IdentificationConfig,
    motor_prior: MotorPrior | None = None,
):
    """Equation error with the known part nonlinear and second-order nuisance regressors
    (:mod:`lpv_sysid.ident.vertex.taylor`), re-expanded about the identified equilibrium.

    Returns ``(Fit, x_e, u_e, xdot_flown, motor)``: :func:`fit_rows`, then :func:`finish`.
    """
    return finish(fit_rows(data, x0, u0, known, cfg), known, cfg, motor_prior, data.name)


def fit_rows(
    data: VertexData, x0, u0, known: KnownModel, cfg: IdentificationConfig
) -> RowSolution:
    """All rows' designs about the flown trim ``x0, u0`` and their joint solution.

    In the moment rows the rotor reaction torque ``J_z delta_r'`` is regressed on the
    *measured* rotor acceleration (``aux``), so the rows stay exact when a rotor saturates; its
    linearisation ``J_z (-a_Omega d delta_r + b_Omega du_r)`` enters ``A[., dr]``, ``B[., ur]``
    through the (identified) delta_r row.
    """
    params = quadrotor_params(cfg)
    rows = list(taylor.ROWS)
    x0 = np.asarray(x0, dtype=float)
    widths = {}

    def nonlin(x_raw):
        kr = taylor.known_rigid_body(x_raw, params)
        rem = taylor.remainders(x0, x_raw - x0, params)
        widths.update({a: r.shape[1] for a, r in rem.items()})
        return np.concatenate(
            [kr] + [rem[a] for a in taylor.FORCE_AXES + taylor.MOMENT_AXES], axis=1
        )

    dt, full, keep = fit_indices(data, cfg)
    u_in = rotor_input(data, params)
    _, xdot, dx, du, nl_s = prepare(data, cfg, x0, u0, nonlin, u=u_in)
    x0 = np.asarray(x0, dtype=float)
    u0 = np.asarray(u0, dtype=float)
    rem, off = {}, 6
    for a in taylor.FORCE_AXES + taylor.MOMENT_AXES:
        rem[a] = nl_s[:, off : off + widths[a]]
        off += widths[a]
    iv = None
    if cfg.instruments:
        # the same regressors with the measured rotor speeds replaced by the motor model's response
        # to the command (Eq. 8): uncorrelated with telemetry noise and aliasing (errors in
        # variables)
        x_iv = np.array(data.x, dtype=float)
        x_iv[:, 8:12] = motor_response(u_in, x_iv[0, 8:12], dt, params)
        _, _, dx_iv, _, nl_iv = prepare(
            dataclasses.replace(data, x=x_iv), cfg, x0, u0, nonlin, u=u_in
        )
        rem_iv, off = {}, 6
        for a in taylor.FORCE_AXES + taylor.MOMENT_AXES:
            rem_iv[a] = nl_iv[:, off : off + widths[a]]
            off += widths[a]
        iv = (dx_iv, rem_iv)
    nuis_idx = taylor.nuisance_index(rem, params)
    nvar, ndvar, rotor_var = regressor_noise_var(cfg, params, dt)
    designs, nuis_kept = [], {}
    n = dx.shape[0]
    for k, row in enumerate(rows):
        ja = [int(j) for j in np.nonzero(known.maskA[row])[0]]
        kb = [int(c) for c in np.nonzero(known.maskB[row])[0]]
        y = xdot[:, row] - nl_s[:, k]
        H = [dx[:, ja]]
        labels = [f"x{j}" for j in ja]
        aux = 3 in kb  # J_z delta_r' (seed 0 Eq. 6f): the measured rotor acceleration
        kb = [c for c in kb if c != 3]
        H.append(du[:, kb])
        labels += [f"u{c}" for c in kb]
        H.append(np.ones((n, 1)))
        labels.append("bias")
        if aux:
            H.append(xdot[:, 11:12])
            labels.append("aux")
        Hm = np.concatenate(H, axis=1)
        Z = None
        if iv is not None:
            Z = Hm.copy()
            Z[:, : len(ja)] = iv[0][:, ja]
        cols = nuis_idx[row]
        if cols:
            E = np.stack([rem[a][:, c] for a, c in cols], axis=1)
            Hm, chosen = ee.append_independent(Hm, E)
            labels += [f"nuisance{c}" for c in chosen]
            if iv is not None and Z is not None:
                Z = np.concatenate(
                    [Z] + [iv[1][cols[c][0]][:, cols[c][1] : cols[c][1] + 1] for c in chosen],
                    axis=1,
                )
        designs.append(
            ee.RowDesign(
                row,
                y,
                Hm,
                tuple(ja),
                tuple(kb),
                tuple(labels),
                Z=Z,
                noise_var=None if Z is not None else design_noise(labels, nvar, ndvar),
            )
        )
        nuis_kept[row] = cols
    motor_d, info = motor_design(data, cfg, params, full, keep, x0, u0, u_in, rotor_var=rotor_var)
    fits, joint, dof = ee.solve_rows(
        designs + ([motor_d] if motor_d is not None else []), cfg.covariance, dt
    )
    if joint is None:  # solve_rows has no covariance only without designs
        raise ConfigError("vertex identification: no state rows to fit")
    return RowSolution(
        x0, u0, params, tuple(fits), joint, dof, nuis_kept, motor_d is not None, info
    )


def finish(
    rows: RowSolution,
    known: KnownModel,
    cfg: IdentificationConfig,
    motor_prior: MotorPrior | None = None,
    name: str = "",
    v_target: np.ndarray | None = None,
    psi_var: float = 0.0,
    psi_dot: float | None = None,
):
    """``(Fit, x_e, u_e, xdot_flown, motor)`` from :func:`fit_rows`: where the maneuver did not
    identify ``a_Omega, b_Omega`` and ``motor_prior`` is given, they enter uncertain with it;
    then the re-expansion about the identified equilibrium (``cfg.equilibrium``) or the
    Jacobians at the flown trim. ``v_target``: the body velocity of that equilibrium (the
    commanded vertex v_d, ``cfg.expand_at: commanded``: the identified second-order model,
    exact in its quadratic remainders, carried from the flown velocity to the one the LPV
    model is scheduled on, its uncertainty propagated by the same delta method); None: the
    flown mean velocity. ``psi_dot``: the equilibrium's yaw rate (the trim-window mean of the
    per-sample yaw rate, segment.yaw_rate_mean); None: the yaw rate of the mean state."""
    x0, u0, params, info = rows.x0, rows.u0, rows.params, rows.motor_info
    fits, joint, dof, nuis_kept = list(rows.fits), rows.joint, rows.dof, rows.nuis_kept
    motor = (
        {"mode": "identified", "delay": info}
        if rows.motor_identified
        else {"mode": "known", "reason": info}
    )
    if not rows.motor_identified and motor_prior is not None:
        # a_Omega, b_Omega not identifiable here: uncertain with the prior (seed 0 Sec. IV values)
        (a, sa), (b, sb) = motor_prior
        P = joint.shape[0]
        prior = ee.RowFit(
            8,
            (),
            (),
            np.array([-a, b]),
            np.diag([sa**2, sb**2]),
            np.diag([sa**2, sb**2]),
            np.diag([sa**2, sb**2]),
            0.0,
            float("nan"),
            0,
            0,
            taylor.MOTOR_LABELS,
            P,
            dof,
        )
        fits = list(fits) + [prior]
        joint = np.block([[joint, np.zeros((P, 2))], [np.zeros((2, P)), prior.cov]])
        motor = {"mode": "prior", "reason": info, "a_omega": [a, sa], "b_omega": [b, sb]}
    maskA, maskB = known.maskA.copy(), known.maskB.copy()
    if motor["mode"] != "known":
        for j in range(4):
            maskA[8 + j, 8 + j] = True
            maskB[8 + j, j] = True
    mA0, mB0 = maskA.copy(), maskB.copy()  # the identified elements (before fixed_intervals)
    model = taylor.IdentifiedModel(x0, u0, fits, nuis_kept, params)
    theta = np.concatenate([rf.theta for rf in fits])
    if psi_dot is None:
        psi_dot = float((np.sin(x0[0]) * x0[6] + np.cos(x0[0]) * x0[7]) / np.cos(x0[1]))
    if cfg.equilibrium:
        v_e = x0[2:5] if v_target is None else np.asarray(v_target, dtype=float)
        rx = taylor.reexpand(
            model,
            theta,
            joint,
            v_e,
            psi_dot,
            maskA,
            maskB,
            fixed=cfg.fixed_intervals,
            psi_var=psi_var,
        )
        if rx.maskA is not None and rx.maskB is not None:
            maskA, maskB = rx.maskA, rx.maskB
        x_e, u_e, A, B, sA, sB, flown = (
            rx.x_e,
            rx.u_e,
            rx.A,
            rx.B,
            rx.std_A,
            rx.std_B,
            rx.xdot_flown,
        )
        if v_target is not None:  # the derivative at the flown point itself (meta)
            flown = np.concatenate(
                [
                    [0.0, 0.0],
                    model.residual(
                        np.concatenate([x0[:2], x0[8:12], u0]), theta, x0[2:5], psi_dot
                    ),
                ]
            )
        log.debug(
            "%s: equilibrium re-expansion in %d Newton steps, shift %s",
            name,
            rx.iterations,
            np.round(x_e - x0, 4).tolist(),
        )
    else:
        flown = np.concatenate(
            [
                [0.0, 0.0],
                model.residual(np.concatenate([x0[:2], x0[8:12], u0]), theta, x0[2:5], psi_dot),
            ]
        )
        A, B = model.jacobians(x0, u0, theta)
        x_e, u_e = x0, np.asarray(u0, dtype=float)
        sA, sB = _direct_std(model, theta, joint, x0, u0, maskA, maskB)

    def expand(v: np.ndarray) -> taylor.Reexpansion:
        """The same identified model re-expanded at body velocity ``v`` (its own uncertainty:
        the delta method there)."""
        return taylor.reexpand(
            model,
            theta,
            joint,
            np.asarray(v, dtype=float),
            psi_dot,
            mA0,
            mB0,
            fixed=cfg.fixed_intervals,
            psi_var=psi_var,
        )

    f = ee.Fit(
        A,
        B,
        sA,
        sB,
        maskA,
        maskB,
        tuple(fits),
        joint,
        dof,
        cfg.covariance.method,
        expand if cfg.equilibrium else None,
    )
    return f, x_e, u_e, flown, motor


def _direct_std(model, theta, cov, x, u, maskA, maskB):
    """Delta-method standard errors of the Jacobians at a fixed point (no re-expansion)."""
    idx = [
        (m, i, int(j))
        for i in range(maskA.shape[0])
        for m, msk in (("A", maskA), ("B", maskB))
        for j in np.nonzero(msk[i])[0]
    ]

    def elems(th):
        Aw, Bw = model.jacobians(x, u, th)
        return np.array([(Aw if m == "A" else Bw)[i, j] for m, i, j in idx])

    D = np.zeros((len(idx), theta.size))
    for p in range(theta.size):
        e = np.zeros(theta.size)
        e[p] = max(abs(theta[p]), 1e-12) * 1e-6
        D[:, p] = (elems(theta + e) - elems(theta - e)) / (2 * e[p])
    std = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", D, cov, D), 0.0))
    sA, sB = np.zeros(maskA.shape), np.zeros(maskB.shape)
    for (m, i, j), s_ in zip(idx, std):
        (sA if m == "A" else sB)[i, j] = s_
    return sA, sB
