"""``hinf.method: box``: the bound of seed 0 Lemma 1 through the element-box LMI.

:func:`resolve_method` decides, :func:`solve_box` hands the problem to
:mod:`lpv_sysid.synthesis.robust`:
the full element box of a ``full_box`` model, or a corner polytope recognised as the corners of a
box (:func:`lpv_sysid.models.lpv.corner_box`), one robust block per vertex with X_i^j = X_i; for a
corner polytope the solution is then re-checked on Eq. (30) itself at every corner system
(:func:`lpv_sysid.synthesis.hinf.lemma1_numeric.certificate_margins`, batched), so the seed's LMIs
are what is certified however many systems there are -- the seed-size problem (sum M_i = 580,
:func:`lpv_sysid.synthesis.hinf.lemma1_numeric.seed_problem_size`) in seconds.
"""

from __future__ import annotations

import logging
import time
from typing import Optional

import numpy as np

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.models.lpv import PolytopicModel
from lpv_sysid.synthesis.hinf.lemma1_numeric import certificate_margins
from lpv_sysid.synthesis.hinf.options import HinfOptions, HinfResult, ProblemSize

log = logging.getLogger(__name__)


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


def solve_box(
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
    from lpv_sysid.synthesis import robust as robust_lmi

    if Be is not None:
        raise ConfigError(
            "hinf.method: box needs the matched excitation B_e = B R (seed 0 Eq. 19)"
        )
    if opts.region is not None:
        raise ConfigError(
            "hinf.region is not offered with the element-box LMI (hinf.method: corners)"
        )
    box = model.box if model.box is not None else corner_box(model.systems)
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
        gamma_accept=float(opts.gamma),
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
