"""MIMO Virtual Reference Feedback Tuning (seed 1, Sec. 3.3, Eqs. 3.7-3.31).

Given one input/output record ``u`` (N x n_u), ``y`` (N x n_y) of an unknown LTI plant, a
reference model ``M(z)`` (n_y x n_y matrix of discrete transfer functions) and a controller
class linear in its parameters ``C(z; theta) = sum_q K_q beta_q(z)`` (seed 1 Assumption 2), find
``theta`` such that the virtual closed loop reproduces the data:

* virtual reference ``r_v = M^-1 y`` (Eq. 3.7), virtual error ``e_v = r_v - y`` (Eq. 3.8);
* filtered signals ``u_L = L u``, ``e_L = L e_v`` (Eqs. 3.10-3.11) with the thesis choice
  ``L = M`` (Eq. 3.18) so that ``e_L = (I - M) y`` never needs ``M^-1`` (Sec. 3.3.4 steps 1-2);
* least squares ``min 1/N sum ||u_L(k) - phi_L^T(k) theta||^2`` (Eqs. 3.13-3.14) with the
  Kronecker regressor ``phi^T(k) = [(beta_1 e_L)(k)^T (x) I, ..., (beta_p e_L)(k)^T (x) I]``
  and ``theta = vec([K_1, ..., K_p])`` (Eqs. 3.21-3.24; the velocity basis
  ``beta_i = z/(z-1) z^-i`` is exactly Eqs. 3.19-3.25);
* extended instrumental variables for noisy data (Eqs. 3.26-3.31):
  ``zeta_L(k) = [u_L(k+l); ...; u_L(k-l)]``, ``R = 1/N sum zeta_L (x) phi_L^T``,
  ``r = 1/N sum zeta_L (x) u_L``, ``theta = (R^T W^-1 R)^-1 R^T W^-1 r`` (W = I as in step 5
  of the Sec. 3.3.4 pseudo-code); or the classic second-experiment / model-based instrument
  of Sec. 3.3.2 (``phi`` rebuilt from a second output record ``y2`` with the same input).

Filtering with a *matrix* ``M`` would not commute with ``C(theta)``, so for a non-scalar
reference model the common scalar filter is ``L = det M`` and ``L M^-1 = adj M`` (proper and
stable when ``M`` is); for ``M = m(z) I`` this reduces to the thesis' ``L = m`` exactly.
An optional extra scalar pre-filter ``W(z)`` multiplies both sides (e.g. ``1 - m``, which gives
the SISO filter ``L = (1 - M) M`` of Eq. 3.12 for a flat input spectrum).

Transfer functions are ``(num, den)`` in descending powers of ``z`` (scipy.signal.dlti
convention) and are applied with ``scipy.signal.lfilter`` from rest.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy import signal

from lpv_sysid.errors import ConfigError, SolverError

log = logging.getLogger(__name__)

__all__ = [
    "Tf",
    "ControllerClass",
    "VrftResult",
    "pid_class",
    "velocity_class",
    "first_order_model",
    "diagonal_model",
    "vrft",
    "vrft_filtered_signals",
    "controller_tf",
    "invert_controller",
    "model_reference_h2",
]


# ----------------------------------------------------------------------------------------------
# scalar discrete transfer functions
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Tf:
    """Scalar proper discrete transfer function num(z)/den(z), descending powers of z."""

    num: tuple[float, ...]
    den: tuple[float, ...]

    @staticmethod
    def make(num, den, what: str = "transfer function") -> "Tf":
        n = np.trim_zeros(np.atleast_1d(np.asarray(num, dtype=float)), "f")
        d = np.trim_zeros(np.atleast_1d(np.asarray(den, dtype=float)), "f")
        if d.size == 0:
            raise ConfigError(f"{what}: denominator is zero")
        if not (np.all(np.isfinite(n)) and np.all(np.isfinite(d))):
            raise ConfigError(f"{what}: coefficients must be finite")
        if n.size == 0:
            n = np.zeros(1)
        if n.size > d.size:
            raise ConfigError(
                f"{what}: improper (numerator degree {n.size - 1} > "
                f"denominator degree {d.size - 1}); not causal"
            )
        return Tf(tuple(n), tuple(d))

    @property
    def is_zero(self) -> bool:
        return not np.any(np.asarray(self.num))

    def ba(self) -> tuple[np.ndarray, np.ndarray]:
        """(b, a) in ascending powers of z^-1 for scipy.signal.lfilter."""
        d = np.asarray(self.den)
        n = np.asarray(self.num)
        b = np.concatenate([np.zeros(d.size - n.size), n])
        return b / d[0], d / d[0]

    def filter(self, x: np.ndarray) -> np.ndarray:
        """Apply to the columns of x from rest (zero initial conditions)."""
        if self.is_zero:
            return np.zeros_like(x, dtype=float)
        b, a = self.ba()
        return signal.lfilter(b, a, x, axis=0)

    def __mul__(self, o: "Tf") -> "Tf":
        return Tf.make(np.polymul(self.num, o.num), np.polymul(self.den, o.den))

    def __add__(self, o: "Tf") -> "Tf":
        if self.is_zero:
            return o
        if o.is_zero:
            return self
        if len(self.den) == len(o.den) and np.allclose(self.den, o.den, rtol=0, atol=0):
            return Tf.make(np.polyadd(self.num, o.num), self.den)
        return Tf.make(
            np.polyadd(np.polymul(self.num, o.den), np.polymul(o.num, self.den)),
            np.polymul(self.den, o.den),
        )

    def __neg__(self) -> "Tf":
        return Tf(tuple(-np.asarray(self.num)), self.den)

    def __sub__(self, o: "Tf") -> "Tf":
        return self + (-o)

    def dcgain(self) -> float:
        d = np.polyval(self.den, 1.0)
        return float(np.polyval(self.num, 1.0) / d) if d != 0 else float("inf")

    def same(self, o: "Tf") -> bool:
        """Equal as rational functions (cross-multiplication)."""
        a = np.polymul(self.num, o.den)
        b = np.polymul(o.num, self.den)
        n = max(a.size, b.size)
        a = np.concatenate([np.zeros(n - a.size), a])
        b = np.concatenate([np.zeros(n - b.size), b])
        return bool(np.allclose(a, b, rtol=1e-12, atol=1e-14))


ONE = Tf((1.0,), (1.0,))
ZERO = Tf((0.0,), (1.0,))

TfMatrix = list  # list[list[Tf]]


def first_order_model(poles: Sequence[float]) -> TfMatrix:
    """Diagonal reference model M_jj = (1 - p_j)/(z - p_j) (unit DC gain),
    seed 1 Eqs. (5.3), (5.5)."""
    ps = [float(p) for p in poles]
    for p in ps:
        if not np.isfinite(p) or abs(p) >= 1.0:
            raise ConfigError(
                f"reference model pole {p} must be finite and inside the unit circle"
            )
    return diagonal_model([Tf.make([1.0 - p], [1.0, -p]) for p in ps])


def diagonal_model(entries: Sequence[Tf]) -> TfMatrix:
    n = len(entries)
    return [[entries[i] if i == j else ZERO for j in range(n)] for i in range(n)]


def _check_model(M: TfMatrix) -> int:
    n = len(M)
    if n == 0 or any(len(row) != n for row in M):
        raise ConfigError(
            "reference model M must be a square n_y x n_y matrix of transfer functions"
        )
    for i, row in enumerate(M):
        for j, m in enumerate(row):
            if m.is_zero:
                continue
            if np.any(np.abs(np.roots(m.den)) >= 1.0):
                raise ConfigError(
                    f"reference model M[{i}][{j}] has a pole on/outside the unit circle"
                )
    return n


def _det(M: TfMatrix) -> Tf:
    n = len(M)
    if n == 1:
        return M[0][0]
    acc = ZERO
    for j in range(n):
        if M[0][j].is_zero:
            continue
        minor = [[M[r][c] for c in range(n) if c != j] for r in range(1, n)]
        term = M[0][j] * _det(minor)
        acc = acc + term if j % 2 == 0 else acc - term
    return acc


def _adj(M: TfMatrix) -> TfMatrix:
    n = len(M)
    if n == 1:
        return [[ONE]]
    adj = [[ZERO] * n for _ in range(n)]
    for i in range(n):
        for j in range(n):
            minor = [[M[r][c] for c in range(n) if c != j] for r in range(n) if r != i]
            cof = _det(minor)
            adj[j][i] = cof if (i + j) % 2 == 0 else -cof
    return adj


def _is_scalar_identity(M: TfMatrix) -> bool:
    n = len(M)
    return all(M[i][j].is_zero for i in range(n) for j in range(n) if i != j) and all(
        M[i][i].same(M[0][0]) for i in range(n)
    )


def _apply(H: TfMatrix, x: np.ndarray) -> np.ndarray:
    out = np.zeros((x.shape[0], len(H)))
    for i, row in enumerate(H):
        for j, h in enumerate(row):
            if not h.is_zero:
                out[:, i] += h.filter(x[:, j])
    return out


# ----------------------------------------------------------------------------------------------
# controller classes, seed 1 Assumption 2 / Eqs. (3.19)-(3.25) / Appendix A.1
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ControllerClass:
    """C(z; theta)_ij = sum_q K_q[i, j] beta_q(z) for the entries (i, j) where mask is True."""

    basis: tuple[Tf, ...]
    names: tuple[str, ...]
    mask: np.ndarray = field(compare=False)  # (n_u, n_y) bool: tuned entries
    Ts: float = 1.0
    kind: str = "custom"  # "pid" | "velocity" | "custom"

    @property
    def n_u(self) -> int:
        return int(self.mask.shape[0])

    @property
    def n_y(self) -> int:
        return int(self.mask.shape[1])

    def param_index(self) -> list[tuple[int, int, int]]:
        """(q, i, j) of each entry of theta: vec([K_1, ..., K_p]) (column-major, Eq. 3.23),
        masked."""
        idx = []
        for q in range(len(self.basis)):
            for j in range(self.n_y):
                for i in range(self.n_u):
                    if self.mask[i, j]:
                        idx.append((q, i, j))
        return idx

    def param_names(self) -> list[str]:
        return [f"{self.names[q]}[{i},{j}]" for q, i, j in self.param_index()]


def _mask(structure, n_u: int, n_y: int) -> np.ndarray:
    if isinstance(structure, str):
        if structure == "full":
            return np.ones((n_u, n_y), dtype=bool)
        if structure == "diagonal":
            if n_u != n_y:
                raise ConfigError(
                    f"controller structure 'diagonal' needs n_u == n_y, got {n_u} x {n_y}"
                )
            return np.eye(n_u, dtype=bool)
        raise ConfigError(
            f"controller structure {structure!r}: use 'full', 'diagonal' or a 0/1 matrix"
        )
    m = np.asarray(structure)
    if m.shape != (n_u, n_y):
        raise ConfigError(
            f"controller structure mask has shape {m.shape}, expected ({n_u}, {n_y})"
        )
    return m.astype(bool)


def pid_class(
    n_u: int, n_y: int, Ts: float, terms: Sequence[str] = ("p", "i"), structure="full"
) -> ControllerClass:
    """Parallel PID, backward-Euler (seed 1 Eq. A.22): Kp + Ki Ts z/(z-1) + Kd (z-1)/(Ts z)."""
    if not np.isfinite(Ts) or Ts <= 0:
        raise ConfigError(f"sample time Ts={Ts} must be positive")
    lib = {
        "p": Tf.make([1.0], [1.0]),
        "i": Tf.make([Ts, 0.0], [1.0, -1.0]),
        "d": Tf.make([1.0, -1.0], [Ts, 0.0]),
    }
    terms = [str(t).lower() for t in terms]
    bad = [t for t in terms if t not in lib]
    if bad or not terms or len(set(terms)) != len(terms):
        raise ConfigError(f"controller terms {list(terms)}: choose distinct items of p, i, d")
    return ControllerClass(
        tuple(lib[t] for t in terms),
        tuple("K" + t for t in terms),
        _mask(structure, n_u, n_y),
        float(Ts),
        "pid",
    )


def velocity_class(
    n_u: int, n_y: int, order: int, structure="full", Ts: float = 1.0
) -> ControllerClass:
    """u(k) = u(k-1) + sum_{i=0..n} B_i e(k-i) (seed 1 Eqs. 3.19-3.25): beta_i = z/(z-1) z^-i."""
    if int(order) != order or order < 0:
        raise ConfigError(f"velocity controller order {order} must be a non-negative integer")
    n = int(order)
    den = np.polymul([1.0, -1.0], np.r_[1.0, np.zeros(n)])
    basis = tuple(Tf.make(np.r_[1.0, np.zeros(n + 1 - i)], den) for i in range(n + 1))
    return ControllerClass(
        basis,
        tuple(f"B{i}" for i in range(n + 1)),
        _mask(structure, n_u, n_y),
        float(Ts),
        "velocity",
    )


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
# the algorithm
# ----------------------------------------------------------------------------------------------
def _as_data(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise ConfigError(f"{name}: expected an (N, channels) array, got shape {np.shape(x)}")
    bad = ~np.isfinite(a)
    if bad.any():
        k, c = np.argwhere(bad)[0]
        raise ConfigError(f"{name}: non-finite value (NaN/inf) at sample {k}, channel {c}")
    return a


def vrft_filtered_signals(u, y, M: TfMatrix, prefilter: Tf | None = None):
    """(u_L, e_L) of seed 1 Eqs. (3.10)-(3.11) with L = M (Eq. 3.18), see module docstring."""
    u = _as_data(u, "u")
    y = _as_data(y, "y")
    n_y = _check_model(M)
    if y.shape[1] != n_y:
        raise ConfigError(f"y has {y.shape[1]} channels but the reference model is {n_y} x {n_y}")
    if u.shape[0] != y.shape[0]:
        raise ConfigError(f"u has {u.shape[0]} samples but y has {y.shape[0]}")
    if _is_scalar_identity(M):
        L = M[0][0]
        LMinv = diagonal_model([ONE] * n_y)
    else:
        L = _det(M)
        if L.is_zero:
            raise ConfigError(
                "reference model M is singular (det M = 0): no virtual reference exists"
            )
        LMinv = _adj(M)
    W = prefilter or ONE
    u_L = (W * L).filter(u)
    # e_L = W L (M^-1 - I) y = W (adj-or-I) y - W L y    (Eq. 3.8, 3.10; pseudo-code step 2)
    e_L = W.filter(_apply(LMinv, y)) - (W * L).filter(y)
    return u_L, e_L


def _regressor(e_L: np.ndarray, cls: ControllerClass) -> np.ndarray:
    """phi_L^T(k) stacked: array (N, n_u, n_theta), Eqs. (3.22)-(3.25)."""
    N = e_L.shape[0]
    idx = cls.param_index()
    filt = [b.filter(e_L) for b in cls.basis]  # (beta_q e_L)(k), (N, n_y)
    Phi = np.zeros((N, cls.n_u, len(idx)))
    for c, (q, i, j) in enumerate(idx):
        Phi[:, i, c] = filt[q][:, j]
    return Phi


def _rank_check(A: np.ndarray, names: list, what: str, rtol: float = 1e-9) -> float:
    s = np.linalg.svd(A, compute_uv=False)
    if s.size == 0 or s[0] == 0.0:
        raise SolverError(f"{what}: all regressors are zero (no excitation in the data)")
    if s[-1] <= rtol * s[0]:
        _, _, vt = np.linalg.svd(A)
        v = vt[-1]
        involved = [names[k] for k in np.argsort(-np.abs(v)) if abs(v[k]) > 0.1 * np.abs(v).max()]
        raise SolverError(
            f"{what} is rank deficient (sigma_min/sigma_max = {s[-1] / s[0]:.2e}): "
            f"collinear basis functions {involved}; excite more / use a smaller class"
        )
    return float(s[0] / s[-1])


def _assemble(theta: np.ndarray, cls: ControllerClass) -> list:
    K = [np.zeros((cls.n_u, cls.n_y)) for _ in cls.basis]
    for v, (q, i, j) in zip(theta, cls.param_index()):
        K[q][i, j] = v
    return K


def vrft(
    u,
    y,
    M: TfMatrix,
    cls: ControllerClass,
    *,
    method: str = "ls",
    prefilter: Tf | None = None,
    window: int = 5,
    instrument=None,
    y2=None,
    discard: int = 0,
    eiv_weight: str = "identity",
) -> VrftResult:
    """Identify theta of ``C(z; theta)`` so that the closed loop approaches ``M`` (seed 1 Sec.
    3.3).

    method:
      ``"ls"``  least squares, Eqs. (3.13)-(3.14);
      ``"eiv"`` extended IV, Eqs. (3.26)-(3.31) with zeta_L = [s_L(k+l) .. s_L(k-l)], l=window,
      where
              s = u (the thesis' choice, valid for open-loop data) or ``instrument`` (N x q, e.g.
              the
              external excitation of a closed-loop experiment, which is independent of the noise);
      ``"iv"``  second experiment / model-based instrument of Sec. 3.3.2: phi rebuilt from ``y2``
              (same input u, independent noise, or a model-simulated noise-free output).
    discard: samples dropped at the start of the regression (transient when data are not from
    rest).
    eiv_weight: ``"identity"`` (W = I, pseudo-code step 5) or ``"residual"``: two-step estimate of
      the residual covariance of Eq. (3.30), W = 1/N sum g g^T with g(k) = zeta_L(k) (x) eps(k) and
      eps the residual of the W = I solution, then Eq. (3.31) with that W.
    """
    u = _as_data(u, "u")
    y = _as_data(y, "y")
    if u.shape[1] != cls.n_u or y.shape[1] != cls.n_y:
        raise ConfigError(
            f"data have n_u={u.shape[1]}, n_y={y.shape[1]} but the controller class is "
            f"{cls.n_u} x {cls.n_y}"
        )
    names = cls.param_names()
    n_th = len(names)
    if n_th == 0:
        raise ConfigError("controller class has no free parameter (mask all False)")
    N = u.shape[0]
    window = int(window)
    if window < 0:
        raise ConfigError(f"EIV window l={window} must be >= 0")
    need = int(discard) + n_th + (2 * window + 1 if method == "eiv" else 0) + 10
    if N < need:
        raise ConfigError(
            f"data too short: N={N} samples, need at least {need} for {n_th} parameters"
            + (f" and EIV window l={window}" if method == "eiv" else "")
        )
    u_L, e_L = vrft_filtered_signals(u, y, M, prefilter)
    Phi = _regressor(e_L, cls)
    s = slice(int(discard), N)
    A = Phi[s].reshape(-1, n_th)
    b = u_L[s].reshape(-1)

    if method == "ls":
        cond = _rank_check(A, names, "VRFT regressor matrix (Eq. 3.14)")
        theta = np.linalg.lstsq(A, b, rcond=None)[0]
    elif method == "eiv":
        if instrument is None:
            z_L = u_L
        else:
            z = _as_data(instrument, "instrument")
            if z.shape[0] != N:
                raise ConfigError(f"instrument has {z.shape[0]} samples, data have {N}")
            z_L = _scalar_L(M, prefilter).filter(z)  # same filter as u_L (Eq. 3.26)
        # zeta_L(k) = [z_L(k+l); ...; z_L(k-l)] with l = window (Eq. 3.26)
        ks = np.arange(max(int(discard), window), N - window)
        Z = np.concatenate([z_L[ks + d] for d in range(window, -window - 1, -1)], axis=1)
        nk = ks.size
        R = np.einsum("ka,kbt->abt", Z, Phi[ks]).reshape(-1, n_th) / nk  # Eq. (3.28)
        r = np.einsum("ka,kb->ab", Z, u_L[ks]).reshape(-1) / nk  # Eq. (3.29)
        cond = _rank_check(R, names, "EIV correlation matrix R (Eq. 3.28)")
        theta = np.linalg.lstsq(R, r, rcond=None)[0]  # Eq. (3.31), W = I
        if eiv_weight == "residual":
            eps = u_L[ks] - np.einsum("kbt,t->kb", Phi[ks], theta)
            g = (Z[:, :, None] * eps[:, None, :]).reshape(nk, -1)  # zeta (x) eps
            W = g.T @ g / nk  # Eq. (3.30)
            W += 1e-9 * np.trace(W) / W.shape[0] * np.eye(W.shape[0])
            try:
                Lw = np.linalg.cholesky(W)
            except np.linalg.LinAlgError:
                raise SolverError(
                    "EIV residual covariance W (Eq. 3.30) is not positive definite"
                ) from None
            Rw = np.linalg.solve(Lw, R)
            cond = _rank_check(Rw, names, "weighted EIV matrix W^-1/2 R (Eq. 3.31)")
            theta = np.linalg.lstsq(Rw, np.linalg.solve(Lw, r), rcond=None)[0]
        elif eiv_weight != "identity":
            raise ConfigError(f"eiv_weight {eiv_weight!r}: use 'identity' or 'residual'")
    elif method == "iv":
        if y2 is None:
            raise ConfigError("method 'iv' needs a second output record y2 (same input u)")
        y2 = _as_data(y2, "y2")
        if y2.shape != y.shape:
            raise ConfigError(f"y2 has shape {y2.shape}, y has {y.shape}")
        _, e2 = vrft_filtered_signals(u, y2, M, prefilter)
        Z = _regressor(e2, cls)[s].reshape(-1, n_th)
        G = Z.T @ A
        cond = _rank_check(G, names, "IV matrix sum phi2 phi^T (Sec. 3.3.2)")
        theta = np.linalg.lstsq(G, Z.T @ b, rcond=None)[0]
    else:
        raise ConfigError(f"VRFT method {method!r}: use 'ls', 'eiv' or 'iv'")

    res = b - A @ theta
    J = float(res @ res / (N - int(discard)))
    log.debug("VRFT %s: N=%d, n_theta=%d, J_VR=%.3e, cond=%.2e", method, N, n_th, J, cond)
    return VrftResult(theta, _assemble(theta, cls), cls, method, J, N, cond, names)


def _scalar_L(M: TfMatrix, prefilter: Tf | None) -> Tf:
    L = M[0][0] if _is_scalar_identity(M) else _det(M)
    return (prefilter or ONE) * L


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
