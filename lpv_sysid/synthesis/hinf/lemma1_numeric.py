"""Seed 0 Lemma 1 in numpy, without a solver.

The weights (C of Eq. 19b, R of Eq. 27, Q of Eq. 28, B_e^j = B_c^j R of Eq. 19), the left-hand
side of Eq. (30) (stated in :mod:`lpv_sysid.synthesis.hinf`) and the smallest gamma it
allows, the independent re-check of a solution at every Eq. (23) system
(:func:`certificate_margins`: the solver's word is not the certificate) and the problem sizes of
the seed's formulation (:func:`seed_problem_size`).
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.lpv import PolytopicModel
from lpv_sysid.synthesis.scaling import Scaling


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


# --------------------------------------------------------------------------- Eq. (30)
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


# --------------------------------------------------------------------------- the re-check
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
