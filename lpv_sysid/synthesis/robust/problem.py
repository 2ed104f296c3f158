"""The robust LMI over the element box as a cvxpy problem, not yet solved (the derivation:
:mod:`lpv_sysid.synthesis.robust`, which solves it): the decision variables, per vertex
the compressed robust block with its rotated second-order cones, the ``rate`` terms and the
``min_effort`` bound, and the size of the problem."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.lpv import ElementBox
from lpv_sysid.synthesis.robust.data import (
    ScaledBox,
    box_scaling,
    element_maps,
    rate_vertex_pairs,
    scale_box,
)
from lpv_sysid.synthesis.scaling import Scaling

log = logging.getLogger(__name__)

LYAPUNOV = ("common", "vertex", "rate")
OBJECTIVES = ("feasibility", "min_gamma", "min_effort")


@dataclass
class BoxProblem:
    """The problem of :func:`build_box_problem` and what reading its solution needs (cvxpy
    objects are untyped: ``Any``)."""

    prob: Any  # cvxpy.Problem
    g: Any  # gamma^2: a variable (min_gamma) or the given float
    kappa: Any  # effort bound: a variable (min_effort) or None
    H: Any  # X (common) or H
    Xs: list  # per vertex (common: the same variable N times)
    S: list  # per vertex Y_i (common) or S_i (variables, or expressions with K_fixed)
    T: list  # per vertex multipliers t_i
    W: list  # rate: per vertex per axis
    scaling: Scaling
    sb: ScaledBox
    pairs: list  # rate: per vertex the (minus, plus, width) neighbours per axis
    rho: np.ndarray  # rate: the per-axis rate bound
    sizes: dict
    build_s: float


def build_box_problem(
    box: ElementBox,
    R: np.ndarray,
    C: np.ndarray,
    *,
    gamma: float,
    lyapunov: str,
    objective: str,
    eps: float,
    scale: bool,
    vmin,
    vmax,
    rate: Optional[Sequence[float]],
    K_fixed: Optional[np.ndarray],
) -> BoxProblem:
    """The robust LMI of :func:`lpv_sysid.synthesis.robust.solve_box` (same arguments) as
    a cvxpy problem; ConfigError for arguments that do not fit."""
    import cvxpy as cp

    if lyapunov not in LYAPUNOV:
        raise ConfigError(f"hinf.lyapunov must be one of {LYAPUNOV}, got {lyapunov!r}")
    if objective not in OBJECTIVES:
        raise ConfigError(f"hinf.objective must be one of {OBJECTIVES}, got {objective!r}")
    R = np.asarray(R, dtype=float)
    C = np.asarray(C, dtype=float)
    N, n, m = box.N, box.n, box.m
    pairs: list = []  # rate form: per vertex the (minus, plus, width) neighbours per axis
    rho = np.zeros(0)  # rate form: the per-axis rate bound
    if lyapunov == "rate":
        if rate is None or vmin is None or vmax is None:
            raise ConfigError(
                "hinf.lyapunov: rate needs the scheduling box and a rate bound (hinf.rate_bound)"
            )
        rho = np.asarray(rate, dtype=float)
        if rho.shape != (np.size(vmin),) or not np.all(np.isfinite(rho)) or np.any(rho < 0):
            raise ConfigError(
                f"rate bound must be {np.size(vmin)} finite numbers >= 0, got {rho.tolist()}"
            )
        pairs = rate_vertex_pairs(np.asarray(vmin, float), np.asarray(vmax, float))
    scaling = box_scaling(box, R, C) if scale else Scaling.identity(n, m)
    sb = scale_box(box, R, C, scaling)
    ne, nz = R.shape[1], C.shape[0]
    nc = len(sb.used)
    Pm = np.zeros((nc, n + m))
    Pm[np.arange(nc), sb.used] = 1.0
    log.info(
        "robust LMI over the element box: building (%d vertices, %d states, %d inputs, "
        "elements per vertex %s, %s Lyapunov matrix, objective %s)",
        N,
        n,
        m,
        box.p,
        lyapunov,
        objective,
    )
    t0 = time.perf_counter()
    g = cp.Variable(nonneg=True, name="gamma2") if objective == "min_gamma" else float(gamma) ** 2
    kappa = cp.Variable(nonneg=True, name="kappa") if objective == "min_effort" else None
    cons = []
    if lyapunov == "common":
        X0 = cp.Variable((n, n), symmetric=True, name="X")
        Xs = [X0] * N
        H = X0
        cons.append(X0 >> eps * np.eye(n))
    else:
        H = cp.Variable((n, n), name="H")
        Xs = [cp.Variable((n, n), symmetric=True, name=f"X_{i}") for i in range(N)]
        cons += [X >> eps * np.eye(n) for X in Xs]
    if K_fixed is not None:
        Kf = np.asarray(K_fixed, dtype=float)
        if Kf.shape != (N, m, n):
            raise ConfigError(f"K_fixed must have shape ({N}, {m}, {n}), got {Kf.shape}")
        if objective == "min_effort":
            raise ConfigError("objective min_effort needs the gains as variables")
        Ks = Kf * scaling.t[None, None, :] / scaling.s_u[None, :, None]  # K~ = S_u^-1 K T
        S = [Ks[i] @ H for i in range(N)]
    else:
        S = [cp.Variable((m, n), name=f"S_{i}") for i in range(N)]
    T, W = [], []
    n_soc = 0
    dims = []
    for i in range(N):
        Srow, Scol, colk = element_maps(sb, i)
        p = sb.rows[i].size
        if p == 0:
            raise ConfigError(
                f"element box: vertex {i} has no uncertain element (use the polytope method)"
            )
        tt = cp.Variable(p, name=f"t_{i}")
        uu = cp.Variable(p, name=f"u_{i}")
        have = np.unique(colk)
        Pi = Pm[have]
        om = cp.Variable(have.size, name=f"omega_{i}")
        loc = np.searchsorted(have, colk)
        # u_l t_l >= omega_c^2 (rotated SOC: ||[2 omega, u - t]|| <= u + t), sum_(l in c) u_l <=
        # omega_c
        cons.append(cp.SOC(uu + tt, cp.vstack([2 * om[loc], uu - tt]), axis=0))
        cons.append(tt >= eps)
        Sc = np.zeros((have.size, p))
        Sc[loc, np.arange(p)] = 1.0
        cons.append(Sc @ uu <= om)
        n_soc += p
        T.append(tt)
        DL = cp.diag(Srow @ tt)
        k = have.size
        if lyapunov == "common":
            AX = sb.A[i] @ X0 + sb.B @ S[i]
            Gx = Pi @ cp.vstack([X0, S[i]])
            Gw = Pi @ np.vstack([np.zeros((n, ne)), sb.Rs])
            M = cp.bmat(
                [
                    [AX + AX.T + DL, sb.Be, X0 @ sb.C.T, Gx.T],
                    [sb.Be.T, -np.eye(ne), np.zeros((ne, nz)), Gw.T],
                    [sb.C @ X0, np.zeros((nz, ne)), -g * np.eye(nz), np.zeros((nz, k))],
                    [Gx, Gw, np.zeros((k, nz)), -cp.diag(om)],
                ]
            )
            dim = n + ne + nz + k
        else:
            Zsum = 0
            if lyapunov == "rate":
                Wi = []
                for kk, (im, ip, w) in enumerate(pairs[i]):
                    Wk = cp.Variable((n, n), symmetric=True, name=f"W_{i}_{kk}")
                    Dk = (Xs[ip] - Xs[im]) * (rho[kk] / w)
                    cons += [Wk - Dk >> 0, Wk + Dk >> 0]
                    Wi.append(Wk)
                    Zsum = Zsum + Wk
                W.append(Wi)
            U = sb.A[i] @ H + sb.B @ S[i]
            CH = sb.C @ H
            Gx = Pi @ cp.vstack([H, S[i]])
            F = Pi @ np.vstack([np.zeros((n, ne)), sb.Rs])
            M = cp.bmat(
                [
                    [U + U.T + DL + Zsum, -Xs[i] + H.T - U, sb.Be, CH.T, Gx.T],
                    [-Xs[i] + H - U.T, -(H + H.T), np.zeros((n, ne)), -CH.T, -Gx.T],
                    [sb.Be.T, np.zeros((ne, n)), -np.eye(ne), np.zeros((ne, nz)), F.T],
                    [CH, -CH, np.zeros((nz, ne)), -g * np.eye(nz), np.zeros((nz, k))],
                    [Gx, -Gx, F, np.zeros((k, nz)), -cp.diag(om)],
                ]
            )
            dim = 2 * n + ne + nz + k
        cons.append(0.5 * (M + M.T) << -eps * np.eye(dim))
        dims.append(dim)
        if kappa is not None:
            if lyapunov == "common":
                cons.append(cp.bmat([[X0, S[i].T], [S[i], kappa * np.eye(m)]]) >> 0)
            else:
                cons.append(cp.bmat([[H + H.T - Xs[i], S[i].T], [S[i], kappa * np.eye(m)]]) >> 0)
    obj = (
        cp.Minimize(g)
        if objective == "min_gamma"
        else (cp.Minimize(kappa) if kappa is not None else cp.Minimize(0))
    )
    prob = cp.Problem(obj, cons)
    build_s = time.perf_counter() - t0
    n_x_var = n * (n + 1) // 2 * (1 if lyapunov == "common" else N)
    n_w = (N * len(pairs[0]) * n * (n + 1) // 2) if lyapunov == "rate" else 0
    sizes = {
        "form": "direct (common X)" if lyapunov == "common" else "Eq. (30) extended (common H)",
        "scalar_variables": n_x_var
        + (0 if lyapunov == "common" else n * n)
        + (0 if K_fixed is not None else N * m * n)
        + 2 * sum(box.p)
        + sum(
            np.unique(np.array([sb.used.index(int(c)) for c in sb.cols[i]])).size for i in range(N)
        )
        + n_w
        + (1 if objective != "feasibility" else 0),
        "lmi_blocks": N
        + (1 if lyapunov == "common" else N)
        + (2 * N * len(pairs[0]) if lyapunov == "rate" else 0)
        + (N if kappa is not None else 0),
        "robust_block_dim": dims,
        "elements_per_vertex": box.p,
        "second_order_cones": n_soc,
    }
    sizes["scalar_constraints"] = int(
        sum(d * (d + 1) // 2 for d in dims)
        + (1 if lyapunov == "common" else N) * n * (n + 1) // 2
        + (2 * N * len(pairs[0]) * n * (n + 1) // 2 if lyapunov == "rate" else 0)
        + (N * (n + m) * (n + m + 1) // 2 if kappa is not None else 0)
        + 3 * n_soc
    )
    return BoxProblem(prob, g, kappa, H, Xs, S, T, W, scaling, sb, pairs, rho, sizes, build_s)
