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

Uncertainty.  Three covariance estimates of ``theta`` are computed:

* white residuals: ``Cov(theta) = s^2 (H^T H)^-1``, ``s^2 = v^T v / (K - p)`` (Morelli & Klein,
  *Aircraft System Identification*, Sec. 5.2) - kept for comparison only: with smoothed
  derivatives, closed-loop data and model-structure error the residuals are coloured and
  this is several times too optimistic;
* ``residual_acf`` (Morelli & Klein's residual-autocorrelation-corrected covariance):
  ``(H^T H)^-1 [sum_i sum_j h(i)^T R_vv(i-j) h(j)] (H^T H)^-1`` with the residual
  autocorrelation ``R_vv`` truncated at ``max_lag`` with Bartlett weights (the double sum is
  ``H^T (r * H)``, an FFT convolution); ``max_lag=None`` takes twice the first lag where the
  autocorrelation falls below ``2/sqrt(K)``; the larger of the white and the coloured variance
  is reported.  It treats the residual as independent of the regressors, which closed-loop
  data (the baseline feeds measurement noise back into the states) violate, and its truncated
  lag window under-reads residual power concentrated in the excitation band;
* ``ewc`` (default of :func:`solve_rows`, used for the vertex models): heteroskedasticity- and
  autocorrelation-robust sandwich on the *score* ``s(t) = h(t) v(t)`` of all rows stacked,
  ``Cov(theta) = (H^T H)^-1 [K Omega] (H^T H)^-1`` (block-diagonal ``(H^T H)^-1``), with the
  long-run variance ``Omega`` estimated by the equal-weighted cosine estimator
  ``Omega = (1/nu) sum_{j=1..nu} L_j L_j^T``, ``L_j = sqrt(2/K) sum_t s(t) cos(pi j (t + 1/2) /
  K)``
  (Mueller 2004; Lazarus, Lewis, Stock & Watson, "HAR inference: recommendations for
  practice", JBES 36, 2018).  It makes no assumption on how residuals and regressors are
  coloured or coupled, it gives the cross-row covariances (needed when an estimate combines
  rows, e.g. the equilibrium re-expansion of :mod:`lpv_sysid.ident.taylor`), and its finite-
  sample law is known: for any linear combination ``c^T theta`` the studentised error is
  Student-t with ``nu`` degrees of freedom, so the interval of ``k`` standard errors is widened
  to the ``t_nu`` quantile of the same coverage (:func:`t_factor`) instead of trusting the
  normal quantile.  ``nu`` (``CovarianceConfig.dof``) trades bias against variance: the cosines
  span ``[0, nu / (2 T)]`` Hz of the score spectrum, which must be flat there; the default
  (:func:`default_dof`) keeps that band below the lowest excitation frequency.
* ``R^2 = 1 - v^T v / sum (y_i - mean(y_i))^2`` per row (on the measurement of Eq. 41).

All inputs are plain arrays; building them from bags is :mod:`lpv_sysid.ident.dataprep`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lpv_sysid.errors import ConfigError, SolverError

COV_METHODS = ("ewc", "residual_acf")


@dataclass(frozen=True)
class CovarianceConfig:
    """How the parameter covariance is estimated (module docstring)."""

    method: str = "ewc"
    dof: int | None = None  # ewc: cosine terms nu (None: default_dof)
    band_hz: float = 1.0  # ewc default: nu / (2 T) <= band_hz (flat score spectrum)
    max_lag: int | None = None  # residual_acf: lags (None: auto_max_lag)

    @classmethod
    def from_dict(cls, d: dict | None) -> "CovarianceConfig":
        from lpv_sysid.config_fields import check_keys, is_count, is_finite_number

        d = dict(d or {})
        check_keys(d, ("method", "dof", "band_hz", "max_lag"), "covariance")
        if d.get("method", "ewc") not in COV_METHODS:
            raise ConfigError(
                f"covariance.method must be one of {COV_METHODS}, got {d['method']!r}"
            )
        for key, low in (("dof", 2), ("max_lag", 0)):
            v = d.get(key)
            if v is not None and (not is_count(v) or v < low):
                raise ConfigError(
                    f"covariance.{key} must be null or an integer >= {low}, got {v!r}"
                )
        if "band_hz" in d and (not is_finite_number(d["band_hz"]) or d["band_hz"] <= 0):
            raise ConfigError(f"covariance.band_hz must be a number > 0, got {d['band_hz']!r}")
        if "band_hz" in d:
            d["band_hz"] = float(d["band_hz"])
        return cls(**d)


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


def coloured_covariance(
    H: np.ndarray, v: np.ndarray, HtH_inv: np.ndarray, max_lag: int
) -> np.ndarray:
    """``(H^T H)^-1 [sum_ij h(i)^T R_vv(i-j) h(j)] (H^T H)^-1`` with Bartlett-weighted lags."""
    k = H.shape[0]
    L = int(min(max_lag, k - 1))
    n = 1 << int(np.ceil(np.log2(2 * k)))
    spec = np.fft.rfft(v, n)
    acf = np.fft.irfft(np.abs(spec) ** 2, n)[: L + 1] / k  # R_vv(0..L), biased
    acf = acf * (1.0 - np.arange(L + 1) / (L + 1.0))  # Bartlett / Newey-West
    kernel = np.concatenate([acf[:0:-1], acf])  # lags -L..L
    # (R H)[i] = sum_l R(l) h(i + l): same-length convolution of every column with the kernel
    m = 1 << int(np.ceil(np.log2(k + 2 * L + 1)))
    conv = np.fft.irfft(np.fft.rfft(H, m, axis=0) * np.fft.rfft(kernel, m)[:, None], m, axis=0)
    RH = conv[L : L + k]
    middle = H.T @ RH
    middle = 0.5 * (middle + middle.T)
    return HtH_inv @ middle @ HtH_inv


def default_dof(n_samples: int, dt: float, band_hz: float = 1.0) -> int:
    """EWC cosine terms: the largest ``nu`` with ``nu / (2 T) <= band_hz`` (``T = n dt``), at
    most ``0.4 n^(2/3)`` (the rule of Lazarus et al. 2018), at least 4."""
    T = n_samples * dt
    return int(max(4, min(np.floor(2.0 * T * band_hz), np.floor(0.4 * n_samples ** (2.0 / 3.0)))))


def ewc_long_run(S: np.ndarray, nu: int) -> np.ndarray:
    """Equal-weighted cosine long-run variance of the rows of ``S`` (K, P), module docstring."""
    from scipy.fft import dct

    k = S.shape[0]
    if not 1 <= nu < k:
        raise SolverError(f"EWC: need 1 <= nu < {k} samples, got nu = {nu}")
    # DCT-II: y_j = 2 sum_t s_t cos(pi j (2t + 1) / (2K))  ->  L_j = sqrt(2/K) y_j / 2
    lam = dct(S, type=2, axis=0)[1 : nu + 1] * np.sqrt(2.0 / k) / 2.0
    return lam.T @ lam / nu


def t_factor(k_sigma: float, dof: float | None) -> float:
    """Widening of a ``k_sigma``-standard-error interval so that it keeps the normal coverage
    ``2 Phi(k) - 1`` when the studentised error is Student-t with ``dof`` degrees of freedom."""
    if dof is None or not np.isfinite(dof):
        return 1.0
    from scipy.stats import norm, t

    return float(t.ppf(norm.cdf(k_sigma), dof) / k_sigma)


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
    ``method='ewc'`` the joint covariance is the stacked-score sandwich of the module docstring
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


def _append_independent(
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


def _labels(cols_A, cols_B, n: int | None = None) -> list[str]:
    labels = [f"x{j}" for j in cols_A] + [f"u{k}" for k in cols_B]
    if n is not None and n > len(labels):
        labels.append("bias")
    if n is not None and n > len(labels):
        labels.extend(f"nuisance{k}" for k in range(n - len(labels)))
    return labels


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
            H, chosen = _append_independent(H, E)
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
    coefficients are estimated but not reported (see :mod:`lpv_sysid.ident.taylor`);
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
