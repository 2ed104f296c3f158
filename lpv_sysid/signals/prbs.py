"""Pseudo-random binary sequences (seed 1 Sec. 3.4).

Two variants:

* :func:`prbs` - the two-level excitation of seed 1 Sec. 3.4 characterised by an amplitude
  and a minimum/maximum switching interval (its bandwidth): the level alternates between
  +amplitude and -amplitude and each hold time is drawn uniformly from the whole-sample
  multiples of dt in [min_interval, max_interval]. A seed makes it reproducible.
* :func:`mls` - the maximal-length LFSR sequence (m-sequence) of ``scipy.signal.max_len_seq``,
  period ``N = 2^nbits - 1``, whose periodic autocorrelation is 1 at lag 0 and exactly
  ``-1/N`` at every other lag; each bit is held for ``samples_per_bit`` samples.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import max_len_seq

from lpv_sysid.errors import ConfigError


def prbs(
    duration: float,
    sample_rate: float,
    amplitude: float,
    min_interval: float,
    max_interval: float,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Random binary signal ``(t (N,), x (N,))`` with switching intervals in [min, max] s.

    Hold times are integer numbers of samples m with ``min_interval <= m dt <= max_interval``
    (at least one such m must exist); the first level's sign is drawn from the seed too.
    """
    for name, v in (
        ("duration", duration),
        ("sample_rate", sample_rate),
        ("amplitude", amplitude),
        ("min_interval", min_interval),
        ("max_interval", max_interval),
    ):
        if not np.isfinite(v) or v <= 0:
            raise ConfigError(f"prbs: {name} must be positive and finite, got {v}")
    if max_interval < min_interval:
        raise ConfigError(f"prbs: max_interval {max_interval} < min_interval {min_interval}")
    dt = 1.0 / sample_rate
    m_lo = int(np.ceil(min_interval / dt - 1e-9))
    m_hi = int(np.floor(max_interval / dt + 1e-9))
    m_lo = max(m_lo, 1)
    if m_hi < m_lo:
        raise ConfigError(
            f"prbs: no whole number of samples (dt = {dt} s) lies in "
            f"[{min_interval}, {max_interval}] s"
        )
    n = int(round(duration * sample_rate))
    if n < 1:
        raise ConfigError(f"prbs: duration {duration} s is shorter than one sample")
    rng = np.random.default_rng(seed)
    level = 1.0 if rng.random() < 0.5 else -1.0
    x = np.empty(n)
    i = 0
    while i < n:
        m = int(rng.integers(m_lo, m_hi + 1))
        x[i : i + m] = level
        level = -level
        i += m
    return np.arange(n) * dt, amplitude * x


def switching_intervals(x: np.ndarray, dt: float) -> np.ndarray:
    """Lengths (s) of the complete constant runs of ``x`` (first and last run excluded)."""
    x = np.asarray(x)
    edges = np.flatnonzero(np.diff(x) != 0) + 1
    return np.diff(edges) * dt


def mls(nbits: int, amplitude: float = 1.0, samples_per_bit: int = 1, state=None) -> np.ndarray:
    """One period of the maximal-length sequence of ``nbits`` mapped to +-amplitude.

    ``state`` (nbits 0/1 values, not all zero) selects the starting point - a cyclic shift.
    """
    if isinstance(nbits, bool) or not isinstance(nbits, (int, np.integer)) or not 2 <= nbits <= 32:
        raise ConfigError(f"mls: nbits must be an integer in [2, 32], got {nbits!r}")
    if samples_per_bit < 1:
        raise ConfigError(f"mls: samples_per_bit must be >= 1, got {samples_per_bit}")
    if state is not None:
        state = np.asarray(state, dtype=np.int8)
        if state.shape != (nbits,) or not np.any(state):
            raise ConfigError(f"mls: state must be {nbits} bits, not all zero")
    seq, _ = max_len_seq(int(nbits), state=state)
    x = amplitude * (2.0 * seq.astype(float) - 1.0)
    return np.repeat(x, samples_per_bit)


def periodic_autocorrelation(x: np.ndarray) -> np.ndarray:
    """``r[k] = (1/N) sum_n x_n x_{(n+k) mod N} / (mean x^2)`` for k = 0..N-1, by FFT."""
    x = np.asarray(x, dtype=float)
    X = np.fft.fft(x)
    r = np.real(np.fft.ifft(X * np.conj(X))) / x.size
    return r / r[0]
