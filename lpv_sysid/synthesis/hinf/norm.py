"""H-infinity norm of a stable LTI system by Hamiltonian bisection (Bruinsma & Steinbuch 1990).

Used to re-check the certificate of seed 0 Lemma 1 with an algorithm that shares nothing with
the LMI (frozen-parameter closed loops of Eq. 19 with K of Eq. 31). Hand-written because
scipy has no H-infinity norm and python-control is not a dependency; the eigenvalue kernel is
``scipy.linalg.eigvals`` (LAPACK geev, balanced).

For G(s) = C (sI - A)^-1 B (D = 0, as in Eq. 19b) and gamma > 0, the Hamiltonian

    Ham(gamma) = [[A, B B^T / gamma], [-C^T C / gamma, -A^T]]

has an eigenvalue j w on the imaginary axis iff gamma is a singular value of G(j w). The two-step
algorithm: start from a lower bound (G at 0 and at the most lightly damped pole frequency),
set gamma = (1 + 2 tol) gamma_lb, collect the imaginary-axis eigenvalues w_1 < ... < w_k, evaluate
sigma_max at the midpoints and raise gamma_lb; stop when no imaginary eigenvalue is left
(then ||G||_inf lies in [gamma_lb, (1 + 2 tol) gamma_lb]). Quadratic convergence.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import eigvals, matrix_balance


@dataclass(frozen=True)
class HinfNorm:
    value: float  # upper end of the bracket (guaranteed >= the true norm within tol)
    lower: float  # lower end (attained at `frequency`)
    frequency: float  # rad/s (continuous) where sigma_max reaches `lower`
    iterations: int
    stable: bool


def sigma_max(
    A: np.ndarray, B: np.ndarray, C: np.ndarray, w: float, D: np.ndarray | None = None
) -> float:
    """Largest singular value of C (j w I - A)^-1 B (+ D)."""
    n = A.shape[0]
    G = C @ np.linalg.solve(1j * w * np.eye(n) - A, B)
    if D is not None:
        G = G + D
    return float(np.linalg.svd(G, compute_uv=False)[0])


def balance(
    A: np.ndarray, B: np.ndarray, C: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Diagonal similarity (powers of 2) balancing [[|A|, |B| 1], [1^T |C|, 0]] (LAPACK gebal).

    The transfer function, hence the norm, is unchanged; it keeps the Hamiltonian's entries of
    comparable size when B contains the rotor gain b = 1.4e4 (seed 0 Eq. 15).
    """
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = np.abs(A)
    M[:n, n] = np.abs(B).sum(axis=1)
    M[n, :n] = np.abs(C).sum(axis=0)
    _, (t, _p) = matrix_balance(M + 1e-300, permute=False, separate=True)
    t = np.asarray(t[:n], dtype=float) / float(t[n])
    return A * t[None, :] / t[:, None], B / t[:, None], C * t[None, :]


def hinf_norm(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    tol: float = 1e-6,
    max_iter: int = 60,
    stability_margin: float = 0.0,
    balanced: bool = True,
    D: np.ndarray | None = None,
) -> HinfNorm:
    """||C (sI - A)^-1 B + D||_inf for continuous-time (A, B, C, D); inf when A is not Hurwitz.

    ``stability_margin``: A counts as Hurwitz when max Re(eig) < -stability_margin.
    ``balanced``: first apply :func:`balance` (a similarity, norm-preserving).
    ``D`` (feedthrough, default 0): for gamma > sigma_max(D) the Hamiltonian of Bruinsma &
    Steinbuch with R = gamma^2 I - D^T D, S = gamma^2 I - D D^T,
    [[A + B R^-1 D^T C, gamma B R^-1 B^T], [-gamma C^T S^-1 C, -(A + B R^-1 D^T C)^T]]
    (the scaled small-gain check of the element-box certificate has q = E x + F w).
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    C = np.asarray(C, dtype=float)
    if D is not None:
        D = np.asarray(D, dtype=float)
        if D.shape != (C.shape[0], B.shape[1]):
            raise ValueError(f"D must be {C.shape[0]} x {B.shape[1]}, got {D.shape}")
        if not np.any(D):
            D = None
    if balanced and A.shape[0] > 0:
        A, B, C = balance(A, B, C)
    if D is not None:
        return _hinf_norm_d(A, B, C, D, tol, max_iter, stability_margin)
    poles = eigvals(A)
    if np.max(poles.real) >= -stability_margin:
        return HinfNorm(float("inf"), float("inf"), float("nan"), 0, False)
    # initial lower bound: DC and the pole with the largest |Im/Re| (lightest damping)
    cand = [0.0]
    ratio = np.abs(poles.imag) / np.abs(poles.real)
    k = int(np.argmax(ratio))
    if poles[k].imag != 0:
        cand.append(float(abs(poles[k])))
    cand.append(float(np.max(np.abs(poles))))
    vals = [sigma_max(A, B, C, w) for w in cand]
    k = int(np.argmax(vals))
    g_lb, w_pk = vals[k], cand[k]
    if g_lb == 0.0:
        # C (sI - A)^-1 B is zero at these frequencies; try a few more before concluding it is 0
        for w in np.logspace(-3, 4, 15):
            s = sigma_max(A, B, C, w)
            if s > g_lb:
                g_lb, w_pk = s, w
        if g_lb == 0.0:
            return HinfNorm(0.0, 0.0, 0.0, 0, True)
    BBt = B @ B.T
    CtC = C.T @ C
    scale = max(1.0, float(np.max(np.abs(A))))
    for it in range(1, max_iter + 1):
        gamma = (1.0 + 2.0 * tol) * g_lb
        Ham = np.block([[A, BBt / gamma], [-CtC / gamma, -A.T]])
        ev = eigvals(Ham)
        on_axis = np.abs(ev.real) <= 1e-9 * max(scale, 1.0) * (1.0 + np.abs(ev))
        w = np.sort(np.unique(np.round(np.abs(ev[on_axis].imag), 12)))
        if w.size == 0:
            return HinfNorm(gamma, g_lb, w_pk, it, True)
        mids = [0.5 * (w[i] + w[i + 1]) for i in range(w.size - 1)] if w.size > 1 else [w[0]]
        new = [(sigma_max(A, B, C, m), m) for m in mids]
        s, m = max(new)
        if s <= g_lb * (1.0 + 1e-12):
            # numerical stall at the bracket: the imaginary eigenvalues are a coalescing pair
            return HinfNorm(gamma, g_lb, w_pk, it, True)
        g_lb, w_pk = s, m
    return HinfNorm((1.0 + 2.0 * tol) * g_lb, g_lb, w_pk, max_iter, True)


def _hinf_norm_d(A, B, C, D, tol, max_iter, stability_margin) -> HinfNorm:
    poles = eigvals(A)
    if np.max(poles.real) >= -stability_margin:
        return HinfNorm(float("inf"), float("inf"), float("nan"), 0, False)
    cand = [0.0, float(np.max(np.abs(poles)))]
    ratio = np.abs(poles.imag) / np.abs(poles.real)
    k = int(np.argmax(ratio))
    if poles[k].imag != 0:
        cand.append(float(abs(poles[k])))
    vals = [sigma_max(A, B, C, w, D) for w in cand]
    k = int(np.argmax(vals))
    g_lb, w_pk = vals[k], cand[k]
    s_inf = float(np.linalg.svd(D, compute_uv=False)[0])  # sigma_max at w -> inf
    if s_inf > g_lb:
        g_lb, w_pk = s_inf, float("inf")
    if g_lb == 0.0:
        return HinfNorm(0.0, 0.0, 0.0, 0, True)
    scale = max(1.0, float(np.max(np.abs(A))))
    for it in range(1, max_iter + 1):
        gamma = (1.0 + 2.0 * tol) * g_lb
        Rm = gamma**2 * np.eye(D.shape[1]) - D.T @ D
        Sm = gamma**2 * np.eye(D.shape[0]) - D @ D.T
        Ri = np.linalg.inv(Rm)
        Ah = A + B @ Ri @ D.T @ C
        Ham = np.block(
            [[Ah, gamma * B @ Ri @ B.T], [-gamma * C.T @ np.linalg.solve(Sm, C), -Ah.T]]
        )
        ev = eigvals(Ham)
        on_axis = np.abs(ev.real) <= 1e-9 * max(scale, 1.0) * (1.0 + np.abs(ev))
        w = np.sort(np.unique(np.round(np.abs(ev[on_axis].imag), 12)))
        if w.size == 0:
            return HinfNorm(gamma, g_lb, w_pk, it, True)
        mids = [0.5 * (w[i] + w[i + 1]) for i in range(w.size - 1)] if w.size > 1 else [w[0]]
        new = [(sigma_max(A, B, C, m, D), m) for m in mids]
        s, m = max(new)
        if s <= g_lb * (1.0 + 1e-12):
            return HinfNorm(gamma, g_lb, w_pk, it, True)
        g_lb, w_pk = s, m
    return HinfNorm((1.0 + 2.0 * tol) * g_lb, g_lb, w_pk, max_iter, True)


def hinf_norm_sweep(
    A: np.ndarray, B: np.ndarray, C: np.ndarray, w: np.ndarray
) -> tuple[float, float]:
    """Peak of sigma_max over a frequency grid (the dense-sweep oracle for the tests)."""
    vals = np.array([sigma_max(A, B, C, wk) for wk in w])
    k = int(np.argmax(vals))
    return float(vals[k]), float(w[k])
