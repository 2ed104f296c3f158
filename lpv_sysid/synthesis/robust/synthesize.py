"""Robust H-infinity state feedback over the whole element box (every identified element in its
interval), polynomial in size: the structured-perturbation form of seed 0 Lemma 1.

The uncertain vertex systems are the :class:`lpv_sysid.models.lpv.ElementBox`

    [A_i(delta), B(delta)] = [A_c,i, B_c] + L_i Delta R~_i,   Delta = diag(delta_l), |delta_l| <=
    1,

with L_i = [h_l e_(r_l)]_l (n x p_i) and R~_i = [e_(c_l)^T]_l (p_i x (n + m)). For a fixed
Lyapunov-type matrix the LMI of the frozen closed loop is affine in (A, B), so the uncertain part
enters as He(cal_L Delta cal_R) and is removed with the S-procedure for diagonal (D-scaling)
multipliers T_i = diag(t_l) > 0 (Petersen's lemma with scalings: for every diagonal Delta with
|delta_l| <= 1, He(cal_L Delta cal_R) <= cal_L T cal_L^T + cal_R^T T^-1 cal_R; Petersen 1987,
Syst. Control Lett. 8:351; Khargonekar, Petersen & Zhou 1990, IEEE TAC 35:356; Boyd, El Ghaoui,
Feron & Balakrishnan 1994, *LMIs in System and Control Theory*, Sec. 5.1 and 6.3.2 (the
"scaled small-gain" / diagonal norm-bound LDI)). Three Lyapunov structures (``lyapunov``):

``common``  one X for every scheduling point and every delta: the dual bounded-real LMI with
            Y_i = K_i X (Boyd et al. Sec. 7.5),

                [A_c X + B_c Y_i + (.)^T + L T L^T   B_c R   X C^T    G^T]
                [R^T B_c^T                          -I      0        G_w^T]  < 0,
                [C X                                 0      -g I     0 ]
                [G                                   G_w     0       -T ]

            G = R~ [X; Y_i], G_w = R~ [0; R]. Because X is common, V = x^T X^-1 x is a
            Lyapunov function of every closed loop in the set, so the bound holds for *arbitrarily
            fast* variation of v_d (and of delta): it covers any flown v_d(t). K_i = Y_i X^-1.
``vertex``  seed 0 Eq. (30) (Rotondo Thm. 2, common H, X_i per scheduling vertex) with the same
            S-procedure on U = A H + B S_i and B_e = B R: frozen v_d (the seed's claim).
``rate``    Eq. (30) with X(v_d) = sum_i alpha_i X_i and the term -dX/dt in the (1,1) block
            (the projection of Eq. 30 onto the null space of [A^T, I, 0, C^T] is the dual BRL
            plus that term, i.e. V = x^T X(v_d)^-1 x with dV/dt including d(X^-1)/dt). With the
            multilinear alpha, dX/dt = sum_k (dv_d,k/dt) D_k X and D_k X at vertex i is
            (X_(k+) - X_(k-)) / (v_max,k - v_min,k) (constant along axis k, multilinear in the
            others), so with |dv_d,k/dt| <= rho_k it suffices that at every vertex
            Psi_i + sum_k W_ik < 0 with W_ik >= +-rho_k D_k X (Apkarian & Adams 1998, IEEE TCST
            6:21, for parameter-dependent Lyapunov functions with bounded rates). Covers v_d(t)
            whose rates stay within rho (the design envelope's ``reference_rate``).

The LMIs are affine in (A, B) for fixed decision variables, so they hold at every frozen
v_d = sum alpha_i v_i (Eq. 21) with A = sum alpha_i A_i(delta_i) and B(delta) common, which is
the interior argument of :mod:`lpv_sysid.models.lpv` with the element box in place of corners.

Size. Written with the Schur complement on T the blocks are (2n + n_e + n_z + p_i) square; with
~50 elements per vertex that is ~80 and dominates the solve. Since L T L^T = diag_r(sum t_l h_l^2)
and cal_R^T T^-1 cal_R = G'^T W G' with W = diag_c(sum_(l in column c) 1/t_l), the same condition
is the block [Psi + L T L^T, G'^T P^T; P G', -Omega] < 0 with Omega = diag(omega_c) and
omega_c <= 1 / sum_(l in c) 1/t_l (P selects the columns that carry elements); the harmonic-sum
bound is convex: u_l t_l >= omega_c^2, sum_(l in c) u_l <= omega_c (rotated second-order cones).
Exact (no added conservatism), and the block size no longer grows with p: 2n + n_e + n_z + n_c
(n_c <= n + m). :func:`box_margins` re-evaluates that compressed form with numpy; the verifier
checks the uncompressed one and the scaled small-gain frequency-domain condition independently.

Objective (``objective``): ``feasibility`` (the seed), ``min_gamma``, or ``min_effort``: minimise
kappa with K_i X K_i^T <= kappa I, i.e. [X, Y_i^T; Y_i, kappa I] >= 0 (``common``) or
[H + H^T - X_i, S_i^T; S_i, kappa I] >= 0 (``vertex``/``rate``: H^T X^-1 H >= H + H^T - X);
the input-amplitude bound of Boyd et al. Sec. 7.2.3 -- among the laws certified at gamma the one
with the least control effort, a well-defined answer where a feasibility solver returns an
arbitrary interior point (high-gain laws with ||K|| ~ 1e3 satisfy gamma = 1 just as well).

Parts: the box in scaled coordinates (:mod:`~lpv_sysid.synthesis.robust.data`), the cvxpy
problem (:mod:`~lpv_sysid.synthesis.robust.problem`), the numpy re-check
(:mod:`~lpv_sysid.synthesis.robust.check`); this module solves (:func:`solve_box`).
"""

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
) -> dict:
    """Solve the robust LMI of the module docstring. With ``K_fixed`` (N, m, n) the gains are
    given and only the Lyapunov matrices, multipliers and gamma are sought (analysis: S_i = K_i X
    or K_i H; the smallest gamma the element-box certificate can prove for that law with
    ``objective: min_gamma``). Returns a dict with the unscaled gains ``K``
    (N, m, n), ``X`` (per vertex), ``S``, ``H``, multipliers ``t`` (per vertex, unscaled:
    t_l = t~_l tau_c^2), ``W`` (rate), ``gamma_solver``, ``gamma_certified``, ``min_margin``,
    ``scaling``, ``size``, ``status``, ``solver``, times. SolverError when no solver returns a
    solution that passes the numpy re-check (:func:`box_margins`)."""
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
    errors = []
    for sv in order:
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
