"""Excitation normalisation and H-infinity weights of seed 0 Sec. V, Eqs. (26)-(28).

* Eq. (26): the normalised excitation u_e has unit energy, ``sqrt(int_0^T u_e^T u_e dt) = 1``.
* Eq. (27): ``R = sqrt(n_u T / 2) diag(Delta_t, Delta_a, Delta_e, Delta_r)`` (n_u = 4), so
  that with the energy split evenly over the channels, ``R u_e`` has per-channel magnitude
  Delta (the amplitude of a sinusoid of that energy: a = sqrt(2 / (n_u T))).
* Eq. (28): ``Q = sqrt(n_z T) diag(Delta_u, Delta_v, Delta_w)`` (n_z = 3), so a step of
  Delta on each velocity lasting T gives a performance output z = Q^-1 dv of unit energy.

Energies are integrals over one period of a periodic signal sampled on the uniform grid
``t_n = n / fs``; the rectangle rule ``dt * sum_n x_n^2`` is exact there for every
trigonometric polynomial whose harmonics lie below Nyquist.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from lpv_sysid.errors import ConfigError


def energy(u: np.ndarray, dt: float) -> float:
    """``sqrt(int_0^T u^T u dt)`` for samples ``u`` (N,) or (N, n) of one period (Eq. 26)."""
    u = np.asarray(u, dtype=float)
    if not np.all(np.isfinite(u)):
        raise ConfigError("energy: signal contains NaN or inf")
    return float(np.sqrt(dt * np.sum(u * u)))


def channel_energy_scales(
    u: np.ndarray, dt: float, total: float = 1.0, power_fraction: Sequence[float] | None = None
) -> np.ndarray:
    """Per-channel factors s_j so that ``u * s`` has energy ``total`` (Eq. 26 for total = 1)
    with a share ``power_fraction[j]`` of ``total^2`` in channel j (even split by default)."""
    u = np.atleast_2d(np.asarray(u, dtype=float).T).T
    n = u.shape[1]
    pf = np.full(n, 1.0 / n) if power_fraction is None else np.asarray(power_fraction, dtype=float)
    if pf.shape != (n,) or np.any(pf <= 0) or abs(pf.sum() - 1.0) > 1e-9:
        raise ConfigError(
            f"power_fraction: need {n} positive values summing to 1, got {pf.tolist()}"
        )
    e = np.sqrt(dt * np.sum(u * u, axis=0))
    if np.any(e == 0):
        raise ConfigError("channel_energy_scales: a channel is identically zero")
    return total * np.sqrt(pf) / e


def excitation_weight(magnitudes: Sequence[float], duration: float) -> np.ndarray:
    """``R = sqrt(n_u T / 2) diag(Delta)`` of seed 0 Eq. (27), n_u = len(Delta)."""
    d = _positive(magnitudes, "excitation_magnitudes")
    T = _positive([duration], "duration")[0]
    return np.sqrt(d.size * T / 2.0) * np.diag(d)


def performance_weight(magnitudes: Sequence[float], duration: float) -> np.ndarray:
    """``Q = sqrt(n_z T) diag(Delta_u, Delta_v, Delta_w)`` of seed 0 Eq. (28), n_z = len(Delta)."""
    d = _positive(magnitudes, "velocity_magnitudes")
    T = _positive([duration], "duration")[0]
    return np.sqrt(d.size * T) * np.diag(d)


def _positive(v: Sequence[float], name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).ravel()
    if a.size == 0 or not np.all(np.isfinite(a)) or np.any(a <= 0):
        raise ConfigError(f"{name}: need positive finite values, got {list(np.ravel(v))}")
    return a
