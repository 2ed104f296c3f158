"""The row designs of the state equation (:func:`row_designs`), the fit of all rows
(:func:`fit`, seed 0 Eqs. 35-47) and ``A, B`` assembled from it (:func:`assemble`); the
method is the :mod:`lpv_sysid.ident.equation_error` docstring."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident.equation_error.covariance import CovarianceConfig
from lpv_sysid.ident.equation_error.solve import RowFit, solve_rows


@dataclass(frozen=True)
class Fit:
    """Identified perturbation model ``dxdot = A dx + B du`` with per-element statistics."""

    A: np.ndarray
    B: np.ndarray
    std_A: np.ndarray  # 0 for known elements
    std_B: np.ndarray
    maskA: np.ndarray  # True = identified
    maskB: np.ndarray
    rows: tuple[RowFit, ...] = field(default_factory=tuple)
    cov_joint: np.ndarray | None = None  # all rows' theta stacked (RowFit.offset), ewc only
    dof: float | None = None  # Student-t dof of every studentised element error
    cov_method: str = "residual_acf"
    # taylor2: v -> the identified model re-expanded at body velocity v (ident.vertex.taylor
    # Reexpansion); what bounds the interpolation error between vertices (issue 20 item 2)
    expand: Any = field(default=None, compare=False, repr=False)

    @property
    def r2(self) -> dict[int, float]:
        return {rf.row: rf.r2 for rf in self.rows}

    def elements(self):
        """Yield ``(matrix, row, col, nominal, std)`` for every identified element (mask order:
        row by row, the A columns then the B columns)."""
        for i in range(self.A.shape[0]):
            for j in np.nonzero(self.maskA[i])[0]:
                yield "A", i, int(j), float(self.A[i, j]), float(self.std_A[i, j])
            for k in np.nonzero(self.maskB[i])[0]:
                yield "B", i, int(k), float(self.B[i, k]), float(self.std_B[i, k])

    def predict(self, dx: np.ndarray, du: np.ndarray) -> np.ndarray:
        """Modelled perturbation derivative ``A dx + B du`` for (N, n_x), (N, n_u) arrays."""
        return dx @ self.A.T + du @ self.B.T


@dataclass(frozen=True)
class RowDesign:
    """One row's regression ``y = H theta + v`` (Eqs. 41, 45) with column labels; ``use``
    selects the samples that enter the fit (None: all)."""

    row: int
    y: np.ndarray
    H: np.ndarray
    cols_A: tuple[int, ...]
    cols_B: tuple[int, ...]
    labels: tuple[str, ...]
    use: np.ndarray | None = None
    Z: np.ndarray | None = None  # instruments (same shape as H): theta = (Z^T H)^-1 Z^T y
    stack: int = 1  # equations per time sample, stacked block-wise in y, H (score summed)
    noise_var: np.ndarray | None = (
        None  # (p,) variance of each regressor's measurement error (EIV)
    )


def _check(name: str, a: np.ndarray, shape: tuple) -> np.ndarray:
    a = np.asarray(a)
    if a.shape != shape:
        raise ConfigError(f"{name} has shape {a.shape}, expected {shape}")
    if a.dtype != bool and not np.all(np.isfinite(a)):
        raise ConfigError(f"{name} contains NaN or inf")
    return a


def append_independent(
    H: np.ndarray, E: np.ndarray, rtol: float = 1e-8
) -> tuple[np.ndarray, list[int]]:
    """Append the columns of ``E`` that are linearly independent of ``H`` and of each other;
    returns the new matrix and the indices of the appended columns of ``E``."""
    from scipy.linalg import qr

    Hn = H / np.maximum(np.linalg.norm(H, axis=0), 1e-300)
    En = E / np.maximum(np.linalg.norm(E, axis=0), 1e-300)
    keep = [j for j in range(E.shape[1]) if np.linalg.norm(E[:, j]) > 0]
    if not keep:
        return H, []
    # project the nuisance columns off span(H), then a pivoted QR picks an independent subset
    Q, _ = np.linalg.qr(Hn)
    R = En[:, keep] - Q @ (Q.T @ En[:, keep])
    _, r, piv = qr(R, mode="economic", pivoting=True)
    d = np.abs(np.diag(r))
    n_ok = int(np.sum(d > rtol * max(d[0], 1e-300))) if d.size else 0
    chosen = sorted(keep[k] for k in piv[:n_ok])
    return np.concatenate([H, E[:, chosen]], axis=1), chosen


def row_designs(
    xdot: np.ndarray,
    x: np.ndarray,
    u: np.ndarray,
    A_known: np.ndarray,
    B_known: np.ndarray,
    maskA: np.ndarray,
    maskB: np.ndarray,
    intercept: bool = False,
    extra: dict[int, np.ndarray] | None = None,
) -> tuple[list[RowDesign], np.ndarray, np.ndarray]:
    """The :class:`RowDesign` of every row with an unknown element (Eqs. 40-41, 45), plus
    ``A, B`` holding the known elements (unknown ones zero).  See :func:`fit` for the arguments."""
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    if x.ndim != 2 or u.ndim != 2:
        raise ConfigError(f"x and u must be 2-D (N, n), got {x.shape} and {u.shape}")
    n_s, n_x = x.shape
    n_u = u.shape[1]
    xdot = _check("xdot", np.asarray(xdot, dtype=float), (n_s, n_x))
    _check("x", x, (n_s, n_x))
    _check("u", u, (n_s, n_u))
    A_known = _check("A_known", np.asarray(A_known, dtype=float), (n_x, n_x))
    B_known = _check("B_known", np.asarray(B_known, dtype=float), (n_x, n_u))
    maskA = _check("maskA", np.asarray(maskA, dtype=bool), (n_x, n_x))
    maskB = _check("maskB", np.asarray(maskB, dtype=bool), (n_x, n_u))
    A = np.where(maskA, 0.0, A_known)
    B = np.where(maskB, 0.0, B_known)
    designs = []
    for i in range(n_x):
        ja = np.nonzero(maskA[i])[0]
        kb = np.nonzero(maskB[i])[0]
        if ja.size + kb.size == 0:
            continue
        # Eq. (41): measurement = xdot_i minus the known part of the row
        y = xdot[:, i] - x @ A[i] - u @ B[i]
        # Eq. (40)/(45): regressors of the unknown elements
        H = np.concatenate([x[:, ja], u[:, kb]], axis=1)
        labels = [f"x{j}" for j in ja] + [f"u{k}" for k in kb]
        if intercept:
            H = np.concatenate([H, np.ones((n_s, 1))], axis=1)
            labels.append("bias")
        if extra is not None and i in extra and np.shape(extra[i])[1] > 0:
            E = _check(
                f"extra[{i}]", np.asarray(extra[i], dtype=float), (n_s, np.shape(extra[i])[1])
            )
            H, chosen = append_independent(H, E)
            labels.extend(f"nuisance{c}" for c in chosen)
        designs.append(
            RowDesign(i, y, H, tuple(int(j) for j in ja), tuple(int(k) for k in kb), tuple(labels))
        )
    return designs, A, B


def assemble(
    fits,
    A: np.ndarray,
    B: np.ndarray,
    maskA: np.ndarray,
    maskB: np.ndarray,
    joint: np.ndarray | None = None,
    dof: float | None = None,
    method: str = "residual_acf",
) -> Fit:
    """Write every row's leading parameters (its unknown A then B columns) into ``A, B``."""
    A, B = A.copy(), B.copy()
    std_A, std_B = np.zeros_like(A), np.zeros_like(B)
    for rf in fits:
        na, nb = len(rf.cols_A), len(rf.cols_B)
        s = rf.std
        A[rf.row, list(rf.cols_A)] = rf.theta[:na]
        B[rf.row, list(rf.cols_B)] = rf.theta[na : na + nb]
        std_A[rf.row, list(rf.cols_A)] = s[:na]
        std_B[rf.row, list(rf.cols_B)] = s[na : na + nb]
    return Fit(
        A,
        B,
        std_A,
        std_B,
        np.asarray(maskA, bool).copy(),
        np.asarray(maskB, bool).copy(),
        tuple(fits),
        joint,
        dof,
        method,
    )


def fit(
    xdot: np.ndarray,
    x: np.ndarray,
    u: np.ndarray,
    A_known: np.ndarray,
    B_known: np.ndarray,
    maskA: np.ndarray,
    maskB: np.ndarray,
    max_lag: int | None = None,
    intercept: bool = False,
    extra: dict[int, np.ndarray] | None = None,
    covariance: CovarianceConfig | None = None,
    dt: float = 0.01,
) -> Fit:
    """Seed 0 Appendix B for all rows.

    ``xdot``, ``x`` (N, n_x), ``u`` (N, n_u) are *perturbation* variables (x - x0, u - u0,
    d/dt of the perturbation).  ``A_known``, ``B_known`` hold the known elements (values at
    unknown positions are ignored); ``maskA``, ``maskB`` are True where the element is unknown.
    Rows with no unknown element are copied from the known matrices.

    Extensions (both off by default, i.e. exactly Appendix B): ``intercept`` adds a constant
    regressor per row (Klein & Morelli's bias term: absorbs trim-estimate and sensor
    offsets); ``extra`` maps a row to nuisance regressors (N, k) appended to ``H_i`` whose
    coefficients are estimated but not reported (see :mod:`lpv_sysid.ident.vertex.taylor`);
    nuisance columns linearly dependent on the others are dropped (pivoted QR).

    ``covariance``: None keeps the per-row ``residual_acf`` estimate with ``max_lag`` (the
    historical default of this function); ``CovarianceConfig()`` selects the joint EWC
    estimate (``dt`` = sample interval, for its default dof).
    """
    designs, A, B = row_designs(xdot, x, u, A_known, B_known, maskA, maskB, intercept, extra)
    cov = (
        covariance
        if covariance is not None
        else CovarianceConfig(method="residual_acf", max_lag=max_lag)
    )
    fits, joint, dof = solve_rows(designs, cov, dt)
    return assemble(fits, A, B, maskA, maskB, joint, dof, cov.method)
