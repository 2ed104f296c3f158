"""State-derivative estimation that does not amplify noise (seed 0 Sec. IV, Appendix B input).

The equation-error method of seed 0 Appendix B needs the measured state derivative
``xdot`` (Eq. 41).  Finite differences multiply white noise by ``~2/dt`` and are useless at
100 Hz, so two smoothing differentiators are provided:

``fourier`` (default) - global Fourier smoothing/differentiation over the whole record, in
    the spirit of SIDPAC's ``smoo``/``deriv`` (Morelli & Klein, *Aircraft System
    Identification*, Ch. 11).  The straight line through the end points is removed, the
    remainder (zero at both ends) is extended as an odd function (a sine series, so value
    *and* slope are continuous across the period boundary), transformed with ``rfft``,
    multiplied by the low-pass ``L(f)`` (flat to ``f_cut``, raised-cosine roll-off over
    ``taper`` * f_cut, zero above), and returned both as the smoothed signal and as its
    exact derivative (multiplication by ``j 2 pi f``), plus the removed line and its slope.

    Bias: ``xdot_hat(f) = L(f) * xdot(f)``.  Below ``f_cut`` the gain is exactly 1
    (no attenuation, no phase), in the roll-off it is ``0.5 (1 + cos(pi (f - f_cut) /
    (taper f_cut)))``, above ``(1 + taper) f_cut`` it is 0.  Because the *same* ``L`` is applied
    to the states and inputs used as regressors (:func:`smooth_and_differentiate`), and an
    LTI system commutes with a linear filter, the filtered data still obey
    ``xdot_f = A x_f + B u_f``: the band limit removes noise without biasing the
    equation-error estimates.  Residual errors come from the end-point treatment (a record
    that is not smooth at its ends leaks a little energy; keep a few samples of margin).

``savgol`` - local Savitzky-Golay differentiation (``scipy.signal.savgol_filter`` with
    ``deriv=1``): least-squares polynomial of order ``polyorder`` over ``window`` samples,
    differentiated at the centre.  Its frequency response is
    ``G(f) = H1(f) / (j 2 pi f)`` with ``H1`` the FIR response of ``savgol_coeffs(...,
    deriv=1)`` (see :func:`savgol_gain`).  For ``polyorder`` 1 or 2 it is in closed form
    ``G(w) = sum_k k sin(k w dt) / (w dt sum_k k^2)``, k = 1..m, window = 2m+1, i.e. an
    attenuation ``1 - (w dt)^2 sum k^4 / (6 sum k^2) + O(w^4)``: a 21-sample window at
    100 Hz loses 17 % at 2 Hz, so use ``polyorder`` 4 (loss < 1 % at 2 Hz with the
    defaults) or the Fourier method.  The regressors are smoothed with the matching
    ``deriv=0`` filter, whose attenuation differs slightly from the derivative's: a small
    bias that the tests quantify.

Both functions work along axis 0 of ``(N,)`` or ``(N, n)`` arrays sampled uniformly at ``dt``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError

METHODS = ("fourier", "savgol")


@dataclass(frozen=True)
class DerivativeConfig:
    """How state derivatives are estimated (see module docstring for the bias)."""

    method: str = cf.choice("fourier", METHODS, "differentiator (module docstring)")
    f_cut: float = cf.number(
        6.0,
        "Fourier pass band edge [Hz] (excitation tops out at 2-5 Hz)",
        lo=0.0,
        lo_open=True,
        unit=" Hz",
    )
    taper: float = cf.number(
        0.3, "raised-cosine roll-off width as a fraction of f_cut", lo=0.0, hi=2.0
    )
    window_s: float = cf.number(0.21, "Savitzky-Golay window length [s]", lo=0.0, lo_open=True)
    polyorder: int = cf.count(4, "Savitzky-Golay polynomial order", lo=1)

    @classmethod
    def from_dict(cls, d: dict | None, where: str = "derivatives") -> "DerivativeConfig":
        return cls(**cf.parse_fields(cls, d or {}, where))


def _as_2d(x: np.ndarray, name: str) -> tuple[np.ndarray, bool]:
    x = np.asarray(x, dtype=float)
    if x.ndim not in (1, 2):
        raise ConfigError(f"{name} must be (N,) or (N, n), got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ConfigError(f"{name} contains NaN or inf")
    return (x[:, None], True) if x.ndim == 1 else (x, False)


def fourier_gain(f: np.ndarray, f_cut: float, taper: float = 0.3) -> np.ndarray:
    """Low-pass gain ``L(f)`` of the Fourier smoother (1 in band, raised-cosine roll-off, 0)."""
    f = np.abs(np.asarray(f, dtype=float))
    gain = np.zeros_like(f)
    gain[f <= f_cut] = 1.0
    if taper > 0:
        band = (f > f_cut) & (f < f_cut * (1 + taper))
        gain[band] = 0.5 * (1 + np.cos(np.pi * (f[band] - f_cut) / (taper * f_cut)))
    return gain


def fourier_smooth_differentiate(
    x: np.ndarray, dt: float, f_cut: float, taper: float = 0.3
) -> tuple[np.ndarray, np.ndarray]:
    """Global Fourier smoothing and differentiation; returns ``(x_smooth, xdot)``.

    Uses ``numpy.fft`` on the odd extension of the end-point-detrended record (a DST-I in
    disguise; scipy.fft.dst would do the same, rfft keeps the derivative a one-liner).
    """
    smooth, deriv = _fourier(x, dt, f_cut, taper, True)
    assert deriv is not None
    return smooth, deriv


def _fourier(
    x: np.ndarray, dt: float, f_cut: float, taper: float, derivative: bool
) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`fourier_smooth_differentiate`; the derivative only when ``derivative``."""
    xs, squeeze = _as_2d(x, "x")
    n = xs.shape[0]
    if n < 8:
        raise ConfigError(f"need at least 8 samples to differentiate, got {n}")
    if not dt > 0:
        raise ConfigError(f"dt must be > 0, got {dt}")
    t = np.arange(n) * dt
    span = t[-1]
    slope = (xs[-1] - xs[0]) / span
    trend = xs[0] + t[:, None] * slope
    r = xs - trend
    ext = np.concatenate([r, -r[-2:0:-1]], axis=0)  # odd extension, period 2(n-1)
    m = ext.shape[0]
    spec = np.fft.rfft(ext, axis=0)
    f = np.fft.rfftfreq(m, dt)
    lp = fourier_gain(f, f_cut, taper)[:, None]
    smooth = np.fft.irfft(spec * lp, n=m, axis=0)[:n] + trend
    deriv = None
    if derivative:
        deriv = np.fft.irfft(spec * lp * (2j * np.pi * f)[:, None], n=m, axis=0)[:n] + slope
    if squeeze:
        return smooth[:, 0], None if deriv is None else deriv[:, 0]
    return smooth, deriv


def fast_length(n: int) -> int:
    """Largest ``m <= n`` for which the odd-extension period ``2 (m - 1)`` is 11-smooth.

    The Fourier differentiator's FFT length is ``2 (n - 1)``; a large prime factor makes
    pocketfft 4x slower, so callers may drop the last ``n - m`` samples (< 2 % for
    n > 2000, < 2.5 % for n > 500; 11-smooth numbers are dense).
    """

    def smooth11(k: int) -> bool:
        for p in (2, 3, 5, 7, 11):
            while k % p == 0:
                k //= p
        return k == 1

    m = n
    while m > 2 and not smooth11(m - 1):
        m -= 1
    return m


def _savgol_window(window_s: float, dt: float, polyorder: int, n: int) -> int:
    w = int(round(window_s / dt))
    w = max(w, polyorder + 2)
    if w % 2 == 0:
        w += 1
    if w > n:
        raise ConfigError(f"Savitzky-Golay window of {w} samples is longer than the record ({n})")
    return w


def savgol_smooth_differentiate(
    x: np.ndarray, dt: float, window_s: float = 0.21, polyorder: int = 4
) -> tuple[np.ndarray, np.ndarray]:
    """Savitzky-Golay smoothing (``deriv=0``) and differentiation (``deriv=1``)."""
    from scipy.signal import savgol_filter  # here: scipy.signal costs ~0.2 s to import

    xs, squeeze = _as_2d(x, "x")
    w = _savgol_window(window_s, dt, polyorder, xs.shape[0])
    smooth = savgol_filter(xs, w, polyorder, deriv=0, axis=0, mode="interp")
    deriv = savgol_filter(xs, w, polyorder, deriv=1, delta=dt, axis=0, mode="interp")
    if squeeze:
        return smooth[:, 0], deriv[:, 0]
    return smooth, deriv


def savgol_gain(
    f: np.ndarray, dt: float, window: int, polyorder: int, deriv: int = 1
) -> np.ndarray:
    """Complex gain of the centred Savitzky-Golay filter relative to the ideal operator.

    ``deriv=1``: ``H1(f) / (j 2 pi f)`` (1 means an unbiased derivative); ``deriv=0``: ``H0(f)``.
    The filter is symmetric (deriv 0) or antisymmetric (deriv 1), so the result is real.
    """
    from scipy.signal import savgol_coeffs

    f = np.asarray(f, dtype=float)
    c = savgol_coeffs(window, polyorder, deriv=deriv, delta=dt, use="dot")
    m = (window - 1) // 2
    k = np.arange(-m, m + 1)
    w = 2 * np.pi * f
    h = np.exp(1j * np.outer(w, k) * dt) @ c  # y(t) = sum c_k x(t + k dt)
    if deriv == 1:
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(w == 0, 1.0, h / (1j * np.where(w == 0, 1.0, w)))
        return np.real(g)
    return np.real(h)


def smooth_and_differentiate(
    x: np.ndarray, dt: float, config: DerivativeConfig = DerivativeConfig()
) -> tuple[np.ndarray, np.ndarray]:
    """Dispatch on ``config.method``; returns ``(x_smooth, xdot)`` with the same filter."""
    if config.method == "fourier":
        return fourier_smooth_differentiate(x, dt, config.f_cut, config.taper)
    if config.method == "savgol":
        return savgol_smooth_differentiate(x, dt, config.window_s, config.polyorder)
    raise ConfigError(f"unknown derivative method {config.method!r}")


def smooth(x: np.ndarray, dt: float, config: DerivativeConfig = DerivativeConfig()) -> np.ndarray:
    """The smoothing half of :func:`smooth_and_differentiate` (for inputs/regressors): the same
    values, without computing the derivative."""
    if config.method == "fourier":
        return _fourier(x, dt, config.f_cut, config.taper, False)[0]
    if config.method == "savgol":
        from scipy.signal import savgol_filter

        xs, squeeze = _as_2d(x, "x")
        w = _savgol_window(config.window_s, dt, config.polyorder, xs.shape[0])
        smooth = savgol_filter(xs, w, config.polyorder, deriv=0, axis=0, mode="interp")
        return smooth[:, 0] if squeeze else smooth
    raise ConfigError(f"unknown derivative method {config.method!r}")


def smooth_columns(
    x: np.ndarray,
    dt: float,
    config: DerivativeConfig = DerivativeConfig(),
    derivative: bool = False,
) -> np.ndarray:
    """The smoothed (``derivative``: differentiated) columns of ``x`` (N, n), each exactly as a
    call on that column alone gives it: one call for ``fourier`` (an FFT per column), column by
    column for ``savgol`` (its edge fit solves all columns together, which differs from one
    column in the last bits)."""
    xs, _ = _as_2d(x, "x")
    if config.method == "savgol":
        k = 1 if derivative else 0
        cols = [smooth_and_differentiate(xs[:, i], dt, config)[k] for i in range(xs.shape[1])]
        return np.stack(cols, axis=1)
    if derivative:
        return smooth_and_differentiate(xs, dt, config)[1]
    return smooth(xs, dt, config)
