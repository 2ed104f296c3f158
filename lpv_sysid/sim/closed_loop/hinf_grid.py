"""Peak gain of a frozen linear system over a frequency grid: an independent (LMI-free) check
of seed 0 Eq. (29) at a frozen parameter."""

from __future__ import annotations

from typing import Optional

import numpy as np


def hinf_norm_grid(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    D: Optional[np.ndarray] = None,
    w: Optional[np.ndarray] = None,
) -> tuple[float, float]:
    """Peak max singular value of G(jw) = C (jwI - A)^-1 B + D over a frequency grid.

    An independent check of Eq. (29) at a frozen parameter: it does not use any LMI. The
    grid maximum is refined with a bounded scalar search around the best grid point. Returns
    (norm, frequency in rad/s). Unstable A -> inf.
    """
    from scipy.optimize import minimize_scalar

    A = np.asarray(A, dtype=float)
    if np.max(np.real(np.linalg.eigvals(A))) >= 0:
        return float("inf"), float("nan")
    B = np.asarray(B, dtype=float)
    C = np.asarray(C, dtype=float)
    D = np.zeros((C.shape[0], B.shape[1])) if D is None else np.asarray(D, dtype=float)
    n = A.shape[0]
    eye = np.eye(n)

    def sigma(wk: float) -> float:
        G = C @ np.linalg.solve(1j * wk * eye - A, B) + D
        return float(np.linalg.svd(G, compute_uv=False)[0])

    if w is None:
        rates = np.abs(np.linalg.eigvals(A))
        lo, hi = max(1e-4, 0.01 * rates.min()), 100.0 * rates.max()
        w = np.concatenate([[0.0], np.logspace(np.log10(lo), np.log10(hi), 2000)])
    s = np.array([sigma(wk) for wk in w])
    k = int(np.argmax(s))
    best, wbest = float(s[k]), float(w[k])
    a = w[max(k - 1, 0)]
    b = w[min(k + 1, w.size - 1)]
    if b > a:
        res = minimize_scalar(
            lambda wk: -sigma(wk),
            bounds=(a, b),
            method="bounded",
            options={"xatol": 1e-10 * max(1.0, b)},
        )
        if -res.fun > best:
            best, wbest = float(-res.fun), float(res.x)
    return best, wbest
