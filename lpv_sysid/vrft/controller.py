"""The controller identified by VRFT (:mod:`lpv_sysid.vrft`): :class:`VrftResult` and its
realisations - transfer functions, the inverse of seed 1 Eq. (3.33) and, for evaluation against
a known plant, the closed loop and the model-reference cost of Eq. (3.4)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from lpv_sysid.errors import SolverError
from lpv_sysid.vrft.controller_class import ControllerClass
from lpv_sysid.vrft.tf import Tf, TfMatrix, _apply, _as_data


# ----------------------------------------------------------------------------------------------
# result
# ----------------------------------------------------------------------------------------------
@dataclass
class VrftResult:
    theta: np.ndarray  # (n_theta,), vec([K_1..K_p]) masked, Eq. (3.23)
    K: list  # p matrices (n_u, n_y), zeros where masked out
    cls: ControllerClass
    method: str
    J_vr: float  # Eq. (3.13) at theta, on the (filtered) data
    n_samples: int
    condition: float  # 2-norm condition number of the solved LS matrix
    param_names: list

    def to_dict(self) -> dict:
        C = controller_tf(self)
        d = {
            "method": self.method,
            "J_vr": float(self.J_vr),
            "n_samples": int(self.n_samples),
            "condition_number": float(self.condition),
            "kind": self.cls.kind,
            "Ts": self.cls.Ts,
            "parameters": {n: float(v) for n, v in zip(self.param_names, self.theta)},
            "matrices": {nm: np.asarray(k).tolist() for nm, k in zip(self.cls.names, self.K)},
            "transfer_functions": [
                [{"num": list(map(float, c.num)), "den": list(map(float, c.den))} for c in row]
                for row in C
            ],
        }
        return d


# ----------------------------------------------------------------------------------------------
# the identified controller
# ----------------------------------------------------------------------------------------------
def _common_den(cls: ControllerClass) -> tuple[np.ndarray, list]:
    """Common denominator d(z) and each basis numerator over d (descending z powers)."""
    dens: list[np.ndarray] = []
    for b in cls.basis:
        if not any(len(d) == len(b.den) and np.allclose(d, b.den) for d in dens):
            dens.append(np.asarray(b.den))
    d = np.array([1.0])
    for x in dens:
        d = np.polymul(d, x)
    nums = []
    for b in cls.basis:
        n = np.asarray(b.num)
        for x in dens:
            if not (len(x) == len(b.den) and np.allclose(x, b.den)):
                n = np.polymul(n, x)
        nums.append(np.concatenate([np.zeros(d.size - n.size), n]))
    return d, nums


def controller_tf(res: VrftResult) -> list:
    """C_ij(z) = sum_q K_q[i, j] beta_q(z) as Tf over the common denominator of the basis."""
    d, nums = _common_den(res.cls)
    return [
        [
            Tf.make(sum(res.K[q][i, j] * nums[q] for q in range(len(nums))), d)
            for j in range(res.cls.n_y)
        ]
        for i in range(res.cls.n_u)
    ]


def _matrix_poly(res: VrftResult) -> tuple[np.ndarray, np.ndarray]:
    """C(z) = N(q^-1)/d(q^-1): d (ascending q^-1, d[0] = 1) and N_k (n_k, n_u, n_y)."""
    d, nums = _common_den(res.cls)
    d0 = d[0]
    Nk = np.zeros((d.size, res.cls.n_u, res.cls.n_y))
    for q, n in enumerate(nums):
        Nk += n[:, None, None] * res.K[q][None, :, :]
    return d / d0, Nk / d0


def invert_controller(res: VrftResult, u) -> np.ndarray:
    """e = C^-1(z; theta) u (seed 1 Eq. 3.33), from rest.

    Raises SolverError when C is not invertible with a causal, stable inverse (pseudo-code step 6:
    "check if minimum-phase").
    """
    u = _as_data(u, "u")
    d, Nk = _matrix_poly(res)
    n_u, n_y = Nk.shape[1:]
    if n_u != n_y:
        raise SolverError(
            f"controller is {n_u} x {n_y}: only square controllers can be inverted (Eq. 3.33)"
        )
    N0 = Nk[0]
    if np.linalg.cond(N0) > 1e12:
        raise SolverError(
            "controller direct-feedthrough matrix N_0 is singular: C^-1 is not causal"
        )
    N0i = np.linalg.inv(N0)
    A = [N0i @ Nk[k] for k in range(1, Nk.shape[0])]
    if A:
        n = n_u
        comp = np.zeros((n * len(A), n * len(A)))
        comp[:n, :] = -np.hstack(A)
        comp[n:, :-n] = np.eye(n * (len(A) - 1))
        zeros = np.linalg.eigvals(comp)
        if zeros.size and np.max(np.abs(zeros)) >= 1.0 - 1e-9:
            raise SolverError(
                f"identified controller is not minimum phase (transmission zero at "
                f"|z| = {np.max(np.abs(zeros)):.4f}): C^-1 is unstable (Eq. 3.33)"
            )
    T = u.shape[0]
    du = signal.lfilter(d, [1.0], u, axis=0)  # d(q^-1) u
    e = np.zeros((T, n_u))
    for k in range(T):
        acc = du[k].copy()
        for m, Am in enumerate(A, start=1):
            if k - m >= 0:
                acc -= Nk[m] @ e[k - m]
        e[k] = N0i @ acc
    return e


def model_reference_h2(res: VrftResult, G_ss, M: TfMatrix, n_imp: int = 2000) -> float:
    """||M - T(theta)||_2^2 (seed 1 Eq. 3.4 with W = I) from impulse responses, for a known plant.

    G_ss: discrete state space (A, B, C, D) of the plant (used only for evaluation, never by VRFT).
    """
    A, B, C, D = (np.atleast_2d(np.asarray(x, dtype=float)) for x in G_ss)
    n_y = len(M)
    tot = 0.0
    for j in range(n_y):
        r = np.zeros((n_imp, n_y))
        r[0, j] = 1.0
        y = simulate_loop((A, B, C, D), res, r)
        m = _apply(M, r)
        tot += float(np.sum((m - y) ** 2))
    return tot


def simulate_loop(G_ss, res: VrftResult, r: np.ndarray, v: np.ndarray | None = None) -> np.ndarray:
    """Closed loop y = G u, u = C(theta)(r - y - v) from rest; returns y (noise-free). For
    evaluation."""
    A, B, C, D = (np.atleast_2d(np.asarray(x, dtype=float)) for x in G_ss)
    d, Nk = _matrix_poly(res)
    T = r.shape[0]
    n_u, n_y = Nk.shape[1:]
    x = np.zeros(A.shape[0])
    e_hist = np.zeros((Nk.shape[0], n_y))
    u_hist = np.zeros((d.size, n_u))
    y = np.zeros((T, n_y))
    vv = np.zeros_like(r) if v is None else v
    # u(k) = -sum_{m>=1} d_m u(k-m) + sum_m N_m e(k-m); e(k) = r - C x - D u(k) - v (algebraic
    # loop)
    S = np.linalg.inv(np.eye(n_u) + Nk[0] @ D)
    for k in range(T):
        past = -sum(d[m] * u_hist[m - 1] for m in range(1, d.size)) + sum(
            Nk[m] @ e_hist[m - 1] for m in range(1, Nk.shape[0])
        )
        e_free = r[k] - C @ x - vv[k]
        uk = S @ (past + Nk[0] @ e_free)
        ek = e_free - D @ uk
        y[k] = C @ x + D @ uk
        x = A @ x + B @ uk
        u_hist = np.roll(u_hist, 1, axis=0)
        u_hist[0] = uk
        e_hist = np.roll(e_hist, 1, axis=0)
        e_hist[0] = ek
    return y
