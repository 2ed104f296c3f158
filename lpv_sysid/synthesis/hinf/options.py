"""What goes into and comes out of the Lemma 1 synthesis (:mod:`lpv_sysid.synthesis.hinf`).

:class:`HinfOptions` are the keys of ``config/synthesis.yaml: hinf`` (checked by
:meth:`HinfOptions.from_dict`), :class:`ProblemSize` counts what one solve states and
:class:`HinfResult` is its solution (K_i = S_i H^-1, seed 0 Eq. 31) in unscaled coordinates with
the numpy re-check of Eq. (30).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Optional, Sequence, Union

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.synthesis.regions import Region
from lpv_sysid.synthesis.scaling import Scaling

SOLVERS = ("CLARABEL", "SCS", "MOSEK", "AUTO")


@dataclass(frozen=True)
class HinfOptions:
    """Options of the Lemma 1 synthesis (keys of ``config/synthesis.yaml: hinf``)."""

    gamma: float = cf.number(
        1.0,
        "requested bound on ||u_e -> z||_inf (Eq. 29); 1e-6 .. 1e6: a bound of 0 or one "
        "that rounds to it has no feasible LMI (the solver runs on), inf/nan are no bound",
        lo=1e-6,
        hi=1e6,
    )
    minimize_gamma: bool = cf.flag(
        False, "true: minimise gamma^2 as a variable; false: feasibility at gamma"
    )
    eps: float = cf.number(
        1e-6, "strictness margin: LMI <= -eps I, X >= eps I (scaled coordinates)", lo=0.0
    )
    solver: str = cf.choice(
        "CLARABEL",
        SOLVERS,
        "CLARABEL | SCS | MOSEK | AUTO (MOSEK if installed, else by size); any case",
        fold_case=True,
    )
    fallback: Optional[str] = cf.choice(
        "SCS",
        SOLVERS,
        "tried when the first solver errors out (not when infeasible); null: none",
        fold_case=True,
        optional=True,
    )
    scale: bool = cf.flag(True, "diagonal similarity scaling (synthesis.scaling)")
    remedy_bisection_steps: int = cf.count(
        0,
        ">0: quantify the uncertainty-reduction remedy by bisection; at most 30 (one LMI "
        "solve each, 2^-30 is below any solver's tolerance)",
        hi=30,
    )
    #: optional LMI region for the closed-loop poles (common-H, see lemma1_cvxpy)
    region: Optional[Region] = None
    verbose: bool = cf.flag(False, "solver output")
    method: str = cf.choice(
        "auto",
        ("auto", "corners", "box"),
        "corners: Eq. (30) at every Eq. (23) system (the seed); box: the structured-"
        "perturbation LMI of synthesis.robust over the element box; auto: box when the model "
        "is the full element box, else corners",
    )
    lyapunov: str = cf.choice(
        "vertex",
        ("vertex", "common", "rate"),
        "vertex: X_i per vertex, frozen v_d (Lemma 1); common: one X, any rate of v_d; rate: "
        "X(v_d) with |dv_d/dt| <= rate_bound (box only)",
    )
    objective: Optional[str] = cf.choice(
        None,
        ("feasibility", "min_gamma", "min_effort"),
        "null: min_gamma when minimize_gamma, else feasibility",
        optional=True,
    )
    rate_bound: Union[None, str, Sequence[float]] = cf.numbers(
        None,
        "rate mode: design (certificate.design.reference_rate of the phase-2 signal) or "
        "per-axis bounds [m/s^2] >= 0",
        lo=0.0,
        choices=("design",),
        optional=True,
    )
    design_gamma_fraction: float = cf.number(
        1.0,
        "the LMI is solved at gamma x this, in (0, 1]; min_effort otherwise uses the whole bound",
        lo=0.0,
        lo_open=True,
        hi=1.0,
    )

    @classmethod
    def from_dict(cls, d: Optional[dict], where: str = "hinf") -> "HinfOptions":
        """The keys of ``d`` (a ``region`` given as a :class:`Region` is kept); solver names
        in upper case; the objective agrees with minimize_gamma, rate mode has a bound."""
        d = d or {}
        kw = cf.parse_fields(cls, d, where, other_keys=("region",))
        region = d.get("region")
        if region is not None and not isinstance(region, Region):
            region = Region.from_dict(region, cf.join(where, "region"))
        opts = cls(region=region, **kw)
        if opts.objective is not None and opts.minimize_gamma and opts.objective != "min_gamma":
            raise cf.error(
                where,
                "minimize_gamma",
                f"true contradicts objective {opts.objective!r} (use objective: min_gamma)",
            )
        if opts.lyapunov == "rate" and opts.rate_bound is None:
            raise cf.error(
                where,
                "lyapunov",
                "rate needs hinf.rate_bound ('design' or per-axis bounds in m/s^2)",
            )
        return replace(
            opts,
            solver=opts.solver.upper(),
            fallback=None if opts.fallback is None else opts.fallback.upper(),
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
