"""Parameter covariance of the equation-error least squares of
:mod:`lpv_sysid.ident.equation_error` (seed 0 Appendix B) with coloured residuals.

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
* ``ewc`` (default of :func:`~lpv_sysid.ident.equation_error.solve.solve_rows`, used for
  the vertex models): heteroskedasticity- and
  autocorrelation-robust sandwich on the *score* ``s(t) = h(t) v(t)`` of all rows stacked,
  ``Cov(theta) = (H^T H)^-1 [K Omega] (H^T H)^-1`` (block-diagonal ``(H^T H)^-1``), with the
  long-run variance ``Omega`` estimated by the equal-weighted cosine estimator
  ``Omega = (1/nu) sum_{j=1..nu} L_j L_j^T``, ``L_j = sqrt(2/K) sum_t s(t) cos(pi j (t + 1/2) /
  K)``
  (Mueller 2004; Lazarus, Lewis, Stock & Watson, "HAR inference: recommendations for
  practice", JBES 36, 2018).  It makes no assumption on how residuals and regressors are
  coloured or coupled, it gives the cross-row covariances (needed when an estimate combines
  rows, e.g. the equilibrium re-expansion of :mod:`lpv_sysid.ident.vertex.taylor`), and its finite-
  sample law is known: for any linear combination ``c^T theta`` the studentised error is
  Student-t with ``nu`` degrees of freedom, so the interval of ``k`` standard errors is widened
  to the ``t_nu`` quantile of the same coverage (:func:`t_factor`) instead of trusting the
  normal quantile.  ``nu`` (``CovarianceConfig.dof``) trades bias against variance: the cosines
  span ``[0, nu / (2 T)]`` Hz of the score spectrum, which must be flat there; the default
  (:func:`default_dof`) keeps that band below the lowest excitation frequency.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import SolverError

COV_METHODS = ("ewc", "residual_acf")


@dataclass(frozen=True)
class CovarianceConfig:
    """How the parameter covariance is estimated (module docstring)."""

    method: str = cf.choice("ewc", COV_METHODS, "covariance estimate (module docstring)")
    dof: int | None = cf.count(
        None, "ewc: cosine terms nu (null: default_dof)", lo=2, optional=True
    )
    band_hz: float = cf.number(
        1.0,
        "ewc default: nu / (2 T) <= band_hz (flat score spectrum) [Hz]",
        lo=0.0,
        lo_open=True,
        unit=" Hz",
    )
    max_lag: int | None = cf.count(None, "residual_acf: lags (null: auto_max_lag)", optional=True)

    @classmethod
    def from_dict(cls, d: dict | None, where: str = "covariance") -> "CovarianceConfig":
        return cls(**cf.parse_fields(cls, d or {}, where))


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
    from scipy import special

    # t.ppf(norm.cdf(k), dof) with t.ppf(q) = -upper_quantile(q, dof), norm.cdf = ndtr
    return float(-upper_quantile(float(special.ndtr(k_sigma)), dof) / k_sigma)


def upper_quantile(q: float, dof: float | None = None) -> float:
    """``x`` with ``P(X > x) = q`` for a standard normal ``X`` (``dof`` None) or a Student-t
    ``X`` with ``dof`` degrees of freedom: the numbers of ``scipy.stats.norm.isf(q)`` /
    ``scipy.stats.t.isf(q, dof)`` bit for bit (scipy 1.11: ``-ndtri(q)`` / ``-stdtrit(dof,
    q)`` inside (0, 1), the ends of the support at q = 0 and 1, nan for dof <= 0), from
    scipy.special: scipy.stats costs ~0.25 s of import, a third of ``lpv-sysid verify``'s
    serial start-up."""
    from scipy import special

    if dof is None:
        return float(-special.ndtri(q))
    if dof > 0 and q in (0.0, 1.0):  # stdtrit gives nan there, scipy.stats the support end
        return float("inf") if q == 0.0 else float("-inf")
    return float(-special.stdtrit(dof, q))
