"""The numpy re-check of the robust LMI (:mod:`lpv_sysid.synthesis.robust`): the
compressed robust block of a vertex evaluated with numpy (:func:`block_numeric`), the
smallest gamma for which a block holds (:func:`block_gamma`) and the certified gamma and
margin of a solution (:func:`box_margins`), independent of the solver's own status."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from lpv_sysid.models.lpv import box_vertices
from lpv_sysid.synthesis.robust.data import ScaledBox, element_maps


def _harmonic(t: np.ndarray, colk: np.ndarray, nc: int) -> np.ndarray:
    """omega_c = 1 / sum_(l in c) 1/t_l (inf for a column without elements at this vertex)."""
    w = np.zeros(nc)
    np.add.at(w, colk, 1.0 / t)
    with np.errstate(divide="ignore"):
        return np.where(w > 0, 1.0 / w, np.inf)


def block_numeric(
    sb: ScaledBox,
    i: int,
    lyapunov: str,
    X: np.ndarray,
    S: np.ndarray,
    H: Optional[np.ndarray],
    t: np.ndarray,
    g: float,
    Z: Optional[np.ndarray] = None,
) -> np.ndarray:
    """The compressed robust block of vertex i (module docstring) in scaled coordinates, numpy.
    Columns of the used set without elements at this vertex get omega = inf (dropped)."""
    n = X.shape[0]
    m = sb.B.shape[1]
    ne, nz = sb.Be.shape[1], sb.C.shape[0]
    Srow, _, colk = element_maps(sb, i)
    nc = len(sb.used)
    om = _harmonic(t, colk, nc)
    keep = np.isfinite(om)
    P = np.zeros((nc, n + m))
    P[np.arange(nc), sb.used] = 1.0
    P, om = P[keep], om[keep]
    DL = np.diag(Srow @ t)
    if lyapunov == "common":
        AX = sb.A[i] @ X + sb.B @ S
        G = P @ np.block(
            [[X, np.zeros((n, ne)), np.zeros((n, nz))], [S, sb.Rs, np.zeros((m, nz))]]
        )
        M = np.block(
            [
                [AX + AX.T + DL, sb.Be, X @ sb.C.T, G[:, :n].T],
                [sb.Be.T, -np.eye(ne), np.zeros((ne, nz)), G[:, n : n + ne].T],
                [sb.C @ X, np.zeros((nz, ne)), -g * np.eye(nz), np.zeros((nz, P.shape[0]))],
                [G[:, :n], G[:, n : n + ne], np.zeros((P.shape[0], nz)), -np.diag(om)],
            ]
        )
        return 0.5 * (M + M.T)
    if H is None:
        raise ValueError(f"block_numeric: the {lyapunov} form needs H")
    U = sb.A[i] @ H + sb.B @ S
    CH = sb.C @ H
    Gx = P @ np.vstack([H, S])
    F = P @ np.vstack([np.zeros((n, ne)), sb.Rs])
    Z = np.zeros((n, n)) if Z is None else Z
    k = P.shape[0]
    M = np.block(
        [
            [U + U.T + DL + Z, -X + H.T - U, sb.Be, CH.T, Gx.T],
            [-X + H - U.T, -(H + H.T), np.zeros((n, ne)), -CH.T, -Gx.T],
            [sb.Be.T, np.zeros((ne, n)), -np.eye(ne), np.zeros((ne, nz)), F.T],
            [CH, -CH, np.zeros((nz, ne)), -g * np.eye(nz), np.zeros((nz, k))],
            [Gx, -Gx, F, np.zeros((k, nz)), -np.diag(om)],
        ]
    )
    return 0.5 * (M + M.T)


def _z_index(lyapunov: str, n: int, ne: int, nz: int) -> np.ndarray:
    start = n + ne if lyapunov == "common" else 2 * n + ne
    return np.arange(start, start + nz)


def block_gamma(M0: np.ndarray, z: np.ndarray) -> float:
    """Smallest gamma with M(g) < 0 for a block whose only g-dependence is -g I on the z rows
    (M0 evaluated at g = 0): Schur complement, g > lambda_max(F (-P)^-1 F^T); inf if P is not <
    0."""
    keep = np.setdiff1d(np.arange(M0.shape[0]), z)
    P = M0[np.ix_(keep, keep)]
    F = M0[np.ix_(z, keep)]
    if np.linalg.eigvalsh(P)[-1] >= 0:
        return float("inf")
    G = F @ np.linalg.solve(-P, F.T)
    G = G + M0[np.ix_(z, z)]
    return float(np.sqrt(max(np.linalg.eigvalsh(0.5 * (G + G.T))[-1], 0.0)))


@dataclass
class BoxSolution:
    """Decision variables in scaled coordinates (``unscaled`` gives the file's)."""

    lyapunov: str
    X: list  # per vertex (common: the same matrix N times)
    S: np.ndarray  # (N, m, n): Y_i (common) or S_i
    H: np.ndarray  # X (common) or H
    t: list  # per vertex multipliers (p_i,)
    W: Optional[list]  # rate: per vertex per axis (n, n)
    g: float
    kappa: float = float("nan")


def box_margins(
    sb: ScaledBox,
    sol: BoxSolution,
    gamma: float,
    pairs: Optional[list] = None,
    rate: Optional[np.ndarray] = None,
) -> tuple[float, float]:
    """(gamma_certified, min_margin) of the compressed robust blocks with numpy: the largest over
    the vertices of the smallest gamma for which the block holds, and the smallest of
    -lambda_max(block at gamma), lambda_min(X_i), min t_l (negative = violated). For ``rate`` the
    W terms are re-derived from X: the block is checked at every sign pattern of dv_d/dt
    (the exact vertex condition the W relaxation implies)."""
    n = sol.H.shape[0]
    ne, nz = sb.Be.shape[1], sb.C.shape[0]
    z = _z_index(sol.lyapunov, n, ne, nz)
    gam, margin = 0.0, float("inf")
    for i in range(len(sb.A)):
        Zs: list[Optional[np.ndarray]] = [None]
        if sol.lyapunov == "rate":
            if pairs is None or rate is None:
                raise ValueError("box_margins: the rate form needs the vertex pairs and the rate")
            Zs = []
            for signs in box_vertices(-np.ones(len(rate)), np.ones(len(rate))):
                Zk = np.zeros((n, n))
                for k, (im, ip, w) in enumerate(pairs[i]):
                    Zk -= signs[k] * rate[k] * (sol.X[ip] - sol.X[im]) / w
                Zs.append(Zk)
        for Z in Zs:
            M0 = block_numeric(sb, i, sol.lyapunov, sol.X[i], sol.S[i], sol.H, sol.t[i], 0.0, Z)
            gam = max(gam, block_gamma(M0, z))
            M = M0.copy()
            M[z, z] -= gamma**2
            margin = min(margin, float(-np.linalg.eigvalsh(M)[-1]))
        margin = min(
            margin,
            float(np.linalg.eigvalsh(0.5 * (sol.X[i] + sol.X[i].T))[0]),
            float(np.min(sol.t[i])) if sol.t[i].size else float("inf"),
        )
    return gam, margin
