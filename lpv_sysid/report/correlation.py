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

AXES = ("X", "Y", "Z", "L", "M", "N")
AXIS_TITLES = {
    "X": "F_x (6a)",
    "Y": "F_y (6b)",
    "Z": "F_z (6c)",
    "L": "M_x (6d)",
    "M": "M_y (6e)",
    "N": "M_z (6f)",
}
REGRESSOR_NAMES = {
    "X": ("u", "u w", "u dt"),
    "Y": ("v", "v w", "v dt"),
    "Z": ("dt^2", "dt", "u^2+v^2", "4w dt - p da - q de"),
    "L": ("da^2", "da", "w da - 2l^2 p dt - l^2 q dr/2", "v dt", "v", "v w", "u dr"),
    "M": ("de^2", "de", "w de - 2l^2 q dt - l^2 p dr/2", "u dt", "u", "u w", "v dr"),
    "N": ("dr^2", "dr", "w dr + p de + q da", "p q", "u da + v de", "u p + v q", "dr_dot"),
}


def virtual_actuators(Omega: np.ndarray, mix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(delta, delta^2) of seed 0 Eq. (7) from rotor speeds Omega (N, 4)."""
    Omega = np.asarray(Omega, dtype=float)
    mix = np.asarray(mix, dtype=float)
    return Omega @ mix.T, (Omega * Omega) @ mix.T


def regressors(
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
    u, vv, w = np.asarray(v, dtype=float).T
    p, q, r = np.asarray(omega, dtype=float).T
    dt, da, de, dr = np.asarray(delta, dtype=float).T
    dt2, da2, de2, dr2 = np.asarray(delta_sq, dtype=float).T
    l2 = float(arm_length) ** 2
    dr_dot = np.gradient(dr, t) if n > 1 else np.zeros(n)
    cols = {
        "X": (u, u * w, u * dt),
        "Y": (vv, vv * w, vv * dt),
        "Z": (dt2, dt, u**2 + vv**2, 4 * w * dt - p * da - q * de),
        "L": (da2, da, w * da - 2 * l2 * p * dt - l2 * q * dr / 2, vv * dt, vv, vv * w, u * dr),
        "M": (de2, de, w * de - 2 * l2 * q * dt - l2 * p * dr / 2, u * dt, u, u * w, vv * dr),
        "N": (dr2, dr, w * dr + p * de + q * da, p * q, u * da + vv * de, u * p + vv * q, dr_dot),
    }
    return {axis: np.column_stack(c) for axis, c in cols.items()}


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


def correlation(X: np.ndarray) -> np.ndarray:
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
        RegressorCorrelation(axis, REGRESSOR_NAMES[axis], correlation(regs[axis])) for axis in AXES
    ]
