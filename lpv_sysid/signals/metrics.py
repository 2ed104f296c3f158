"""Quality metrics of excitation signals (seed 0 Sec. V, Figs. 5-7; Morelli 2021).

* relative peak factor, ``RPF = (max - min) / (2 sqrt(2) rms)`` (SIDPAC ``peakfactor``):
  1 for a single sinusoid, 1/sqrt(2) for a square wave, sqrt(3/2) for a triangle wave;
* correlation coefficient matrix of the channels (seed 0 Fig. 7);
* one-sided power spectra by FFT over an integer number of periods (seed 0 Fig. 6), so a
  periodic multisine shows power only in the bins of its harmonics;
* harmonic content: fraction of each channel's energy outside its allocated harmonics.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from lpv_sysid.errors import ConfigError


def rms(x: np.ndarray, axis: int = 0) -> np.ndarray:
    """Root mean square about zero (not about the mean), as SIDPAC's ``rms``."""
    x = np.asarray(x, dtype=float)
    return np.sqrt(np.mean(x * x, axis=axis))


def relative_peak_factor(x: np.ndarray, axis: int = 0) -> np.ndarray | float:
    """``RPF = (max(x) - min(x)) / (2 sqrt(2) rms(x))`` along ``axis`` (Morelli 2021).

    A constant-zero channel has no defined RPF and raises :class:`ConfigError`.
    """
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        raise ConfigError("relative_peak_factor: empty signal")
    r = rms(x, axis=axis)
    if np.any(r == 0.0):
        raise ConfigError("relative_peak_factor: a channel is identically zero")
    out = (np.max(x, axis=axis) - np.min(x, axis=axis)) / (2.0 * np.sqrt(2.0) * r)
    return float(out) if np.ndim(out) == 0 else out


def correlation_matrix(u: np.ndarray) -> np.ndarray:
    """Correlation coefficients of the columns of ``u`` (N, n) (seed 0 Fig. 7)."""
    u = np.asarray(u, dtype=float)
    if u.ndim != 2 or u.shape[0] < 2:
        raise ConfigError(f"correlation_matrix: expected (N>=2, n) samples, got shape {u.shape}")
    return np.atleast_2d(np.corrcoef(u, rowvar=False))


def max_cross_correlation(u: np.ndarray) -> float:
    """Largest ``|corr|`` between two different channels (0 for one channel)."""
    c = correlation_matrix(u)
    if c.shape[0] < 2:
        return 0.0
    off = c - np.diag(np.diag(c))
    return float(np.max(np.abs(off)))


def power_spectrum(u: np.ndarray, sample_rate: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectrum of each column of ``u`` (N, n) over its N samples.

    ``u`` must span an integer number of periods of the signal so the harmonics fall in
    bins exactly. Returns ``(f (N//2+1,), P (N//2+1, n))`` where ``P[k]`` is the mean-square
    contribution of bin k (a sinusoid of amplitude a in bin k, 0 < k < N/2, gives a^2/2);
    ``sum(P) == mean(u^2)`` (Parseval).
    """
    u = np.asarray(u, dtype=float)
    if u.ndim == 1:
        u = u[:, None]
    n = u.shape[0]
    if n < 2:
        raise ConfigError("power_spectrum: need at least 2 samples")
    X = np.fft.rfft(u, axis=0) / n
    P = np.abs(X) ** 2
    P[1:] *= 2.0
    if n % 2 == 0:
        P[-1] /= 2.0  # the Nyquist bin is not doubled
    f = np.fft.rfftfreq(n, d=1.0 / sample_rate)
    return f, P


@dataclass(frozen=True)
class HarmonicContent:
    """Energy bookkeeping of one channel against its allocated harmonics."""

    allocated_fraction: float  # share of the channel's power in its own harmonics
    leakage_fraction: float  # share anywhere else (numerical zero for a clean design)
    foreign_fraction: float  # share in harmonics allocated to *other* channels


def harmonic_content(
    u: np.ndarray, harmonics: Sequence[Sequence[int] | np.ndarray]
) -> list[HarmonicContent]:
    """Check that channel j of ``u`` (N, n, one period) has power only at ``harmonics[j]``."""
    u = np.asarray(u, dtype=float)
    if u.ndim == 1:
        u = u[:, None]
    if len(harmonics) != u.shape[1]:
        raise ConfigError(
            f"harmonic_content: {len(harmonics)} harmonic sets for {u.shape[1]} channels"
        )
    _, P = power_spectrum(u, 1.0)
    total = P.sum(axis=0)
    out = []
    for j, h in enumerate(harmonics):
        own_mask = np.zeros(P.shape[0], dtype=bool)
        own_mask[np.asarray(h, dtype=int)] = True
        others = [np.asarray(k, dtype=int) for i, k in enumerate(harmonics) if i != j]
        foreign = P[np.concatenate(others), j].sum() if others else 0.0
        tot = total[j] if total[j] > 0 else 1.0
        # the complement is summed directly (not total - own) so round-off does not mask leakage
        out.append(
            HarmonicContent(
                float(P[own_mask, j].sum() / tot),
                float(P[~own_mask, j].sum() / tot),
                float(foreign / tot),
            )
        )
    return out
