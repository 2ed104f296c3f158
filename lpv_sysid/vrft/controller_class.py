"""VRFT controller classes linear in their parameters (seed 1 Assumption 2, Eqs. 3.19-3.25,
Appendix A.1): ``C(z; theta) = sum_q K_q beta_q(z)`` with the PID and velocity bases."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.vrft.tf import Tf


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
