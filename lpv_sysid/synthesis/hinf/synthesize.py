"""Solving seed 0 Lemma 1 (:func:`solve_lemma1`) and, when it is infeasible, the remedies of
Sec. VI (:func:`synthesize_hinf`, :func:`remedy_analysis`); the method is the
:mod:`lpv_sysid.synthesis.hinf` docstring."""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.models.lpv import PolytopicModel
from lpv_sysid.synthesis.hinf.box import resolve_method, solve_box
from lpv_sysid.synthesis.hinf.lemma1_cvxpy import build_problem, extract_result
from lpv_sysid.synthesis.hinf.lemma1_numeric import excitation_matrix
from lpv_sysid.synthesis.hinf.options import HinfOptions, HinfResult
from lpv_sysid.synthesis.scaling import Scaling, choose_scaling

log = logging.getLogger(__name__)

#: AUTO: Clarabel up to this many Eq. (30) blocks, SCS above (measured crossover, see
#: bench/results/synthesis.md: Clarabel 2.9 s / 18 s / 117 s for 8 / 16 / 32 blocks, SCS < 1.5 s).
AUTO_CLARABEL_MAX_BLOCKS = 8


def _solve(prob, solver: str, verbose: bool) -> None:
    kw: dict = {"verbose": verbose}
    if solver == "SCS":
        kw.update(eps=1e-7, max_iters=200000)
    prob.solve(solver=solver, **kw)


def solve_lemma1(
    model: PolytopicModel,
    R: np.ndarray,
    C: np.ndarray,
    opts: HinfOptions = HinfOptions(),
    Be: Optional[np.ndarray] = None,
) -> HinfResult:
    """Solve seed 0 Lemma 1 (Eq. 30) once; no remedy analysis (see :func:`synthesize_hinf`).

    ``R`` gives B_e^j = B_c^j R (Eq. 19); an explicit ``Be`` (n, n_e) replaces it for plants whose
    exogenous input is not matched with the control input (then R is ignored).

    Raises SolverError when the solver fails or reports infeasibility.
    """
    import cvxpy as cp

    R = np.zeros((model.n_u, 0)) if R is None else np.asarray(R, dtype=float)
    C = np.asarray(C, dtype=float)
    method = resolve_method(model, opts)
    if method == "box":
        return solve_box(model, R, C, opts, Be)
    if opts.lyapunov == "rate":
        raise ConfigError(
            "hinf.lyapunov: rate is offered for the element-box LMI (hinf.method: box)"
        )
    if opts.effective_objective == "min_effort":
        raise ConfigError(
            "hinf.objective: min_effort is offered for the element-box LMI (hinf.method: box)"
        )
    if Be is None and R.shape[0] != model.n_u:
        raise ConfigError(f"R has {R.shape[0]} rows, the model has {model.n_u} inputs")
    if C.shape[1] != model.n_x:
        raise ConfigError(f"C has {C.shape[1]} columns, the model has {model.n_x} states")
    all_A = [a for lst in model.systems for a, _ in lst]
    all_B = [b for lst in model.systems for _, b in lst]
    all_Be = [excitation_matrix(b, R, Be) for b in all_B]
    scaling = (
        choose_scaling(all_A, all_B, all_Be, C)
        if opts.scale
        else Scaling.identity(model.n_x, model.n_u)
    )
    log.info(
        "Lemma 1 (seed 0 Eq. 30): building the LMI over %d systems (%d vertices, %d states, "
        "%d inputs, %s Lyapunov matrix, objective %s)",
        sum(len(lst) for lst in model.systems),
        model.n_vertices,
        model.n_x,
        model.n_u,
        opts.lyapunov,
        opts.effective_objective,
    )
    prob, H, S, Xs, g, size, systems, Cs = build_problem(model, R, C, opts, scaling, Be)
    installed = set(cp.installed_solvers())
    solvers = _solver_order(opts, len(systems), installed)
    errors = []
    for sv in solvers:
        if sv not in installed:
            errors.append(f"solver {sv} is not installed")
            continue
        log.info(
            "Lemma 1: solving with %s (%d scalar variables, %d LMI blocks of total dimension "
            "%d, %d scalar constraints)",
            sv,
            size.scalar_variables,
            size.lmi_blocks,
            size.lmi_total_dim,
            size.scalar_constraints,
        )
        try:
            _solve(prob, sv, opts.verbose)
        except cp.error.SolverError as exc:
            errors.append(f"{sv}: {exc}")
            log.warning("LMI solver %s failed (%s)", sv, exc)
            continue
        if prob.status == "infeasible":
            raise SolverError(f"Lemma 1 LMI (seed 0 Eq. 30): infeasible ({sv})")
        if prob.status not in ("optimal", "optimal_inaccurate"):
            errors.append(f"{sv}: status {prob.status}")
            continue
        try:
            res = extract_result(model, R, C, opts, Be, prob, H, S, Xs, g, size, scaling, sv)
        except SolverError as exc:
            errors.append(f"{sv}: {exc}")
            continue
        # the solver's word is not the certificate: accept only what numpy re-checks (Eq. 30)
        ok = (
            res.min_margin > 0
            if opts.effective_objective != "min_gamma"
            else np.isfinite(res.gamma_certified)
        )
        if ok:
            return res
        errors.append(
            f"{sv}: status {prob.status} but the numpy re-check of Eq. (30) fails "
            f"(margin {res.min_margin:.3g}, gamma {res.gamma_certified:.4g})"
        )
        log.warning("%s", errors[-1])
    raise SolverError(
        "Lemma 1 LMI (seed 0 Eq. 30): no certified solution (" + "; ".join(errors) + ")"
    )


def _solver_order(opts: HinfOptions, n_blocks: int, installed: set) -> list:
    """Solvers to try in order (``AUTO``: MOSEK if installed, else Clarabel/SCS by problem
    size)."""
    if opts.solver == "AUTO":
        first = ["MOSEK"] if "MOSEK" in installed else []
        by_size = (
            ["CLARABEL", "SCS"] if n_blocks <= AUTO_CLARABEL_MAX_BLOCKS else ["SCS", "CLARABEL"]
        )
        order = first + by_size
    else:
        order = [opts.solver] + ([opts.fallback] if opts.fallback else [])
    return list(dict.fromkeys(order))


# --------------------------------------------------------------------------- remedies
@dataclass
class Remedy:
    gamma_requested: float
    gamma_min: float
    excitation_shrink: float  # divide Delta_t..Delta_r (R) by this factor
    output_grow: float  # multiply Delta_u..Delta_w (Q) by this factor
    uncertainty_shrink: Optional[float] = None  # largest rho in [0,1] found feasible (bisection)
    nominal_gamma_min: Optional[float] = None
    failure: str = ""  # why the solve at gamma_requested failed (the solver's / re-check's words)

    def message(self) -> str:
        if self.gamma_min < self.gamma_requested:
            # not infeasibility: a point below the requested bound exists, the solve at the
            # requested one failed numerically (solver accuracy or the numpy re-check)
            return (
                f"Lemma 1 not certified at gamma={self.gamma_requested:g}, but NOT infeasible: "
                f"a gamma minimisation reached gamma_min={self.gamma_min:.4g} < "
                f"{self.gamma_requested:g}; the solve at the requested objective failed "
                f"numerically ({self.failure or 'solver'}). Remedies: another solver "
                "(hinf.solver: MOSEK / SCS / CLARABEL), hinf.objective: feasibility or "
                "min_gamma, a larger hinf.eps, or a smaller uncertainty set (the pad / "
                "inflation of uncertainty.*)"
            )
        lines = [
            f"Lemma 1 infeasible at gamma={self.gamma_requested:g}: the smallest achievable bound "
            "is "
            f"gamma_min={self.gamma_min:.4g}.",
            "Remedies of seed 0 Sec. VI (the map u_e -> z scales linearly with R and with Q^-1, "
            "Eqs. 27-28):",
            "  (1) reduce the excitation magnitudes Delta_t..Delta_r (R) by a factor >= "
            f"{self.excitation_shrink:.4g}, or",
            "  (2) enlarge the allowed output magnitudes Delta_u..Delta_w (Q) by a factor >= "
            f"{self.output_grow:.4g}, or",
        ]
        if self.uncertainty_shrink is not None:
            if self.uncertainty_shrink > 0:
                lines.append(
                    "  (3) reduce the model uncertainty intervals to <= "
                    f"{100 * self.uncertainty_shrink:.1f}% "
                    "of their identified width (bisection) by refined identification."
                )
            else:
                lines.append(
                    "  (3) reducing the model uncertainty alone does not suffice (nominal "
                    "gamma_min = "
                    f"{self.nominal_gamma_min:.4g})."
                )
        else:
            lines.append(
                "  (3) reduce the model uncertainty by refined identification "
                "(set hinf.remedy_bisection_steps > 0 to quantify)."
            )
        return "\n".join(lines)


def _shrunk_model(model: PolytopicModel, rho: float) -> PolytopicModel:
    """Uncertainty vertices shrunk by rho about the nominal (remedy 3); an element box shrinks its
    half-widths about the box centre (rho = 0: a 1e-9 residue, the box keeps its elements). A
    common input set keeps
    its product structure: its corners shrink about the hull of the vertex nominals
    (:meth:`lpv_sysid.models.lpv.CommonInputSet.shrunk`), so B stays common to all vertices."""
    if model.box is not None:
        b = model.box
        box = replace(b, half=tuple(np.asarray(h, dtype=float) * max(rho, 1e-9) for h in b.half))
        return replace(
            model,
            box=box,
            systems=box.sample_systems(list(zip(model.A, model.B)), len(model.systems[0])),
        )
    if model.common_input is not None:
        common = model.common_input.shrunk(rho)
        MB = common.M
        systems = [
            [
                (model.A[i] + rho * (a - model.A[i]), common.corners[j % MB])
                for j, (a, _) in enumerate(lst)
            ]
            for i, lst in enumerate(model.systems)
        ]
        return replace(model, systems=systems, common_input=common)
    systems = [
        [
            (model.A[i] + rho * (a - model.A[i]), model.B[i] + rho * (b - model.B[i]))
            for a, b in lst
        ]
        for i, lst in enumerate(model.systems)
    ]
    return replace(model, systems=systems)


def remedy_analysis(
    model: PolytopicModel,
    R: np.ndarray,
    C: np.ndarray,
    opts: HinfOptions,
    Be: Optional[np.ndarray] = None,
) -> Remedy:
    """Quantify the remedies of seed 0 Sec. VI for a requested gamma (see module docstring)."""
    g_opts = replace(opts, minimize_gamma=True, objective="min_gamma")
    log.info("remedies (seed 0 Sec. VI): the smallest feasible gamma")
    gmin = solve_lemma1(model, R, C, g_opts, Be).gamma_solver
    log.info("remedies: gamma_min %.4g for gamma %.4g requested", gmin, opts.gamma)
    factor = gmin / opts.gamma
    rem = Remedy(opts.gamma, gmin, excitation_shrink=factor, output_grow=factor)
    if opts.remedy_bisection_steps > 0 and factor > 1:
        nominal = _shrunk_model(model, 0.0)
        log.info("remedies: gamma_min of the nominal model (no uncertainty)")
        try:
            g0 = solve_lemma1(nominal, R, C, g_opts, Be).gamma_solver
        except SolverError:
            g0 = float("inf")
        rem.nominal_gamma_min = g0
        if g0 >= opts.gamma:
            rem.uncertainty_shrink = 0.0
        else:
            lo, hi = 0.0, 1.0
            f_opts = replace(opts, minimize_gamma=False, objective="feasibility")
            for step in range(opts.remedy_bisection_steps):
                mid = 0.5 * (lo + hi)
                log.info(
                    "remedies: uncertainty shrink bisection %d/%d, trying %.4g of the set "
                    "(feasible up to %.4g)",
                    step + 1,
                    opts.remedy_bisection_steps,
                    mid,
                    lo,
                )
                try:
                    solve_lemma1(_shrunk_model(model, mid), R, C, f_opts, Be)
                    lo = mid
                except SolverError:
                    hi = mid
            rem.uncertainty_shrink = lo
    return rem


def synthesize_hinf(
    model: PolytopicModel,
    R: np.ndarray,
    C: np.ndarray,
    opts: HinfOptions = HinfOptions(),
    Be: Optional[np.ndarray] = None,
) -> HinfResult:
    """Lemma 1 with the remedy advice of Sec. VI on failure.

    Feasibility mode: solve at ``opts.gamma``; if infeasible, compute gamma_min and raise
    SolverError with :class:`Remedy` advice. Minimisation mode: if gamma_min > gamma, raise the
    same advice (the result is kept in ``exc.result``).
    """
    try:
        res = solve_lemma1(model, R, C, opts, Be)
    except SolverError as exc:
        if opts.effective_objective == "min_gamma":
            raise
        log.info(
            "Lemma 1 not solved at gamma %.4g (%s); quantifying the remedies", opts.gamma, exc
        )
        try:
            rem = remedy_analysis(model, R, C, opts, Be)
        except SolverError as exc2:
            raise SolverError(
                f"{exc}; gamma minimisation also failed ({exc2}): the polytope may not be "
                "quadratically stabilisable with a common H (reduce the uncertainty)"
            ) from None
        rem.failure = str(exc).replace("\n", " | ")
        err = SolverError(rem.message())
        err.remedy = rem  # type: ignore[attr-defined]
        raise err from None
    if opts.effective_objective == "min_gamma" and res.gamma_solver > opts.gamma * (1 + 1e-6):
        factor = res.gamma_solver / opts.gamma
        rem = Remedy(opts.gamma, res.gamma_solver, factor, factor)
        err = SolverError(rem.message())
        err.remedy = rem  # type: ignore[attr-defined]
        err.result = res  # type: ignore[attr-defined]
        raise err
    return res
