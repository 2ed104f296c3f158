"""The u_e -> z response by FIR regression (seed 0 Eqs. 26-29 on data without an unexcited twin).

On a flight (simulated nonlinear run or PX4) ``z = Q^-1 (v - v_d)`` mixes the response to the
excitation ``u_e`` with the slow tracking error of the reference. :func:`excitation_response_fir`
fits a causal FIR ``u_e -> z`` above the reference band and returns the part of z it explains,
the FIR's fit and its peak gain; the phase-2 simulation (:mod:`lpv_sysid.sim.phase2`) and the
PX4 chain (:mod:`lpv_sysid.flight.chain`) both use it.
"""

from __future__ import annotations

import numpy as np

from lpv_sysid.errors import ConfigError


def excitation_response_fir(
    t: np.ndarray,
    z: np.ndarray,
    ue: np.ndarray,
    f_cut: float = 0.3,
    lags_s: float = 1.0,
    fs: float = 50.0,
    ridge: float = 1e-6,
) -> tuple[np.ndarray, dict]:
    """The part of ``z`` driven by ``u_e``: a causal FIR ``u_e -> z`` (lags 0..``lags_s``)
    fitted by ridge-regularised least squares on the zero-phase high-passed (``f_cut``, below
    the excitation band, above most of the reference band: the slow tracking error is not the
    response to ``u_e``; LTI filters commute, so the FIR is unchanged) signals resampled at
    ``fs`` (anti-aliased when the data are faster), leaving out the first ``L`` rows (lag
    history incomplete) and the filter transients at both ends; then applied to the unfiltered
    ``u_e`` and interpolated back onto ``t``.

    Returns ``(z_e (N, n_z), info)``; ``info`` (plain numbers): ``fit_r2`` (share of the
    high-passed z the FIR explains over the fitted rows), ``fir_peak_gain`` (largest singular
    value of the FIR at the frequencies where u_e has power, >= 5 % of its strongest bin above
    ``f_cut``: elsewhere the data do not determine it; a lower estimate of the H-inf norm the
    certificate bounds), ``window_s`` (first and last fitted time), ``f_cut_hz``, ``lags_s``,
    ``fs_hz``, ``lags``. ConfigError when there are too few samples for the lags."""
    from scipy.signal import butter, sosfiltfilt

    t = np.asarray(t, dtype=float)
    if t.size < 10:
        raise ConfigError(f"FIR excitation response: {t.size} samples are too few")
    dt = float(np.median(np.diff(t)))
    tg = np.arange(t[0], t[-1] + 1e-9 / fs, 1.0 / fs)
    tg = tg[tg <= t[-1]]
    sos_aa = butter(4, 0.4 * fs, fs=1.0 / dt, output="sos") if 1.0 / dt > 1.25 * fs else None

    def on_grid(y: np.ndarray) -> np.ndarray:
        y = sosfiltfilt(sos_aa, y, axis=0) if sos_aa is not None and y.shape[0] > 30 else y
        return np.column_stack([np.interp(tg, t, y[:, k]) for k in range(y.shape[1])])

    zg, ug = on_grid(np.asarray(z, dtype=float)), on_grid(np.asarray(ue, dtype=float))
    n, ne = ug.shape
    L = max(1, int(round(lags_s * fs)))
    if n < 4 * L * ne:
        raise ConfigError(
            f"FIR excitation response: {n} samples at {fs:g} Hz too few for {L} lags x {ne} inputs"
        )
    sos = butter(4, f_cut, btype="highpass", fs=fs, output="sos")
    zh, uh = sosfiltfilt(sos, zg, axis=0), sosfiltfilt(sos, ug, axis=0)
    edge = min(int(round(2.0 / f_cut * fs)), n // 6)  # filter transients dropped at both ends
    rows = slice(L + edge, n - edge)
    H = _lagged(uh, L)[rows]
    G = H.T @ H
    theta = np.linalg.solve(
        G + ridge * np.trace(G) / G.shape[0] * np.eye(G.shape[0]), H.T @ zh[rows]
    )
    res = zh[rows] - H @ theta
    r2 = 1.0 - float((res**2).sum()) / max(float((zh[rows] ** 2).sum()), 1e-300)
    # the FIR on the original grid: u_e resampled at fs is exact for its band (<= 5 Hz < fs / 2)
    ze_g = _lagged(ug, L) @ theta
    z_e = np.column_stack([np.interp(t, tg, ze_g[:, k]) for k in range(ze_g.shape[1])])
    return z_e, {
        "fit_r2": float(r2),
        "fir_peak_gain": _peak_gain(theta.reshape(L, ne, -1), ug, fs, f_cut),
        "window_s": [float(tg[rows.start]), float(tg[rows.stop - 1])],
        "f_cut_hz": float(f_cut),
        "lags_s": float(lags_s),
        "lags": int(L),
        "fs_hz": float(fs),
    }


def _lagged(u: np.ndarray, L: int) -> np.ndarray:
    """Regressor matrix ``[u(k), u(k-1), ..., u(k-L+1)]`` (zeros before the start)."""
    m, ne = u.shape
    H = np.zeros((m, ne * L))
    for lag in range(L):
        H[lag:, lag * ne : (lag + 1) * ne] = u[: m - lag]
    return H


def _peak_gain(h: np.ndarray, ug: np.ndarray, fs: float, f_cut: float) -> float:
    """Largest singular value of the FIR ``h[lag, input, output]`` at the frequencies where
    ``ug`` has >= 5 % of its strongest bin's power, above ``f_cut``."""
    L = h.shape[0]
    spec = (np.abs(np.fft.rfft(ug, axis=0)) ** 2).sum(axis=1)
    fb = np.fft.rfftfreq(ug.shape[0], 1.0 / fs)
    smax = 0.0
    for f in fb[(spec >= 0.05 * spec.max()) & (fb > f_cut)]:
        Hf = np.tensordot(np.exp(-2j * np.pi * f * np.arange(L) / fs), h, axes=(0, 0)).T
        smax = max(smax, float(np.linalg.svd(Hf, compute_uv=False)[0]))
    return smax
