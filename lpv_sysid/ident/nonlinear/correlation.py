"""Regressors of the nonlinear aerodynamic model, seed 0 Eq. (6), and their correlation (Fig. 10).

For each axis of Eq. (6) the regressor functions multiplying the lumped parameters K are
evaluated on time histories of body velocity v = (u, v, w), body rates w = (p, q, r) and the
virtual actuators of Eq. (7), ``delta = Mix Omega`` and ``delta^2 = Mix Omega^2`` (note that
``dt^2`` is the first row of ``Mix Omega^2``, not ``dt`` squared). Their correlation
coefficients tell whether the phase-2 data can separate the parameters (seed 0 Sec. VII).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident.nonlinear.data import AXES, REGRESSORS, regressors_of_delta

AXIS_TITLES = {
    "X": "F_x (6a)",
    "Y": "F_y (6b)",
    "Z": "F_z (6c)",
    "L": "M_x (6d)",
    "M": "M_y (6e)",
    "N": "M_z (6f)",
}
#: regressor labels per axis: those of :data:`REGRESSORS` and, in N, the rotor reaction
#: torque ``dr_dot`` (J_z dr_dot of Eq. 6f, known in the identification, shown in Fig. 10)
REGRESSOR_NAMES = {
    axis: tuple(label for _, label in REGRESSORS[axis]) + (("dr_dot",) if axis == "N" else ())
    for axis in AXES
}


def fig10_regressors(
    t: np.ndarray,
    v: np.ndarray,
    omega: np.ndarray,
    delta: np.ndarray,
    delta_sq: np.ndarray,
    arm_length: float,
) -> dict[str, np.ndarray]:
    """Regressor matrices (N, n_axis) of seed 0 Eq. (6a)-(6f), keyed by axis X, Y, Z, L, M, N.

    ``dr_dot`` is the numerical derivative of dr on ``t``. The seed prints the last term of
    Eq. (6f) as ``J_z p dr_dot``; like :mod:`lpv_sysid.models.quadrotor` it is read as the rotor
    reaction torque ``J_z dr_dot`` (a moment), so the regressor is ``dr_dot``.
    """
    t = np.asarray(t, dtype=float)
    arrays = {"v": v, "omega": omega, "delta": delta, "delta_sq": delta_sq}
    n = t.size
    for name, arr in arrays.items():
        arr = np.asarray(arr, dtype=float)
        want = 3 if name in ("v", "omega") else 4
        if arr.shape != (n, want):
            raise ConfigError(
                f"regressors: '{name}' must have shape ({n}, {want}), got {arr.shape}"
            )
    regs = regressors_of_delta(
        np.asarray(v, dtype=float),
        np.asarray(omega, dtype=float),
        np.asarray(delta, dtype=float),
        np.asarray(delta_sq, dtype=float),
        float(arm_length),
    )
    dr = np.asarray(delta, dtype=float)[:, 3]
    dr_dot = np.gradient(dr, t) if n > 1 else np.zeros(n)
    regs["N"] = np.column_stack([regs["N"], dr_dot])
    return regs


@dataclass(frozen=True)
class RegressorCorrelation:
    """Correlation matrix of one axis's regressors; NaN where a regressor is constant."""

    axis: str
    names: tuple[str, ...]
    corr: np.ndarray

    def max_offdiag(self) -> float:
        c = np.abs(self.corr.copy())
        np.fill_diagonal(c, np.nan)
        return float(np.nanmax(c)) if np.any(np.isfinite(c)) else float("nan")

    def to_dict(self) -> dict:
        return {
            "names": list(self.names),
            "corr": [[None if not np.isfinite(x) else float(x) for x in row] for row in self.corr],
        }


def column_correlation(X: np.ndarray) -> np.ndarray:
    """Pearson correlation of the columns of X (np.corrcoef), NaN for constant columns."""
    X = np.asarray(X, dtype=float)
    Xc = X - X.mean(axis=0)
    s = np.sqrt(np.sum(Xc * Xc, axis=0))
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(
            s > 1e-12 * max(1.0, float(np.max(np.abs(X))) * np.sqrt(X.shape[0])), s, np.nan
        )
        C = (Xc.T @ Xc) / np.outer(scale, scale)
    return np.clip(C, -1.0, 1.0)


def regressor_correlations(regs: dict[str, np.ndarray]) -> list[RegressorCorrelation]:
    """Correlation matrices per axis (seed 0 Fig. 10)."""
    return [
        RegressorCorrelation(axis, REGRESSOR_NAMES[axis], column_correlation(regs[axis]))
        for axis in AXES
    ]
