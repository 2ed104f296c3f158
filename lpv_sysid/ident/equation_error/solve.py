"""Solving the row regressions of :mod:`lpv_sysid.ident.equation_error` (seed 0 Eq. 47):
scaled-SVD least squares with rank checks (or instrumental variables, or bias-compensated least
squares for regressors with measurement error), each row's covariance and the joint covariance
of all rows (estimators: :mod:`lpv_sysid.ident.equation_error.covariance`), and
``R^2 = 1 - v^T v / sum (y_i - mean(y_i))^2`` per row (on the measurement of Eq. 41).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.ident.equation_error.covariance import (
    CovarianceConfig,
    auto_max_lag,
    coloured_covariance,
    default_dof,
    ewc_long_run,
)


@dataclass(frozen=True)
class RowFit:
    """Result for one state-equation row ``i`` (Eqs. 40-47)."""

    row: int
    cols_A: tuple[int, ...]  # unknown A columns j, (i, j) in I_A (Eq. 36)
    cols_B: tuple[int, ...]  # unknown B columns k, (i, k) in I_B (Eq. 37)
    theta: np.ndarray  # Eq. (42)/(47), then intercept / auxiliary / nuisance terms
    cov: np.ndarray  # reported covariance
    cov_white: np.ndarray  # s^2 (H^T H)^-1
    cov_coloured: np.ndarray  # the coloured-residual estimate (ewc or residual_acf)
    sigma2: float  # residual variance s^2
    r2: float  # coefficient of determination of the row
    n_samples: int
    max_lag: int
    labels: tuple[str, ...] = ()  # one per theta entry (x<j>, u<k>, bias, aux names, nuisance)
    offset: int = 0  # index of theta[0] in the joint parameter vector
    dof: float | None = None  # Student-t degrees of freedom of studentised errors
    eiv_bias: np.ndarray | None = None  # LS minus bias-compensated estimate (errors in variables)

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))


def _solve_iv(i: int, y: np.ndarray, H: np.ndarray, Z: np.ndarray, labels, rcond: float = 1e-10):
    """Instrumental variables ``theta = (Z^T H)^-1 Z^T y``: ``(theta, (Z^T H)^-1)`` (the bread of
    the sandwich; the scores are ``z(t) v(t)``)."""
    _solve(i, y, H, labels, rcond)  # rank checks on the regressors
    _solve(i, y, Z, labels, rcond)  # ... and on the instruments
    scale = np.linalg.norm(H, axis=0)
    zscale = np.linalg.norm(Z, axis=0)
    M = (Z / zscale).T @ (H / scale)
    sv = np.linalg.svd(M, compute_uv=False)
    if sv[-1] < rcond * sv[0]:
        raise SolverError(
            f"row {i}: instruments uncorrelated with regressors {list(labels)} "
            f"(condition {sv[0] / max(sv[-1], 1e-300):.3g})"
        )
    Minv = np.linalg.inv(M)
    theta = (Minv @ ((Z / zscale).T @ y)) / scale
    bread = Minv / np.outer(scale, zscale)  # (Z^T H)^-1
    return theta, bread


def _solve(i: int, y: np.ndarray, H: np.ndarray, labels, rcond: float = 1e-10):
    """Scaled-SVD least squares with rank checks: ``(theta, (H^T H)^-1)``."""
    k, p = H.shape
    if k <= p:
        raise SolverError(f"row {i}: {k} samples for {p} unknown parameters")
    scale = np.linalg.norm(H, axis=0)
    if np.any(scale == 0):
        bad = [c for c, s in zip(labels, scale) if s == 0]
        raise SolverError(f"row {i}: regressor(s) {bad} are identically zero (not excited)")
    Hs = H / scale
    _, s, vt = np.linalg.svd(Hs, full_matrices=False)
    if s[-1] < rcond * s[0]:
        rank = int(np.sum(s > rcond * s[0]))
        raise SolverError(
            f"row {i}: regressors {list(labels)} are linearly dependent "
            f"(rank {rank} of {p}, condition {s[0] / max(s[-1], 1e-300):.3g}); excite them "
            "independently or mark some elements known"
        )
    theta_s = vt.T @ ((vt @ (Hs.T @ y)) / s**2)
    # (H^T H)^-1 from the SVD of the scaled regressors: V diag(1/s^2) V^T, unscaled.
    HtH_inv = ((vt.T / s**2) @ vt) / np.outer(scale, scale)
    return theta_s / scale, HtH_inv


def _r2(y: np.ndarray, v: np.ndarray) -> float:
    yc = y - y.mean()
    sst = float(yc @ yc)
    return 1.0 - float(v @ v) / sst if sst > 0 else (1.0 if float(v @ v) == 0 else 0.0)


def fit_row(
    i: int,
    y: np.ndarray,
    H: np.ndarray,
    cols_A,
    cols_B,
    max_lag: int | None = None,
    rcond: float = 1e-10,
) -> RowFit:
    """Least squares for one row, Eq. (47), with white and ``residual_acf`` covariance."""
    k, p = H.shape
    labels = _labels(cols_A, cols_B, p)
    theta, HtH_inv = _solve(i, y, H, labels, rcond)
    v = y - H @ theta
    sigma2 = float(v @ v) / (k - p)
    cov_w = sigma2 * HtH_inv
    L = auto_max_lag(v) if max_lag is None else int(max_lag)
    cov_c = coloured_covariance(H, v, HtH_inv, L) * (k / (k - p)) if L > 0 else cov_w
    # report the wider of the two per parameter (keep cross terms consistent by scaling)
    dw, dc = np.diag(cov_w), np.diag(cov_c)
    if np.all(dc >= dw):
        cov = cov_c
    else:
        ratio = np.sqrt(np.maximum(dc, dw) / np.where(dc > 0, dc, dw))
        cov = cov_c * np.outer(ratio, ratio) if np.all(dc > 0) else cov_w
    return RowFit(
        i,
        tuple(cols_A),
        tuple(cols_B),
        theta,
        cov,
        cov_w,
        cov_c,
        sigma2,
        _r2(y, v),
        k,
        L,
        tuple(labels),
    )


def solve_rows(
    designs,
    covariance: CovarianceConfig = CovarianceConfig(),
    dt: float = 0.01,
    rcond: float = 1e-10,
) -> tuple[list[RowFit], np.ndarray | None, float | None]:
    """Least squares for every :class:`RowDesign` and their joint covariance.

    Returns ``(row fits, joint covariance of all theta stacked or None, dof or None)``; with
    ``method='ewc'`` the joint covariance is the stacked-score sandwich of
    :mod:`lpv_sysid.ident.equation_error.covariance`
    and every studentised linear combination is ``t_dof``; with ``'residual_acf'`` each row
    gets :func:`fit_row`'s covariance and the rows are treated as independent.
    """
    designs = list(designs)
    if not designs:
        return [], None, None
    if covariance.method == "residual_acf":
        fits, off = [], 0
        for d in designs:
            use = slice(None) if d.use is None else np.asarray(d.use, dtype=bool)
            rf = fit_row(d.row, d.y[use], d.H[use], d.cols_A, d.cols_B, covariance.max_lag, rcond)
            fits.append(RowFit(**{**rf.__dict__, "labels": tuple(d.labels), "offset": off}))
            off += rf.theta.size
        P = off
        J = np.zeros((P, P))
        for rf in fits:
            sl = slice(rf.offset, rf.offset + rf.theta.size)
            J[sl, sl] = rf.cov
        return fits, J, None
    n = designs[0].y.shape[0] // designs[0].stack
    parts, offs, off = [], [], 0
    for d in designs:
        m = d.stack * n
        if d.y.shape != (m,) or d.H.shape[0] != m:
            raise ConfigError(f"row {d.row}: all designs need the same {n} samples per equation")
        use = np.ones(m, bool) if d.use is None else np.asarray(d.use, dtype=bool)
        Hu, yu = d.H[use], d.y[use]
        eiv = None
        if d.Z is None:
            theta, HtH_inv = _solve(d.row, yu, Hu, d.labels, rcond)
            Zs, cw = d.H, None
            if d.noise_var is not None and np.any(np.asarray(d.noise_var) > 0):
                # bias-compensated LS: E[h h^T] = E[h0 h0^T] + Sigma, so (H^T H - N Sigma)^-1 H^T y
                theta_ls = theta
                M = np.linalg.inv(HtH_inv) - Hu.shape[0] * np.diag(
                    np.asarray(d.noise_var, dtype=float)
                )
                HtH_inv = np.linalg.inv(M)
                theta = HtH_inv @ (Hu.T @ yu)
                eiv = theta_ls - theta
        else:
            if d.Z.shape != d.H.shape:
                raise ConfigError(
                    f"row {d.row}: instruments {d.Z.shape} must match regressors {d.H.shape}"
                )
            theta, HtH_inv = _solve_iv(d.row, yu, Hu, d.Z[use], d.labels, rcond)
            Zs = d.Z
            cw = HtH_inv @ (d.Z[use].T @ d.Z[use]) @ HtH_inv.T
        v = np.where(use, d.y - d.H @ theta, 0.0)
        p = theta.size
        sigma2 = float(v @ v) / (int(use.sum()) - p)
        parts.append((d, theta, HtH_inv, v, sigma2, use, Zs, cw, eiv))
        offs.append(off)
        off += p
    P = off
    nu = covariance.dof if covariance.dof is not None else default_dof(n, dt, covariance.band_hz)
    nu = int(min(nu, n - 1))
    # scores; the bias-compensation term N Sigma theta is constant in t and the cosines j >= 1
    # of the EWC are orthogonal to constants, so it drops out
    S = np.concatenate(
        [
            (Zs * v[:, None]).reshape(d.stack, n, -1).sum(axis=0)
            for d, _, _, v, _, _, Zs, _, _ in parts
        ],
        axis=1,
    )
    Omega = n * ewc_long_run(S, nu)
    Hinv = np.zeros((P, P))
    for (d, theta, HtH_inv, *_), o in zip(parts, offs):
        Hinv[o : o + theta.size, o : o + theta.size] = HtH_inv
    joint = Hinv @ Omega @ Hinv.T
    joint = 0.5 * (joint + joint.T)
    fits = []
    for (d, theta, HtH_inv, v, sigma2, use, _, cw, eiv), o in zip(parts, offs):
        sl = slice(o, o + theta.size)
        c = joint[sl, sl]
        white = sigma2 * (HtH_inv if cw is None else cw)
        fits.append(
            RowFit(
                d.row,
                tuple(d.cols_A),
                tuple(d.cols_B),
                theta,
                c,
                white,
                c,
                sigma2,
                _r2(d.y[use], v[use]),
                int(use.sum()),
                0,
                tuple(d.labels),
                o,
                float(nu),
                eiv,
            )
        )
    return fits, joint, float(nu)


def _labels(cols_A, cols_B, n: int | None = None) -> list[str]:
    labels = [f"x{j}" for j in cols_A] + [f"u{k}" for k in cols_B]
    if n is not None and n > len(labels):
        labels.append("bias")
    if n is not None and n > len(labels):
        labels.extend(f"nuisance{k}" for k in range(n - len(labels)))
    return labels
