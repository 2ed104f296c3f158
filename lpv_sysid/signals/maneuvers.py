"""Deterministic validation manoeuvres: frequency sweep (chirp), doublet, 3-2-1-1.

The 3-2-1-1 and doublet are the classic flight-test inputs (Morelli & Klein, Aircraft System
Identification, Ch. 9): square pulses of alternating sign with widths 3, 2, 1, 1 (resp. 1, 1)
times a base pulse width. The sweep uses ``scipy.signal.chirp``.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import chirp

from lpv_sysid.errors import ConfigError


def _grid(duration: float, sample_rate: float) -> np.ndarray:
    if not (
        np.isfinite(duration) and duration > 0 and np.isfinite(sample_rate) and sample_rate > 0
    ):
        raise ConfigError(
            f"manoeuvre: duration and sample_rate must be positive, got {duration}, {sample_rate}"
        )
    return np.arange(int(round(duration * sample_rate))) / sample_rate


def sweep(
    duration: float,
    sample_rate: float,
    f_start: float,
    f_end: float,
    amplitude: float = 1.0,
    method: str = "logarithmic",
) -> tuple[np.ndarray, np.ndarray]:
    """Frequency sweep from ``f_start`` to ``f_end`` Hz over ``duration`` (scipy.signal.chirp),
    starting at zero (phase -90 deg: a sine)."""
    if method not in ("linear", "logarithmic", "quadratic", "hyperbolic"):
        raise ConfigError(f"sweep: unknown method {method!r}")
    if f_start <= 0 or f_end <= 0 or max(f_start, f_end) >= sample_rate / 2:
        raise ConfigError(
            f"sweep: frequencies must be in (0, {sample_rate / 2}) Hz, got {f_start}, {f_end}"
        )
    t = _grid(duration, sample_rate)
    return t, amplitude * chirp(t, f_start, duration, f_end, method=method, phi=-90.0)


def pulse_train(
    widths: tuple[float, ...],
    signs: tuple[float, ...],
    pulse_width: float,
    amplitude: float,
    sample_rate: float,
    start: float = 0.0,
    duration: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive square pulses ``signs[i] * amplitude`` lasting ``widths[i] * pulse_width``
    seconds after ``start``, zero elsewhere; ``duration`` defaults to the end of the train +
    start."""
    if pulse_width <= 0 or start < 0:
        raise ConfigError(
            f"pulse train: pulse_width must be > 0 and start >= 0, got {pulse_width}, {start}"
        )
    total = start + pulse_width * sum(widths)
    duration = 2.0 * start + pulse_width * sum(widths) if duration is None else duration
    if duration < total - 1e-12:
        raise ConfigError(
            f"pulse train: duration {duration} s shorter than the manoeuvre {total} s"
        )
    t = _grid(duration, sample_rate)
    x = np.zeros_like(t)
    # sample n belongs to a pulse when start + a <= t_n < start + b (1e-9 guards round-off)
    edge = start
    for w, s in zip(widths, signs):
        end = edge + w * pulse_width
        x[(t >= edge - 1e-9) & (t < end - 1e-9)] = s * amplitude
        edge = end
    return t, x


def doublet(
    pulse_width: float,
    amplitude: float,
    sample_rate: float,
    start: float = 0.0,
    duration: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Doublet: +A for one pulse width, then -A for one pulse width."""
    return pulse_train((1, 1), (1.0, -1.0), pulse_width, amplitude, sample_rate, start, duration)


def maneuver_3211(
    pulse_width: float,
    amplitude: float,
    sample_rate: float,
    start: float = 0.0,
    duration: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """3-2-1-1: +A for 3 dt_p, -A for 2 dt_p, +A for 1 dt_p, -A for 1 dt_p."""
    return pulse_train(
        (3, 2, 1, 1), (1.0, -1.0, 1.0, -1.0), pulse_width, amplitude, sample_rate, start, duration
    )
