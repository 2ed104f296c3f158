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

from lpv_sysid.errors import ConfigError
from lpv_sysid.synthesis.regions import Region
from lpv_sysid.synthesis.scaling import Scaling

SOLVERS = ("CLARABEL", "SCS", "MOSEK", "AUTO")


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
        None  # optional LMI region for the closed-loop poles (common-H, see lemma1_cvxpy)
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
