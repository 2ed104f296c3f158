"""Diagonal state/input scaling used inside the LMI synthesis (a similarity transform).

The quadrotor's motor rows ``delta' = -a delta + b u`` with ``b = 1.399e4`` (seed 0 Eq. 15)
make ``B`` badly scaled against ``A`` (entries of order 1e-3 .. 1e4), which costs interior-point
solvers accuracy. We solve the LMIs for the scaled system

    x = T x~,  u_c = S_u u~:   A~ = T^-1 A T,  B~_c = T^-1 B_c S_u,  B~_e = T^-1 B_e,  C~ = C T

(``u_e`` and ``z`` are not scaled, so the H-infinity norm u_e -> z is unchanged) and undo the
scaling exactly afterwards:

    K = S_u K~ T^-1,   X = T X~ T^T,   H = T H~ T^T,   S = S_u S~ T^T,

which is the congruence diag(T, T, I, I) of the Eq. (30) LMI (Sylvester's law of inertia:
definiteness is preserved, so the unscaled matrices satisfy the unscaled LMI).

``T`` comes from ``scipy.linalg.matrix_balance`` (LAPACK gebal, powers of 2, no permutation)
applied to the elementwise mean of |A| over all vertex systems, bordered by the exogenous loop
u_e -> z (see :func:`choose_scaling`); ``S_u`` then makes each column of ``T^-1 B`` have its
largest-magnitude entry equal to the largest entry of ``|A~|`` (rounded to a power of 2).
Powers of two make the scaling itself exact in floating point. For the quadrotor-like model
this gives T = 8192 on the rotor-speed states and S_u = 8, and turns Clarabel's
"minimise gamma" answer from a wrong 240.8 (unscaled: solver "optimal" but far from optimal)
into 0.0043, consistent with the feasibility solutions (bench/results/synthesis.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.linalg import matrix_balance


@dataclass(frozen=True)
class Scaling:
    t: np.ndarray  # (n,) state scale, x = diag(t) x~
    s_u: np.ndarray  # (m,) input scale, u = diag(s_u) u~

    @classmethod
    def identity(cls, n: int, m: int) -> "Scaling":
        return cls(np.ones(n), np.ones(m))

    def A(self, A: np.ndarray) -> np.ndarray:
        return A * self.t[None, :] / self.t[:, None]

    def Bc(self, B: np.ndarray) -> np.ndarray:
        return B * self.s_u[None, :] / self.t[:, None]

    def Be(self, Be: np.ndarray) -> np.ndarray:
        return Be / self.t[:, None]

    def C(self, C: np.ndarray) -> np.ndarray:
        return C * self.t[None, :]

    def unscale_K(self, K_s: np.ndarray) -> np.ndarray:
        """K = S_u K~ T^-1 (works on (m, n) or stacked (N, m, n))."""
        return K_s * self.s_u[:, None] / self.t[None, :]

    def unscale_sym(self, X_s: np.ndarray) -> np.ndarray:
        """X = T X~ T^T (also H)."""
        return X_s * self.t[:, None] * self.t[None, :]

    def unscale_S(self, S_s: np.ndarray) -> np.ndarray:
        """S = S_u S~ T^T."""
        return S_s * self.s_u[:, None] * self.t[None, :]


def _pow2(x: np.ndarray) -> np.ndarray:
    return 2.0 ** np.round(np.log2(x))


def choose_scaling(
    As: Sequence[np.ndarray],
    Bs: Sequence[np.ndarray],
    Bes: Sequence[np.ndarray] | None = None,
    C: np.ndarray | None = None,
) -> Scaling:
    """Balancing scaling for a family of (A, B) (see module docstring).

    With ``Bes`` and ``C`` the balanced matrix is [[|A|, |B_e| 1], [1^T |C|, 0]]: the exogenous
    path u_e -> z is treated as one extra loop index, whose scale is then normalised to 1 (a
    common factor of T does not change B_e C), so that the states driven by u_e (the rotor speeds,
    through b = 1.4e4) are scaled to their excited magnitude as well.
    """
    Aabs = np.mean([np.abs(a) for a in As], axis=0)
    Babs = np.max([np.abs(b) for b in Bs], axis=0)
    n, m = Babs.shape
    if Bes is not None and C is not None:
        be = np.max([np.abs(b).sum(axis=1) for b in Bes], axis=0)
        c = np.abs(np.asarray(C, dtype=float)).sum(axis=0)
        M = np.zeros((n + 1, n + 1))
        M[:n, :n] = Aabs
        M[:n, n] = be
        M[n, :n] = c
        _, (t_all, _perm) = matrix_balance(M + 1e-300, permute=False, separate=True)
        t = np.asarray(t_all[:n], dtype=float) / float(t_all[n])
    else:
        # gebal ignores rows/cols that are entirely zero; regularise so every state is scaled
        _, (t, _perm) = matrix_balance(Aabs + 1e-300, permute=False, separate=True)
        t = np.asarray(t, dtype=float)
    A_s = Aabs * t[None, :] / t[:, None]
    ref = float(np.max(A_s)) if np.max(A_s) > 0 else 1.0
    Bt = Babs / t[:, None]
    colmax = np.max(Bt, axis=0)
    s_u = np.where(colmax > 0, ref / np.where(colmax > 0, colmax, 1.0), 1.0)
    return Scaling(t=_pow2(t), s_u=_pow2(s_u))
