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
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.models.lpv import ElementBox, box_vertices
from lpv_sysid.synthesis.scaling import Scaling, choose_scaling

log = logging.getLogger(__name__)

LYAPUNOV = ("common", "vertex", "rate")
OBJECTIVES = ("feasibility", "min_gamma", "min_effort")


@dataclass
class ScaledBox:
    """The element box and the LMI data in the scaled coordinates of :mod:`scaling`."""

    A: list  # per vertex A_c~ (n, n)
    B: np.ndarray  # B_c~ (n, m)
    Be: np.ndarray  # B_c~ R~ = T^-1 B_c R (n, n_e)
    Rs: np.ndarray  # R in the scaled input coordinates, S_u^-1 R (m, n_e)
    C: np.ndarray  # C T (n_z, n)
    rows: list
    cols: list
    half: list  # scaled half-widths h_l tau_c / t_r
    used: list  # columns of [x; u] that carry elements (sorted, union over the vertices)
    tau: np.ndarray  # [t; s_u]


def scale_box(box: ElementBox, R: np.ndarray, C: np.ndarray, scaling: Scaling) -> ScaledBox:
    tau = np.r_[scaling.t, scaling.s_u]
    A = [scaling.A(np.asarray(a, dtype=float)) for a in box.A_centre]
    B = scaling.Bc(np.asarray(box.B_centre, dtype=float))
    rows, cols, half = [], [], []
    for i in range(box.N):
        r, c, h = box.arrays(i)
        rows.append(r)
        cols.append(c)
        half.append(h * tau[c] / scaling.t[r])
    used = sorted({int(c) for cc in cols for c in cc})
    Rs = np.asarray(R, dtype=float) / scaling.s_u[:, None]
    return ScaledBox(
        A,
        B,
        scaling.Be(np.asarray(box.B_centre, dtype=float) @ R),
        Rs,
        scaling.C(C),
        rows,
        cols,
        half,
        used,
        tau,
    )


def box_scaling(box: ElementBox, R: np.ndarray, C: np.ndarray) -> Scaling:
    """:func:`choose_scaling` on the box bounds (centre and both ends of every element)."""
    As, Bs = [], []
    for i in range(box.N):
        lo, hi = box.bounds(i)
        for AB in (lo, hi):
            As.append(np.abs(AB[:, : box.n]))
            Bs.append(np.abs(AB[:, box.n :]))
    return choose_scaling(As, Bs, [b @ R for b in Bs], C)


def rate_vertex_pairs(vmin: np.ndarray, vmax: np.ndarray) -> list:
    """For every vertex i and axis k: (i_minus, i_plus, width_k), the vertices of the edge through
    i along k (box order of :func:`box_vertices`), so D_k X at i = (X_plus - X_minus) / width."""
    V = box_vertices(vmin, vmax)
    p = V.shape[1]
    out = []
    for i in range(V.shape[0]):
        per = []
        for k in range(p):
            lo_v, hi_v = V[i].copy(), V[i].copy()
            lo_v[k], hi_v[k] = vmin[k], vmax[k]
            im = int(np.nonzero(np.all(V == lo_v, axis=1))[0][0])
            ip = int(np.nonzero(np.all(V == hi_v, axis=1))[0][0])
            per.append((im, ip, float(vmax[k] - vmin[k])))
        out.append(per)
    return out


def _element_maps(sb: ScaledBox, i: int):
    """(Srow (n, p): h_l^2 at row r_l, Scol (n_c, p): 1 at the used-column index of c_l, colk)."""
    r, c, h = sb.rows[i], sb.cols[i], sb.half[i]
    n = sb.A[0].shape[0]
    p = r.size
    Srow = np.zeros((n, p))
    Srow[r, np.arange(p)] = h**2
    colk = np.array([sb.used.index(int(x)) for x in c], dtype=int)
    Scol = np.zeros((len(sb.used), p))
    Scol[colk, np.arange(p)] = 1.0
    return Srow, Scol, colk


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
    Srow, _, colk = _element_maps(sb, i)
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
        Srow, Scol, colk = _element_maps(sb, i)
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
