"""Solving the robust LMI over the element box (:func:`solve_box`); the method is the
:mod:`lpv_sysid.synthesis.robust` docstring."""

from __future__ import annotations

import logging
import time
from typing import Optional, Sequence

import numpy as np

from lpv_sysid.errors import SolverError
from lpv_sysid.models.lpv import ElementBox
from lpv_sysid.synthesis.robust.check import BoxSolution, box_margins
from lpv_sysid.synthesis.robust.problem import build_box_problem

log = logging.getLogger(__name__)


def solve_box(
    box: ElementBox,
    R: np.ndarray,
    C: np.ndarray,
    *,
    gamma: float,
    lyapunov: str = "common",
    objective: str = "feasibility",
    eps: float = 1e-6,
    solver: str = "CLARABEL",
    fallback: Optional[str] = "SCS",
    scale: bool = True,
    vmin=None,
    vmax=None,
    rate: Optional[Sequence[float]] = None,
    verbose: bool = False,
    K_fixed: Optional[np.ndarray] = None,
    gamma_accept: Optional[float] = None,
) -> dict:
    """Solve the robust LMI of the module docstring. With ``K_fixed`` (N, m, n) the gains are
    given and only the Lyapunov matrices, multipliers and gamma are sought (analysis: S_i = K_i X
    or K_i H; the smallest gamma the element-box certificate can prove for that law with
    ``objective: min_gamma``). Returns a dict with the unscaled gains ``K``
    (N, m, n), ``X`` (per vertex), ``S``, ``H``, multipliers ``t`` (per vertex, unscaled:
    t_l = t~_l tau_c^2), ``W`` (rate), ``gamma_solver``, ``gamma_certified``, ``min_margin``,
    ``scaling``, ``size``, ``status``, ``solver``, times. SolverError when no solver returns a
    solution that passes the numpy re-check (:func:`box_margins`) and, with ``gamma_accept``,
    the law of an inaccurate solve is not certified at most ``gamma_accept`` by analysis
    (:func:`_certify_inaccurate_law`)."""
    import cvxpy as cp

    bp = build_box_problem(
        box,
        R,
        C,
        gamma=gamma,
        lyapunov=lyapunov,
        objective=objective,
        eps=eps,
        scale=scale,
        vmin=vmin,
        vmax=vmax,
        rate=rate,
        K_fixed=K_fixed,
    )
    prob, g, kappa, H, Xs, S, T, W = bp.prob, bp.g, bp.kappa, bp.H, bp.Xs, bp.S, bp.T, bp.W
    scaling, sb, pairs, rho, sizes = bp.scaling, bp.sb, bp.pairs, bp.rho, bp.sizes
    build_s, N = bp.build_s, box.N
    installed = set(cp.installed_solvers())
    order = list(dict.fromkeys([solver] + ([fallback] if fallback else [])))
    errors: list = []
    rescue_kw = dict(
        lyapunov=lyapunov,
        eps=eps,
        solver=solver,
        fallback=fallback,
        scale=scale,
        vmin=vmin,
        vmax=vmax,
        rate=rate,
        verbose=verbose,
    )
    # the rescue (synthesis, then analysis of that law) comes right after Clarabel's failure:
    # ~30 s, where the SCS fallback takes minutes on the same problem
    steps = [st for sv in order for st in ([sv, RESCUE] if sv == "CLARABEL" else [sv])]
    if RESCUE not in steps:
        steps.append(RESCUE)
    for sv in steps:
        if sv == RESCUE:
            rescued = _certify_inaccurate_law(
                box,
                R,
                C,
                prob,
                S,
                H,
                scaling,
                objective,
                K_fixed,
                gamma,
                gamma_accept,
                rescue_kw,
                errors,
            )
            if rescued is not None:
                return rescued
            continue
        if sv not in installed:
            errors.append(f"solver {sv} is not installed")
            continue
        kw: dict = {"verbose": verbose}
        if sv == "SCS":
            kw.update(eps=1e-8, max_iters=100000)
        log.info(
            "robust LMI: solving with %s (%d scalar variables, %d LMI blocks, %d scalar "
            "constraints)",
            sv,
            sizes["scalar_variables"],
            sizes["lmi_blocks"],
            sizes["scalar_constraints"],
        )
        t1 = time.perf_counter()
        try:
            prob.solve(solver=sv, **kw)
        except cp.error.SolverError as exc:
            errors.append(f"{sv}: {exc}")
            log.warning("robust LMI: solver %s failed (%s)", sv, exc)
            continue
        wall = time.perf_counter() - t1
        if prob.status == "infeasible":
            raise SolverError(
                f"robust LMI over the element box ({lyapunov} Lyapunov matrix): infeasible ({sv})"
            )
        if prob.status not in ("optimal", "optimal_inaccurate"):
            errors.append(f"{sv}: status {prob.status}")
            continue
        Hs = np.asarray(H.value, dtype=float)
        if not np.all(np.isfinite(Hs)) or np.linalg.cond(Hs) > 1e12:
            errors.append(f"{sv}: H (or X) numerically singular")
            continue
        gs = (
            float(np.asarray(g.value, dtype=float))
            if isinstance(g, cp.Variable)
            else float(gamma) ** 2
        )
        sol = BoxSolution(
            lyapunov,
            [np.asarray(X.value, dtype=float) for X in Xs],
            np.array([np.asarray(s_.value, dtype=float) for s_ in S]),
            Hs,
            [np.asarray(tt.value, dtype=float) for tt in T],
            [[np.asarray(w.value, dtype=float) for w in Wi] for Wi in W] if W else None,
            gs,
            float(np.asarray(kappa.value, dtype=float)) if kappa is not None else float("nan"),
        )
        g_cert, margin = box_margins(sb, sol, float(np.sqrt(gs)) * (1 + 1e-9), pairs, rho)
        ok = margin > 0 if objective != "min_gamma" else np.isfinite(g_cert)
        log.info(
            "robust LMI (%s, %s): %s/%s, gamma %.4g, certified %.4g, margin %.3g, %.2f s",
            lyapunov,
            objective,
            sv,
            prob.status,
            np.sqrt(gs),
            g_cert,
            margin,
            wall,
        )
        if not ok:
            errors.append(
                f"{sv}: status {prob.status} but the numpy re-check fails (margin {margin:.3g})"
            )
            continue
        K_s = np.array([np.linalg.solve(Hs.T, s.T).T for s in sol.S])
        stats = prob.solver_stats
        return {
            "K": scaling.unscale_K(K_s),
            "X": [scaling.unscale_sym(x) for x in sol.X],
            "S": scaling.unscale_S(sol.S),
            "H": scaling.unscale_sym(Hs),
            "t": [sol.t[i] * sb.tau[sb.cols[i]] ** 2 for i in range(N)],
            "W": None if sol.W is None else [[scaling.unscale_sym(w) for w in Wi] for Wi in sol.W],
            "kappa": sol.kappa,
            "gamma_solver": float(np.sqrt(gs)),
            "gamma_certified": g_cert,
            "min_margin": margin,
            "scaling": scaling,
            "size": sizes,
            "status": prob.status,
            "solver": sv,
            "compile_time": float(getattr(prob, "compilation_time", build_s) or build_s) + build_s,
            "solve_time": float(stats.solve_time)
            if stats is not None and stats.solve_time is not None
            else wall,
            "rate": rho.tolist() if lyapunov == "rate" else None,
            "lyapunov": lyapunov,
            "objective": objective,
            "scaled": sb,
            "solution": sol,
        }
    raise SolverError(
        "robust LMI over the element box: no certified solution (" + "; ".join(errors) + ")"
    )


#: the step of :func:`solve_box` that certifies the law of an inaccurate solve
RESCUE = "rescue: synthesis, then analysis"

#: Clarabel settings of the second attempt at a synthesis whose first solve stalled (seen with
#: the interpolation pad on the quick demo: min_effort ends in NumericalError at a duality gap of
#: 6e-5): a little static regularisation and more iterations reach an (inaccurate) point
RESCUE_CLARABEL = {"max_iter": 400, "static_regularization_constant": 1e-7}


def _certify_inaccurate_law(
    box, R, C, prob, S, H, scaling, objective, K_fixed, gamma, gamma_accept, kw, errors
) -> Optional[dict]:
    """Synthesis, then analysis: when no solver returned a point that passes the numpy
    re-check, take the law K_i = S_i H^-1 of an inaccurate solve (a Clarabel re-solve with
    :data:`RESCUE_CLARABEL`, else the last solver's point) and certify THAT law by the analysis
    problem (K fixed, objective ``min_gamma``: linear in X, gamma^2 and the multipliers, well
    conditioned). The law is accepted when the certified gamma is at most ``gamma_accept``
    (the bound the caller must prove; the design gamma is only the synthesis target); the
    result is the analysis' certificate (its X, multipliers, margin) for the synthesized K,
    ``status`` saying so. None when there is no law to take or it is not certified."""
    import cvxpy as cp

    if K_fixed is not None or objective == "min_gamma" or gamma_accept is None:
        return None
    K = _law_of(S, H, scaling)
    if "CLARABEL" in cp.installed_solvers():
        try:
            prob.solve(solver="CLARABEL", verbose=kw["verbose"], **RESCUE_CLARABEL)
            K = _law_of(S, H, scaling) if prob.status in ("optimal", "optimal_inaccurate") else K
        except cp.error.SolverError as exc:
            errors.append(f"CLARABEL (rescue settings): {exc}")
    if K is None:
        return None
    log.info(
        "robust LMI: no certified %s solution; certifying the law of the inaccurate solve by "
        "analysis (K fixed, min_gamma, accepted up to gamma %.4g)",
        objective,
        gamma_accept,
    )
    try:
        an = solve_box(box, R, C, gamma=gamma, objective="min_gamma", K_fixed=K, **kw)
    except SolverError as exc:
        errors.append(f"analysis of the inaccurate law: {exc}")
        return None
    if not (an["gamma_certified"] <= gamma_accept):
        errors.append(
            f"analysis of the inaccurate law: certified gamma {an['gamma_certified']:.4g} > "
            f"{gamma_accept:.4g}"
        )
        return None
    an["K"] = K
    an["objective"] = objective
    an["status"] = f"{objective} inaccurate; law certified by analysis ({an['status']})"
    return an


def _law_of(S, H, scaling) -> Optional[np.ndarray]:
    """K_i = S_i H^-1 (unscaled) from the solver's current values, None without usable ones."""
    if H.value is None or any(s_.value is None for s_ in S):
        return None
    Hs = np.asarray(H.value, dtype=float)
    Ss = np.array([np.asarray(s_.value, dtype=float) for s_ in S])
    if not (np.all(np.isfinite(Hs)) and np.all(np.isfinite(Ss))) or np.linalg.cond(Hs) > 1e12:
        return None
    return scaling.unscale_K(np.array([np.linalg.solve(Hs.T, s.T).T for s in Ss]))
