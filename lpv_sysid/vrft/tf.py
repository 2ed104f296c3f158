"""Discrete transfer functions of the VRFT of :mod:`lpv_sysid.vrft` (seed 1 Sec. 3.3).

Scalar proper :class:`Tf`, reference-model matrices (``TfMatrix``: lists of lists of ``Tf``)
with their determinant and adjugate, and the checks and application of both to ``(N,
channels)`` data records (conventions: :mod:`lpv_sysid.vrft`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import signal

from lpv_sysid.errors import ConfigError


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
