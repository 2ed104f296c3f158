"""Seed 0 Lemma 1 as a cvxpy problem, and its solution read back.

:func:`build_problem` states Eq. (30) (:mod:`lpv_sysid.synthesis.hinf`) at every Eq. (23)
system, optionally with the seed 2 Eq. (125) pole region on a symmetric H;
:func:`extract_result` turns the solver's values into a
:class:`~lpv_sysid.synthesis.hinf.options.HinfResult` (K_i = S_i H^-1, Eq. 31) and re-checks it
with numpy (:func:`lpv_sysid.synthesis.hinf.lemma1_numeric.certificate_margins`).

Strictness: every LMI is imposed as ``<= -eps I`` and ``X >= eps I`` (in the scaled coordinates of
:mod:`lpv_sysid.synthesis.scaling`). Options: fixed gamma (feasibility) or minimise g = gamma^2;
``lyapunov: common`` ties every X_i^j to one X (the u_e -> z bound then holds for
any scheduling signal v_d(t); not the reference-driven part, docs/certificate.md 3b).
"""

from __future__ import annotations

import logging
from typing import Any, Optional

import numpy as np

from lpv_sysid.errors import SolverError
from lpv_sysid.models.lpv import PolytopicModel
from lpv_sysid.synthesis.hinf.lemma1_numeric import certificate_margins, excitation_matrix
from lpv_sysid.synthesis.hinf.options import HinfOptions, HinfResult, ProblemSize
from lpv_sysid.synthesis.regions import region_lmi
from lpv_sysid.synthesis.scaling import Scaling

log = logging.getLogger(__name__)


def _problem_systems(
    model: PolytopicModel,
    R: np.ndarray,
    C: np.ndarray,
    scaling: Scaling,
    Be: Optional[np.ndarray] = None,
):
    out = []
    for i, lst in enumerate(model.systems):
        for j, (Aj, Bj) in enumerate(lst):
            Aj = np.asarray(Aj, float)
            Bj = np.asarray(Bj, float)
            out.append(
                (i, j, scaling.A(Aj), scaling.Bc(Bj), scaling.Be(excitation_matrix(Bj, R, Be)))
            )
    return out, scaling.C(C)


def build_problem(
    model: PolytopicModel,
    R: np.ndarray,
    C: np.ndarray,
    opts: HinfOptions,
    scaling: Scaling,
    Be: Optional[np.ndarray] = None,
):
    """Eq. (30) at every system of ``model`` (scaled by ``scaling``) as a cvxpy problem:
    (problem, H, S, X by (i, j), gamma^2 variable or None, size, systems, scaled C)."""
    import cvxpy as cp

    n, m = model.n_x, model.n_u
    ne, nz = (R.shape[1] if Be is None else np.shape(Be)[1]), C.shape[0]
    systems, Cs = _problem_systems(model, R, C, scaling, Be)
    H = cp.Variable((n, n), name="H")
    S = [cp.Variable((m, n), name=f"S_{i}") for i in range(model.n_vertices)]
    g_expr: Any  # the cvxpy variable gamma^2 or its fixed value
    if opts.effective_objective == "min_gamma":
        g = cp.Variable(nonneg=True, name="gamma2")
        g_expr = g
    else:
        g = None
        g_expr = float(opts.gamma) ** 2
    Z_ne_n = np.zeros((ne, n))
    Z_n_ne = np.zeros((n, ne))
    Z_nz_ne = np.zeros((nz, ne))
    Z_ne_nz = np.zeros((ne, nz))
    I_ne = np.eye(ne)
    d = 2 * n + ne + nz
    epsI = opts.eps * np.eye(d)
    CH = Cs @ H
    HC = CH.T
    HpHt = H + H.T
    constraints = []
    Xs: dict = {}
    X_common = cp.Variable((n, n), symmetric=True, name="X") if opts.lyapunov == "common" else None
    for i, j, A, Bc, Be_j in systems:
        X = (
            X_common
            if X_common is not None
            else cp.Variable((n, n), symmetric=True, name=f"X_{i}_{j}")
        )
        Xs[(i, j)] = X
        U = A @ H + Bc @ S[i]
        Ut = U.T
        M = cp.bmat(
            [
                [U + Ut, -X + H.T - U, Be_j, HC],
                [-X + H - Ut, -HpHt, Z_n_ne, -HC],
                [Be_j.T, Z_ne_n, -I_ne, Z_ne_nz],
                [CH, -CH, Z_nz_ne, -g_expr * np.eye(nz)],
            ]
        )
        constraints.append(M << -epsI)
        if X_common is None or (i, j) == systems[0][:2]:
            constraints.append(X >> opts.eps * np.eye(n))
    n_lmi = len(systems)
    n_x = 1 if X_common is not None else n_lmi
    size = ProblemSize(
        scalar_variables=n_x * n * (n + 1) // 2
        + model.n_vertices * m * n
        + n * n
        + (1 if g is not None else 0),
        lmi_blocks=n_lmi + n_x,
        lmi_total_dim=n_lmi * d + n_x * n,
        scalar_constraints=n_lmi * d * (d + 1) // 2 + n_x * n * (n + 1) // 2,
        eq30_block_dim=d,
    )
    if opts.region is not None:
        # Combined H-inf + D-region (common-H formulation): H is restricted to be symmetric and
        # used as the Lyapunov matrix of the region LMI of seed 2 Eq. (125) with Gamma_i = S_i, so
        # the same K_i = S_i H^-1 satisfies both. Conservative (H symmetric) but sound.
        alpha, beta = opts.region.characteristic()
        constraints.append(H == H.T)
        dr = alpha.shape[0] * n
        for i, j, A, Bc, Be_ in systems:
            Mr = region_lmi(alpha, beta, H, A @ H + Bc @ S[i])
            constraints.append(0.5 * (Mr + Mr.T) << -opts.eps * np.eye(dr))
            size.lmi_blocks += 1
            size.lmi_total_dim += dr
            size.scalar_constraints += dr * (dr + 1) // 2
    objective = cp.Minimize(g) if g is not None else cp.Minimize(0)
    prob = cp.Problem(objective, constraints)
    return prob, H, S, Xs, g, size, systems, Cs


def extract_result(model, R, C, opts, Be, prob, H, S, Xs, g, size, scaling, used) -> HinfResult:
    """The solved problem of :func:`build_problem` as a :class:`HinfResult` in unscaled
    coordinates, with the numpy re-check of Eq. (30) (gamma_certified, min_margin)."""
    compile_time = float(getattr(prob, "compilation_time", float("nan")) or float("nan"))
    stats = prob.solver_stats
    solve_time = (
        float(stats.solve_time)
        if stats is not None and stats.solve_time is not None
        else float("nan")
    )
    Hs = np.asarray(H.value)
    if not np.all(np.isfinite(Hs)) or np.linalg.cond(Hs) > 1e12:
        raise SolverError(
            f"Lemma 1: H is numerically singular (cond {np.linalg.cond(Hs):.2e}); K = S H^-1 "
            "undefined"
        )
    Ss = np.array([np.asarray(s.value) for s in S])
    K_s = np.array([np.linalg.solve(Hs.T, s.T).T for s in Ss])  # S H^-1
    X_un = [[None] * len(model.systems[i]) for i in range(model.n_vertices)]
    for (i, j), X in Xs.items():
        X_un[i][j] = scaling.unscale_sym(np.asarray(X.value))
    gamma_solver = float(np.sqrt(max(g.value, 0.0))) if g is not None else float(opts.gamma)
    res = HinfResult(
        K=scaling.unscale_K(K_s),
        X=X_un,
        S=scaling.unscale_S(Ss),
        H=scaling.unscale_sym(Hs),
        gamma_requested=float(opts.gamma),
        gamma_solver=gamma_solver,
        status=prob.status,
        solver=used,
        size=size,
        compile_time=compile_time,
        solve_time=solve_time,
        scaling=scaling,
        eps=opts.eps,
    )
    # independent numpy re-evaluation in the scaled coordinates (a congruence, inertia-preserving)
    gam, margin = certificate_margins(
        model,
        R,
        C,
        res.X,
        res.S,
        res.H,
        scaling,
        gamma=float(opts.gamma) if opts.effective_objective != "min_gamma" else gamma_solver,
        Be=Be,
    )
    res.gamma_certified = gam
    res.min_margin = margin
    log.info(
        "Lemma 1: %s/%s, gamma_solver=%.4g, certified=%.4g, margin=%.3g, compile %.2fs, solve "
        "%.2fs",
        used,
        prob.status,
        gamma_solver,
        gam,
        margin,
        compile_time,
        solve_time,
    )
    return res
