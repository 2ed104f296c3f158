"""Equation-error grey-box least squares, seed 0 Appendix B (Eqs. 35-47).

For the perturbation state equation ``dxdot = A dx + B du`` (Eq. 35, with ``dx = x - x0``,
``du = u - u0``) some elements of ``A`` and ``B`` are known (kinematics, gravity, motor model)
and the others are unknown (functions of the aerodynamic parameters K).  Per row ``i``:

* index sets of unknown/known elements, Eqs. (36)-(39): ``maskA[i]``, ``maskB[i]`` (True =
  unknown) and their complements;
* regressors ``h_i = [x_j^T  u_k^T]`` over the unknown columns, Eq. (40) -> ``H_i`` (K x p_i),
  Eq. (45);
* measurement ``y_i = xdot_i - sum_known A_ij x_j - sum_known B_ik u_k``, Eq. (41);
* parameters ``theta^(i)`` = unknown elements of row i of ``[A B]``, Eq. (42);
* estimate ``theta^(i) = (H_i^T H_i)^-1 H_i^T y_i``, Eq. (47), computed with
  ``numpy.linalg.lstsq`` (SVD) instead of forming ``(H^T H)^-1``: the normal equations
  square the condition number of ``H`` (regressors in rad, m/s and ~600 rad/s rotor speeds
  differ by orders of magnitude), while the SVD solves the same problem in the conditioning
  of ``H`` itself.  Columns are scaled to unit norm first (the solution is unscaled after),
  and a rank-deficient ``H_i`` (regressor never excited) raises :class:`SolverError` naming
  the row and columns instead of returning a minimum-norm guess.

Uncertainty (Morelli & Klein, *Aircraft System Identification*, Sec. 5.2 and 6.x):
* white residuals: ``Cov(theta) = s^2 (H^T H)^-1``, ``s^2 = v^T v / (K - p)``;
* coloured residuals (the usual case with smoothed derivatives, model-structure error and
  turbulence): ``Cov(theta) = (H^T H)^-1 [sum_i sum_j h(i)^T R_vv(i-j) h(j)] (H^T H)^-1``
  with ``R_vv(k) = (1/K) sum v(i) v(i+k)`` the residual autocorrelation (Morelli & Klein's
  residual-autocorrelation-corrected covariance).  The double sum is evaluated as
  ``H^T (r * H)`` (a convolution of each regressor column with the autocorrelation sequence,
  by FFT).  Lags are truncated at ``max_lag`` with Bartlett weights ``1 - |k|/(L+1)`` (the
  Newey-West form, which keeps the matrix positive semi-definite); ``max_lag=None`` chooses
  ``L`` as twice the first lag where the residual autocorrelation drops below ``2/sqrt(K)``.
  The larger of the white and the coloured variance is reported per parameter, so the
  correction can only widen the error bars.
* ``R^2 = 1 - v^T v / sum (y_i - mean(y_i))^2`` per row (on the measurement of Eq. 41).

All inputs are plain arrays; building them from bags is :mod:`lpv_sysid.ident.dataprep`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lpv_sysid.errors import ConfigError, SolverError


@dataclass(frozen=True)
class RowFit:
    """Result for one state-equation row ``i`` (Eqs. 40-47)."""

    row: int
    cols_A: tuple[int, ...]          # unknown A columns j, (i, j) in I_A (Eq. 36)
    cols_B: tuple[int, ...]          # unknown B columns k, (i, k) in I_B (Eq. 37)
    theta: np.ndarray                # Eq. (42)/(47)
    cov: np.ndarray                  # reported covariance (max of white/coloured per element)
    cov_white: np.ndarray            # s^2 (H^T H)^-1
    cov_coloured: np.ndarray         # residual-autocorrelation-corrected
    sigma2: float                    # residual variance s^2
    r2: float                        # coefficient of determination of the row
    n_samples: int
    max_lag: int

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))


@dataclass(frozen=True)
class Fit:
    """Identified perturbation model ``dxdot = A dx + B du`` with per-element statistics."""

    A: np.ndarray
    B: np.ndarray
    std_A: np.ndarray                # 0 for known elements
    std_B: np.ndarray
    maskA: np.ndarray                # True = identified
    maskB: np.ndarray
    rows: tuple[RowFit, ...] = field(default_factory=tuple)

    @property
    def r2(self) -> dict[int, float]:
        return {rf.row: rf.r2 for rf in self.rows}

    def elements(self):
        """Yield ``(matrix, row, col, nominal, std)`` for every identified element."""
        for rf in self.rows:
            for j in rf.cols_A:
                yield "A", rf.row, j, float(self.A[rf.row, j]), float(self.std_A[rf.row, j])
            for k in rf.cols_B:
                yield "B", rf.row, k, float(self.B[rf.row, k]), float(self.std_B[rf.row, k])

    def predict(self, dx: np.ndarray, du: np.ndarray) -> np.ndarray:
        """Modelled perturbation derivative ``A dx + B du`` for (N, n_x), (N, n_u) arrays."""
        return dx @ self.A.T + du @ self.B.T


def _check(name: str, a: np.ndarray, shape: tuple) -> np.ndarray:
    a = np.asarray(a)
    if a.shape != shape:
        raise ConfigError(f"{name} has shape {a.shape}, expected {shape}")
    if a.dtype != bool and not np.all(np.isfinite(a)):
        raise ConfigError(f"{name} contains NaN or inf")
    return a


def auto_max_lag(v: np.ndarray) -> int:
    """Twice the first lag where the residual autocorrelation falls below ``2/sqrt(K)``."""
    k = v.shape[0]
    n = 1 << int(np.ceil(np.log2(2 * k)))
    spec = np.fft.rfft(v - v.mean(), n)
    acf = np.fft.irfft(np.abs(spec) ** 2, n)[:k]
    if acf[0] <= 0:
        return 0
    rho = acf / acf[0]
    below = np.nonzero(np.abs(rho) < 2.0 / np.sqrt(k))[0]
    first = int(below[0]) if below.size else k // 4
    return int(min(max(2 * first, 1), k // 4))


def coloured_covariance(H: np.ndarray, v: np.ndarray, HtH_inv: np.ndarray,
                        max_lag: int) -> np.ndarray:
    """``(H^T H)^-1 [sum_ij h(i)^T R_vv(i-j) h(j)] (H^T H)^-1`` with Bartlett-weighted lags."""
    k = H.shape[0]
    L = int(min(max_lag, k - 1))
    n = 1 << int(np.ceil(np.log2(2 * k)))
    spec = np.fft.rfft(v, n)
    acf = np.fft.irfft(np.abs(spec) ** 2, n)[: L + 1] / k          # R_vv(0..L), biased
    acf = acf * (1.0 - np.arange(L + 1) / (L + 1.0))                # Bartlett / Newey-West
    kernel = np.concatenate([acf[:0:-1], acf])                      # lags -L..L
    # (R H)[i] = sum_l R(l) h(i + l): same-length convolution of every column with the kernel
    m = 1 << int(np.ceil(np.log2(k + 2 * L + 1)))
    conv = np.fft.irfft(np.fft.rfft(H, m, axis=0) * np.fft.rfft(kernel, m)[:, None], m, axis=0)
    RH = conv[L: L + k]
    middle = H.T @ RH
    middle = 0.5 * (middle + middle.T)
    return HtH_inv @ middle @ HtH_inv


def fit_row(i: int, y: np.ndarray, H: np.ndarray, cols_A, cols_B,
            max_lag: int | None = None, rcond: float = 1e-10) -> RowFit:
    """Least squares for one row, Eq. (47), with white and coloured-residual covariance."""
    k, p = H.shape
    if k <= p:
        raise SolverError(f"row {i}: {k} samples for {p} unknown parameters")
    scale = np.linalg.norm(H, axis=0)
    if np.any(scale == 0):
        bad = [c for c, s in zip(_labels(cols_A, cols_B, p), scale) if s == 0]
        raise SolverError(f"row {i}: regressor(s) {bad} are identically zero (not excited)")
    Hs = H / scale
    theta_s, _, rank, sv = np.linalg.lstsq(Hs, y, rcond=None)
    if rank < p or sv[-1] < rcond * sv[0]:
        raise SolverError(
            f"row {i}: regressors {_labels(cols_A, cols_B, p)} are linearly dependent "
            f"(rank {rank} of {p}, condition {sv[0] / max(sv[-1], 1e-300):.3g}); excite them "
            "independently or mark some elements known")
    theta = theta_s / scale
    v = y - H @ theta
    sigma2 = float(v @ v) / (k - p)
    # (H^T H)^-1 from the SVD of the scaled regressors: V diag(1/s^2) V^T, unscaled.
    _, s, vt = np.linalg.svd(Hs, full_matrices=False)
    HtH_inv_s = (vt.T / s**2) @ vt
    HtH_inv = HtH_inv_s / np.outer(scale, scale)
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
    yc = y - y.mean()
    sst = float(yc @ yc)
    r2 = 1.0 - float(v @ v) / sst if sst > 0 else (1.0 if float(v @ v) == 0 else 0.0)
    return RowFit(i, tuple(cols_A), tuple(cols_B), theta, cov, cov_w, cov_c, sigma2, r2, k, L)


def _append_independent(H: np.ndarray, E: np.ndarray, rtol: float = 1e-8) -> np.ndarray:
    """Append the columns of ``E`` that are linearly independent of ``H`` and of each other."""
    from scipy.linalg import qr

    Hn = H / np.maximum(np.linalg.norm(H, axis=0), 1e-300)
    En = E / np.maximum(np.linalg.norm(E, axis=0), 1e-300)
    keep = [j for j in range(E.shape[1]) if np.linalg.norm(E[:, j]) > 0]
    if not keep:
        return H
    # project the nuisance columns off span(H), then a pivoted QR picks an independent subset
    Q, _ = np.linalg.qr(Hn)
    R = En[:, keep] - Q @ (Q.T @ En[:, keep])
    _, r, piv = qr(R, mode="economic", pivoting=True)
    d = np.abs(np.diag(r))
    n_ok = int(np.sum(d > rtol * max(d[0], 1e-300))) if d.size else 0
    chosen = sorted(keep[k] for k in piv[:n_ok])
    return np.concatenate([H, E[:, chosen]], axis=1)


def _labels(cols_A, cols_B, n: int | None = None) -> list[str]:
    labels = [f"x{j}" for j in cols_A] + [f"u{k}" for k in cols_B]
    if n is not None and n > len(labels):
        labels.append("bias")
    return labels


def fit(xdot: np.ndarray, x: np.ndarray, u: np.ndarray, A_known: np.ndarray, B_known: np.ndarray,
        maskA: np.ndarray, maskB: np.ndarray, max_lag: int | None = None,
        intercept: bool = False, extra: dict[int, np.ndarray] | None = None) -> Fit:
    """Seed 0 Appendix B for all rows.

    ``xdot``, ``x`` (N, n_x), ``u`` (N, n_u) are *perturbation* variables (x - x0, u - u0,
    d/dt of the perturbation).  ``A_known``, ``B_known`` hold the known elements (values at
    unknown positions are ignored); ``maskA``, ``maskB`` are True where the element is unknown.
    Rows with no unknown element are copied from the known matrices.

    Extensions (both off by default, i.e. exactly Appendix B): ``intercept`` adds a constant
    regressor per row (Klein & Morelli's bias term: absorbs trim-estimate and sensor
    offsets); ``extra`` maps a row to nuisance regressors (N, k) appended to ``H_i`` whose
    coefficients are estimated but not reported (see :mod:`lpv_sysid.ident.taylor`);
    nuisance columns linearly dependent on the others are dropped (pivoted QR).
    """
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
    std_A = np.zeros_like(A)
    std_B = np.zeros_like(B)
    rows = []
    for i in range(n_x):
        ja = np.nonzero(maskA[i])[0]
        kb = np.nonzero(maskB[i])[0]
        if ja.size + kb.size == 0:
            continue
        # Eq. (41): measurement = xdot_i minus the known part of the row
        y = xdot[:, i] - x @ A[i] - u @ B[i]
        # Eq. (40)/(45): regressors of the unknown elements
        H = np.concatenate([x[:, ja], u[:, kb]], axis=1)
        if intercept:
            H = np.concatenate([H, np.ones((n_s, 1))], axis=1)
        if extra is not None and i in extra and np.shape(extra[i])[1] > 0:
            H = _append_independent(H, _check(f"extra[{i}]", np.asarray(extra[i], dtype=float),
                                              (n_s, np.shape(extra[i])[1])))
        rf = fit_row(i, y, H, tuple(int(j) for j in ja), tuple(int(k) for k in kb), max_lag)
        A[i, ja] = rf.theta[: ja.size]
        B[i, kb] = rf.theta[ja.size: ja.size + kb.size]
        s = rf.std
        std_A[i, ja] = s[: ja.size]
        std_B[i, kb] = s[ja.size: ja.size + kb.size]
        rows.append(rf)
    return Fit(A, B, std_A, std_B, maskA.copy(), maskB.copy(), tuple(rows))
