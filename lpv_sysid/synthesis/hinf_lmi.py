"""Robust polytopic H-infinity state feedback: seed 0 Lemma 1, Eqs. (29)-(31).

For every scheduling vertex i and uncertainty vertex j (Eq. 23) find X_i^j = X_i^j^T > 0,
S_i and one common (general square) H with

    [ U + U^T          -X + H^T - U    B_e^j   H^T C^T ]
    [ -X + H - U^T     -(H + H^T)      0       -H^T C^T]
    [ B_e^j^T          0               -I      0       ]   < 0,     U = A_i^j H + B_c^j S_i   (30)
    [ C H              -C H            0       -g I    ]

with g = gamma^2; then K_i = S_i H^-1 (Eq. 31) gives ||u_e -> z||_inf < gamma for all v_d in the
box and all theta in the uncertainty box -- provided B_c^j is common to all scheduling vertices
(``model.common_input``, the product polytope of :mod:`lpv_sysid.models.lpv`, whose docstring
gives the interior argument); with per-vertex B_i^j only the vertices are certified. (Eq. 30 is
Phi0 + He([A;I;0;C] H [I,-I,0,0]) with the
dual bounded-real-lemma matrix Phi0; eliminating H recovers A X + X A^T + B_e B_e^T + X C^T C X /
g < 0.)

Strictness: every LMI is imposed as ``<= -eps I`` and ``X >= eps I`` (in the scaled coordinates of
:mod:`lpv_sysid.synthesis.scaling`). Options: fixed gamma (feasibility) or minimise g = gamma^2;
``lyapunov: common`` ties every X_i^j to one X (the bound then holds for arbitrarily fast v_d).

``method: box`` (:func:`resolve_method`) hands the problem to
:mod:`lpv_sysid.synthesis.robust_lmi`:
the full element box of a ``full_box`` model, or a corner polytope recognised as the corners of a
box (:func:`lpv_sysid.models.lpv.corner_box`), one robust block per vertex with X_i^j = X_i; for a
corner polytope the solution is then re-checked on Eq. (30) itself at every corner system
(:func:`certificate_margins`, batched), so the seed's LMIs are what is certified however many
systems there are -- the seed-size problem (sum M_i = 580, :func:`seed_problem_size`) in seconds.

If the problem is infeasible at the requested gamma, the remedies of seed 0 Sec. VI are quantified.
Scaling R by c (B_e -> c B_e, Eq. 27) maps a solution (X, S, H) at gamma to c^2 (X, S, H) at
c gamma: the new Eq. (30) matrix is the congruence diag(cI, cI, I, cI) of the old one, and K = S
H^-1
is unchanged. The same holds for Q -> Q / c (C -> c C, Eq. 28) with (X, S, H) kept and the
congruence
diag(I, I, I, I/c). So the LMI feasible set is exactly
{gamma >= c gamma_min}: the factor by which the excitation magnitudes Delta_t..Delta_r must shrink
(or Delta_u..Delta_w grow) is gamma_min / gamma_req, read off one gamma minimisation; a bisection
on c would return the same number. Reducing the model uncertainty (remedy 3) is not homogeneous and
is quantified by bisection on the shrink factor rho of the uncertainty vertices about the nominal
(A_i^j -> A_i + rho (A_i^j - A_i)).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import Any, Optional, Sequence, Union

import numpy as np

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.models.lpv import PolytopicModel
from lpv_sysid.synthesis.regions import Region, region_lmi
from lpv_sysid.synthesis.scaling import Scaling, choose_scaling

log = logging.getLogger(__name__)

SOLVERS = ("CLARABEL", "SCS", "MOSEK", "AUTO")
#: AUTO: Clarabel up to this many Eq. (30) blocks, SCS above (measured crossover, see
#: bench/results/synthesis.md: Clarabel 2.9 s / 18 s / 117 s for 8 / 16 / 32 blocks, SCS < 1.5 s).
AUTO_CLARABEL_MAX_BLOCKS = 8


@dataclass(frozen=True)
class HinfOptions:
    """Options of the Lemma 1 synthesis (keys of ``config/synthesis.yaml: hinf``)."""

    gamma: float = 1.0  # requested bound (Eq. 29)
    minimize_gamma: bool = (
        False  # True: minimise gamma^2 as a variable; False: feasibility at gamma
    )
    eps: float = 1e-6  # strictness margin: LMI <= -eps I, X >= eps I (scaled coords)
    solver: str = (
        "CLARABEL"  # CLARABEL (default) | SCS | MOSEK | AUTO (MOSEK if installed, else by size)
    )
    fallback: Optional[str] = "SCS"  # tried when the first solver errors out (not when infeasible)
    scale: bool = True  # diagonal similarity scaling (synthesis.scaling)
    remedy_bisection_steps: int = 0  # >0: quantify uncertainty-reduction remedy by bisection
    region: Optional[Region] = (
        None  # optional LMI region for the closed-loop poles (common-H, see _build)
    )
    verbose: bool = False
    #: "corners": Eq. (30) at every Eq. (23) system (the seed); "box": the structured-perturbation
    #: LMI of synthesis.robust_lmi over the element box (one block per vertex); "auto": box when
    #: the
    #: model is the full element box, else corners
    method: str = "auto"
    #: "vertex": X_i (box) / X_i^j (corners) per vertex, frozen v_d (the seed's Lemma 1);
    #: "common": one X, any rate of v_d; "rate": X(v_d) with |dv_d/dt| <= rate_bound (box only)
    lyapunov: str = "vertex"
    #: "feasibility" | "min_gamma" | "min_effort" (None: min_gamma when minimize_gamma, else
    #: feasibility)
    objective: Optional[str] = None
    #: rate mode: "design" (certificate.design.reference_rate of the phase-2 signal) or per-axis
    #: bounds
    rate_bound: Union[None, str, Sequence[float]] = None
    #: the LMI is solved at gamma x this (<= 1); min_effort otherwise uses the whole bound
    design_gamma_fraction: float = 1.0

    @classmethod
    def from_dict(cls, d: Optional[dict]) -> "HinfOptions":
        d = dict(d or {})
        known = set(cls.__dataclass_fields__)
        bad = set(d) - known
        if bad:
            raise ConfigError(f"hinf: unknown key(s) {sorted(bad)}; known: {sorted(known)}")
        if "region" in d and not isinstance(d["region"], Region):
            d["region"] = Region.from_dict(d["region"])
        opts = cls(**d)
        if not (
            isinstance(opts.gamma, (int, float)) and np.isfinite(opts.gamma) and opts.gamma > 0
        ):
            raise ConfigError(f"hinf.gamma must be a finite number > 0, got {opts.gamma!r}")
        if not (opts.eps >= 0 and np.isfinite(opts.eps)):
            raise ConfigError(f"hinf.eps must be >= 0, got {opts.eps!r}")
        if str(opts.solver).upper() not in SOLVERS:
            raise ConfigError(f"hinf.solver must be one of {SOLVERS}, got {opts.solver!r}")
        if opts.fallback is not None and str(opts.fallback).upper() not in SOLVERS:
            raise ConfigError(
                f"hinf.fallback must be one of {SOLVERS} or null, got {opts.fallback!r}"
            )
        if opts.method not in ("auto", "corners", "box"):
            raise ConfigError(f"hinf.method must be auto, corners or box, got {opts.method!r}")
        if opts.lyapunov not in ("vertex", "common", "rate"):
            raise ConfigError(
                f"hinf.lyapunov must be vertex, common or rate, got {opts.lyapunov!r}"
            )
        if opts.objective is not None and opts.objective not in (
            "feasibility",
            "min_gamma",
            "min_effort",
        ):
            raise ConfigError(
                "hinf.objective must be feasibility, min_gamma or min_effort, got "
                f"{opts.objective!r}"
            )
        if opts.objective is not None and opts.minimize_gamma and opts.objective != "min_gamma":
            raise ConfigError(
                "hinf: minimize_gamma: true contradicts objective "
                f"{opts.objective!r} (use objective: min_gamma)"
            )
        f = opts.design_gamma_fraction
        if isinstance(f, bool) or not isinstance(f, (int, float)) or not (0 < f <= 1):
            raise ConfigError(f"hinf.design_gamma_fraction must be in (0, 1], got {f!r}")
        rb = opts.rate_bound
        if rb is not None and rb != "design":
            try:
                rb = [float(x) for x in rb]
            except (TypeError, ValueError):
                raise ConfigError(
                    f"hinf.rate_bound must be 'design' or a list of numbers, got {rb!r}"
                ) from None
            if not all(np.isfinite(x) and x >= 0 for x in rb):
                raise ConfigError(f"hinf.rate_bound entries must be finite and >= 0, got {rb}")
        if opts.lyapunov == "rate" and rb is None:
            raise ConfigError(
                "hinf.lyapunov: rate needs hinf.rate_bound ('design' or per-axis bounds in m/s^2)"
            )
        return replace(
            opts,
            solver=str(opts.solver).upper(),
            rate_bound=rb,
            fallback=None if opts.fallback is None else str(opts.fallback).upper(),
        )

    @property
    def effective_objective(self) -> str:
        if self.objective is not None:
            return self.objective
        return "min_gamma" if self.minimize_gamma else "feasibility"


@dataclass
class ProblemSize:
    scalar_variables: int  # free scalars (symmetric matrices counted n(n+1)/2)
    lmi_blocks: int  # number of matrix inequalities (Eq. 30 blocks + X > 0)
    lmi_total_dim: int  # sum of the dimensions of those blocks
    scalar_constraints: int  # sum of d(d+1)/2 over the blocks
    eq30_block_dim: int  # dimension of one Eq. (30) block (2n + n_e + n_z)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class HinfResult:
    """Solution of Lemma 1 in unscaled coordinates (K_i = S_i H^-1)."""

    K: np.ndarray  # (N, m, n)
    X: list  # X[i][j] (n, n)
    S: np.ndarray  # (N, m, n)
    H: np.ndarray  # (n, n)
    gamma_requested: float
    gamma_solver: float  # gamma used (requested) or minimised by the solver
    status: str
    solver: str
    size: ProblemSize
    compile_time: float
    solve_time: float
    scaling: Scaling
    eps: float
    gamma_certified: float = float("nan")  # numpy re-evaluation of Eq. (30), see lmi_check
    min_margin: float = float("nan")
    info: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- problem data
def performance_matrix(Q: np.ndarray, n_x: int, velocity_index: Sequence[int]) -> np.ndarray:
    """C of seed 0 Eq. (19b): z = Q^-1 (v - v_d) = C dx (Eq. 18)."""
    Q = np.asarray(Q, dtype=float)
    if Q.shape != (len(velocity_index), len(velocity_index)):
        raise ConfigError(f"Q must be {len(velocity_index)}x{len(velocity_index)}, got {Q.shape}")
    Sel = np.zeros((len(velocity_index), n_x))
    Sel[np.arange(len(velocity_index)), list(velocity_index)] = 1.0
    return np.linalg.solve(Q, Sel)


def excitation_R(deltas: Sequence[float], T: float) -> np.ndarray:
    """R = sqrt(n_u T / 2) diag(Delta_t, Delta_a, Delta_e, Delta_r), seed 0 Eq. (27)."""
    d = np.asarray(deltas, dtype=float)
    if d.ndim != 1 or not np.all(np.isfinite(d)) or np.any(d <= 0) or not (T > 0):
        raise ConfigError(
            f"R: need positive input magnitudes and T > 0, got {d.tolist()}, T={T!r}"
        )
    return np.sqrt(d.size * T / 2.0) * np.diag(d)


def output_Q(deltas: Sequence[float], T: float) -> np.ndarray:
    """Q = sqrt(n_z T) diag(Delta_u, Delta_v, Delta_w), seed 0 Eq. (28)."""
    d = np.asarray(deltas, dtype=float)
    if d.ndim != 1 or not np.all(np.isfinite(d)) or np.any(d <= 0) or not (T > 0):
        raise ConfigError(
            f"Q: need positive output magnitudes and T > 0, got {d.tolist()}, T={T!r}"
        )
    return np.sqrt(d.size * T) * np.diag(d)


# --------------------------------------------------------------------------- the LMI
def eq30_matrix(
    A: np.ndarray,
    Bc: np.ndarray,
    Be: np.ndarray,
    C: np.ndarray,
    X: np.ndarray,
    S: np.ndarray,
    H: np.ndarray,
    g: float,
) -> np.ndarray:
    """Numeric left-hand side of seed 0 Eq. (30) (numpy; used by the independent check)."""
    n = A.shape[0]
    ne, nz = Be.shape[1], C.shape[0]
    U = A @ H + Bc @ S
    CH = C @ H
    return np.block(
        [
            [U + U.T, -X + H.T - U, Be, CH.T],
            [-X + H - U.T, -(H + H.T), np.zeros((n, ne)), -CH.T],
            [Be.T, np.zeros((ne, n)), -np.eye(ne), np.zeros((ne, nz))],
            [CH, -CH, np.zeros((nz, ne)), -g * np.eye(nz)],
        ]
    )


def lmi_gamma(A, Bc, Be, C, X, S, H) -> float:
    """Smallest gamma for which Eq. (30) holds with the given (X, S, H); inf if none.

    With M = [[P, F^T], [F, -g I]] (F = last block row without its diagonal), M < 0 iff P < 0 and
    g > lambda_max(F (-P)^-1 F^T) (Schur complement). Pure numpy.
    """
    M = eq30_matrix(A, Bc, Be, C, X, S, H, 0.0)
    nz = C.shape[0]
    P = M[:-nz, :-nz]
    F = M[-nz:, :-nz]
    Ps = 0.5 * (P + P.T)
    lam = np.linalg.eigvalsh(Ps)
    if lam[-1] >= 0:
        return float("inf")
    W = np.linalg.solve(-Ps, F.T)
    G = F @ W
    return float(np.sqrt(max(np.max(np.linalg.eigvalsh(0.5 * (G + G.T))), 0.0)))


def excitation_matrix(
    Bj: np.ndarray, R: np.ndarray, Be: Optional[np.ndarray] = None
) -> np.ndarray:
    """B_e^j = B_c^j R (seed 0 Eq. 19) unless an explicit (unmatched) B_e is given."""
    return np.asarray(Be, dtype=float) if Be is not None else np.asarray(Bj, dtype=float) @ R


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


def _build(
    model: PolytopicModel,
    R: np.ndarray,
    C: np.ndarray,
    opts: HinfOptions,
    scaling: Scaling,
    Be: Optional[np.ndarray] = None,
):
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
        return _solve_box(model, R, C, opts, Be)
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
    prob, H, S, Xs, g, size, systems, Cs = _build(model, R, C, opts, scaling, Be)
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
            res = _extract(model, R, C, opts, Be, prob, H, S, Xs, g, size, scaling, sv)
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


def resolve_method(model: PolytopicModel, opts: HinfOptions) -> str:
    """``box`` for the full element box (``model.box``) or, with ``method: box``, for a corner
    polytope that is the set of corners of an element box
    (:func:`lpv_sysid.models.lpv.corner_box`);
    ``corners`` otherwise (Eq. 30 at every system, the seed's formulation)."""
    if opts.method == "corners":
        if model.box is not None:
            raise ConfigError(
                "hinf.method: corners cannot enumerate the full element box (2^p corners); "
                "use method: box (or uncertainty.set: reduced_polytope)"
            )
        return "corners"
    if model.box is not None:
        return "box"
    if opts.method == "box":
        return "box"
    return "corners"


def _solve_box(
    model: PolytopicModel,
    R: np.ndarray,
    C: np.ndarray,
    opts: HinfOptions,
    Be: Optional[np.ndarray],
) -> HinfResult:
    """The element-box LMI (synthesis.robust_lmi) as a :class:`HinfResult`. For a corner polytope
    (``model.box`` None) the box is recovered from the corners and, with ``lyapunov: vertex``, the
    solution X_i^j = X_i, S_i, H is re-checked on Eq. (30) at every corner system: the seed's LMIs
    themselves, however many there are."""
    from lpv_sysid.models.lpv import corner_box
    from lpv_sysid.synthesis import robust_lmi

    if Be is not None:
        raise ConfigError(
            "hinf.method: box needs the matched excitation B_e = B R (seed 0 Eq. 19)"
        )
    if opts.region is not None:
        raise ConfigError(
            "hinf.region is not offered with the element-box LMI (hinf.method: corners)"
        )
    box = model.box if model.box is not None else corner_box(model)
    if box is None:
        raise ConfigError(
            "hinf.method: box: the Eq. (23) systems are not the corners of a box of single "
            "elements with a B part common to all vertices (use method: corners)"
        )
    rate = None
    if opts.lyapunov == "rate":
        rb = opts.rate_bound
        if rb is None or isinstance(rb, str):
            raise ConfigError(
                "hinf.rate_bound: design needs the phase-2 design envelope (reference_rate of a "
                "signals summary)"
                if rb == "design"
                else "hinf.lyapunov: rate needs hinf.rate_bound (per-axis bounds or design)"
            )
        rate = [float(x) for x in rb]
    obj = opts.effective_objective
    g_req = float(opts.gamma) * float(opts.design_gamma_fraction)
    r = robust_lmi.solve_box(
        box,
        R,
        C,
        gamma=g_req,
        lyapunov=opts.lyapunov,
        objective=obj,
        eps=opts.eps,
        solver="CLARABEL" if opts.solver == "AUTO" else opts.solver,
        fallback=opts.fallback if opts.solver != "AUTO" else "SCS",
        scale=opts.scale,
        vmin=model.vmin,
        vmax=model.vmax,
        rate=rate,
        verbose=opts.verbose,
    )
    Ms = [len(lst) for lst in model.systems]
    X = [[r["X"][i]] * (Ms[i] if model.box is None else 1) for i in range(model.n_vertices)]
    sz = r["size"]
    size = ProblemSize(
        scalar_variables=int(sz["scalar_variables"]),
        lmi_blocks=int(sz["lmi_blocks"]),
        lmi_total_dim=int(sum(sz["robust_block_dim"])),
        scalar_constraints=int(sz["scalar_constraints"]),
        eq30_block_dim=int(max(sz["robust_block_dim"])),
    )
    res = HinfResult(
        K=r["K"],
        X=X,
        S=r["S"],
        H=r["H"],
        gamma_requested=float(opts.gamma),
        gamma_solver=r["gamma_solver"],
        status=r["status"],
        solver=r["solver"],
        size=size,
        compile_time=r["compile_time"],
        solve_time=r["solve_time"],
        scaling=r["scaling"],
        eps=opts.eps,
        gamma_certified=r["gamma_certified"],
        min_margin=r["min_margin"],
        info={"method": "box", "box": box, "robust": r, "size": sz},
    )
    if model.box is None and opts.lyapunov == "vertex":
        log.info("re-checking seed 0 Eq. (30) with numpy at the %d corner systems", sum(Ms))
        t0 = time.perf_counter()
        g30, m30 = certificate_margins(
            model,
            R,
            C,
            X,
            r["S"],
            r["H"],
            r["scaling"],
            gamma=float(opts.gamma) if obj != "min_gamma" else r["gamma_solver"],
        )
        res.info["eq30"] = {
            "gamma": g30,
            "margin": m30,
            "systems": int(sum(Ms)),
            "check_s": time.perf_counter() - t0,
        }
        res.gamma_certified, res.min_margin = g30, m30
        if not (m30 > 0 or (obj == "min_gamma" and np.isfinite(g30))):
            raise SolverError(
                f"element-box solution fails the Eq. (30) re-check at the {sum(Ms)} corner "
                "systems "
                f"(margin {m30:.3g})"
            )
    return res


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


def _extract(model, R, C, opts, Be, prob, H, S, Xs, g, size, scaling, used) -> HinfResult:
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


def certificate_margins(
    model: PolytopicModel,
    R: np.ndarray,
    C: np.ndarray,
    X: list,
    S: np.ndarray,
    H: np.ndarray,
    scaling: Optional[Scaling] = None,
    gamma: float = 1.0,
    Be: Optional[np.ndarray] = None,
) -> tuple[float, float]:
    """Re-evaluate Eq. (30) with numpy from (X, S, H) in unscaled coordinates.

    The matrices are first mapped through the congruence diag(T^-1, T^-1, I, I) of ``scaling``
    (inertia-preserving, so this is a preconditioner, not trust in the solver). Returns
    (gamma_certified, min_margin): the largest over all (i, j) of the smallest gamma for which
    the LMI holds (the Schur complement of :func:`lmi_gamma`) and min over (i, j) of
    min(-lambda_max(Eq. 30 at gamma), lambda_min(X_i^j)) (negative = violated). The blocks of a
    vertex are evaluated as one stacked batch (the seed-size problem has 580 of them).
    """
    n, m = model.n_x, model.n_u
    sc = scaling or Scaling.identity(n, m)
    Hs = H / (sc.t[:, None] * sc.t[None, :])
    Cs = sc.C(C)
    nz = Cs.shape[0]
    gam = 0.0
    margin = float("inf")
    for i, lst in enumerate(model.systems):
        Ss = S[i] / (sc.s_u[:, None] * sc.t[None, :])
        Xs = np.array([X[i][j] for j in range(len(lst))]) / (sc.t[:, None] * sc.t[None, :])
        Ms = []
        for j, (Aj, Bj) in enumerate(lst):
            A_, Bc_ = sc.A(np.asarray(Aj)), sc.Bc(np.asarray(Bj))
            Be_ = sc.Be(excitation_matrix(Bj, R, Be))
            Ms.append(eq30_matrix(A_, Bc_, Be_, Cs, Xs[j], Ss, Hs, 0.0))
        M = np.array(Ms)
        M = 0.5 * (M + np.swapaxes(M, 1, 2))
        P, F = M[:, :-nz, :-nz], M[:, -nz:, :-nz]
        lamP = np.linalg.eigvalsh(P)[:, -1]
        ok = lamP < 0
        if not np.all(ok):
            gam = float("inf")
        if np.any(ok):
            W = np.linalg.solve(-P[ok], np.swapaxes(F[ok], 1, 2))
            G = F[ok] @ W
            gam = max(
                gam,
                float(
                    np.sqrt(max(np.max(np.linalg.eigvalsh(0.5 * (G + np.swapaxes(G, 1, 2)))), 0.0))
                ),
            )
        Mg = M.copy()
        Mg[:, -nz:, -nz:] -= gamma**2 * np.eye(nz)
        lam_M = np.linalg.eigvalsh(Mg)[:, -1]
        lam_X = np.linalg.eigvalsh(0.5 * (Xs + np.swapaxes(Xs, 1, 2)))[:, 0]
        margin = min(margin, float(np.min(-lam_M)), float(np.min(lam_X)))
    return gam, margin


def seed_problem_size(
    M: Sequence[int], n: int, m: int, n_e: int, n_z: int, tied: bool = False
) -> dict:
    """Sizes of seed 0 Lemma 1 for uncertainty-vertex counts M_i, counted two ways.

    The package (primal, what cvxpy states): scalar variables sum_i M_i n(n+1)/2 (X_i^j) + N m n
    (S_i) + n^2 (H); PSD cones: one Eq. (30) block (2n + n_e + n_z) and one X > 0 block (n) per
    system; cone entries sum d(d+1)/2. CVX hands the *dual* problem to its solver and reports it
    (seed 0 Sec. VI: "332,920 variables with 45,768 constraints"): its variables are the cone
    entries and its equality constraints the primal variables. For N = 8, sum M_i = 580, n = 12,
    n_e = 4, n_z = 3 this gives 45,768 primal variables and 332,920 cone entries, the seed's two
    numbers swapped. ``tied``: X_i^j = X_i (what the element-box solve of the seed-size problem
    returns) -- the variables of the problem as posed are still counted."""
    N = len(M)
    d = 2 * n + n_e + n_z
    total = int(sum(M))
    variables = total * n * (n + 1) // 2 + N * m * n + n * n
    entries = total * (d * (d + 1) // 2 + n * (n + 1) // 2)
    return {
        "N": N,
        "sum_M": total,
        "M": [int(x) for x in M],
        "eq30_block_dim": d,
        "psd_cones": 2 * total,
        "package": {"scalar_variables": variables, "cone_entries": entries},
        "as_cvx_reports": {"variables": entries, "constraints": variables},
        "X_tied_per_vertex": bool(tied),
    }


# --------------------------------------------------------------------------- remedies
@dataclass
class Remedy:
    gamma_requested: float
    gamma_min: float
    excitation_shrink: float  # divide Delta_t..Delta_r (R) by this factor
    output_grow: float  # multiply Delta_u..Delta_w (Q) by this factor
    uncertainty_shrink: Optional[float] = None  # largest rho in [0,1] found feasible (bisection)
    nominal_gamma_min: Optional[float] = None

    def message(self) -> str:
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
