"""The multisine design (:func:`design`): harmonics per channel (:func:`allocate_harmonics`),
amplitudes and phases, the :class:`SignalSet`; the method is the
:mod:`lpv_sysid.signals.multisine` docstring."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.signals.multisine.config import GroupConfig, SignalsConfig
from lpv_sysid.signals.multisine.phase_opt import (
    optimise_phases,
    rpf_of,
    schroeder_phases,
    synthesize,
    zero_start_shift,
)
from lpv_sysid.signals.weights import channel_energy_scales, excitation_weight, performance_weight

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SignalSet:
    """A designed multisine set: ``u[:, j]`` sampled at ``t`` (one period, N samples)."""

    t: np.ndarray  # (N,), t_n = n / fs, n = 0..N-1
    u: np.ndarray  # (N, n)
    names: tuple[str, ...]
    groups: tuple[str, ...]  # group name of each channel
    bands: tuple[tuple[float, float], ...]  # configured band of each channel, Hz
    harmonics: tuple[np.ndarray, ...]  # harmonic indices h_k of f0 per channel
    amplitudes: tuple[np.ndarray, ...]  # a_k per channel, in the channel's final scale
    phases: tuple[np.ndarray, ...]  # phi_k per channel (after the time shift)
    rpf: np.ndarray  # optimised RPF per channel
    rpf_schroeder: np.ndarray  # RPF with Schroeder phases only
    sample_rate: float
    duration: float
    R: Optional[np.ndarray] = None  # Eq. (27), when configured
    Q: Optional[np.ndarray] = None  # Eq. (28), when configured

    @property
    def f0(self) -> float:
        return 1.0 / self.duration

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ConfigError(
                f"signal set has no channel {name!r}; channels are {list(self.names)}"
            ) from None

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        """Exact sum of sinusoids at arbitrary times ``t`` (K,) -> (K, n); periodic in T."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.empty((t.size, len(self.names)))
        w0 = 2.0 * np.pi / self.duration
        for j, (h, a, p) in enumerate(zip(self.harmonics, self.amplitudes, self.phases)):
            out[:, j] = np.cos(w0 * np.outer(t, h) + p) @ a
        return out


def allocate_harmonics(
    groups: tuple[GroupConfig, ...], duration: float, sample_rate: float
) -> list[np.ndarray]:
    """Interleaved allocation of harmonic indices (seed 0 Sec. V): one array per channel,
    in the order of ``groups``/``channels``. Harmonics in a band that an earlier group
    already holds are skipped, so bands that share an edge (``[0.01, 0.5]`` then
    ``[0.5, 5]``) give ``(0.5, 5]`` to the second group."""
    n = int(round(duration * sample_rate))
    f0 = 1.0 / duration
    k_all = np.arange(1, (n - 1) // 2 + 1)  # strictly below Nyquist
    taken = np.zeros(k_all.size + 1, dtype=bool)
    out: list[np.ndarray] = []
    tol = 1e-9 * f0
    for g in groups:
        f = k_all * f0
        ks = k_all[(f >= g.band[0] - tol) & (f <= g.band[1] + tol) & ~taken[k_all]]
        nc = len(g.channels)
        if ks.size < nc:
            raise ConfigError(
                f"group {g.name!r}: band {list(g.band)} Hz holds {ks.size} free harmonics of "
                f"f0 = {f0:g} Hz for {nc} channels; widen the band or lengthen the duration"
            )
        taken[ks] = True
        out.extend(ks[j::nc].copy() for j in range(nc))
    return out


def _channel_amplitudes(h: np.ndarray, f0: float, spectrum) -> np.ndarray:
    if not spectrum:
        return np.ones(h.size)
    fb = np.array([p[0] for p in spectrum])
    ab = np.array([p[1] for p in spectrum])
    a = np.interp(h * f0, fb, ab)
    if not np.any(a > 0):
        raise ConfigError("spectrum: zero amplitude at every allocated harmonic")
    return a


def design(config: SignalsConfig) -> SignalSet:
    """Design the orthogonal phase-optimised multisine set of ``config`` (steps 1-4 above)."""
    T, fs = config.duration, config.sample_rate
    n = config.n_samples
    f0 = 1.0 / T
    dt = 1.0 / fs
    harmonics = allocate_harmonics(config.groups, T, fs)
    names, gnames, amps, phases, rpf, rpf0 = [], [], [], [], [], []
    bands: list[tuple[float, float]] = []
    u = np.empty((n, len(harmonics)))
    j = 0
    for g in config.groups:
        cols = []
        for c in g.channels:
            h = harmonics[j]
            a = _channel_amplitudes(h, f0, g.spectra.get(c))
            a = a / np.sqrt(0.5 * np.sum(a * a))  # unit rms before scaling
            phi_s = schroeder_phases(a)
            rpf0.append(rpf_of(synthesize(n, h, a, phi_s)))
            phi, r = optimise_phases(n, h, a, phi_s, config.optimisation)
            x = synthesize(n, h, a, phi)
            s = zero_start_shift(x)
            phi = np.mod(phi + 2.0 * np.pi * h * s / n, 2.0 * np.pi)
            u[:, j] = synthesize(n, h, a, phi)
            rpf.append(rpf_of(u[:, j]))
            log.debug(
                "channel %s: %d harmonics, RPF %.4f (Schroeder %.4f)", c, h.size, rpf[-1], rpf0[-1]
            )
            names.append(c)
            gnames.append(g.name)
            bands.append((float(g.band[0]), float(g.band[1])))
            amps.append(a)
            phases.append(phi)
            cols.append(j)
            j += 1
        if g.energy is not None:
            scale = channel_energy_scales(u[:, cols], dt, g.energy, g.power_fraction)
        else:
            peak = g.peak if g.peak is not None else (1.0,) * len(cols)
            scale = np.asarray(peak) / np.max(np.abs(u[:, cols]), axis=0)
        for k, col in enumerate(cols):
            u[:, col] *= scale[k]
            amps[col] = amps[col] * scale[k]
    R = Q = None
    w = config.weights
    if w.excitation_magnitudes is not None:
        R = excitation_weight(w.excitation_magnitudes, T)
    if w.velocity_magnitudes is not None:
        Q = performance_weight(w.velocity_magnitudes, T)
    return SignalSet(
        t=np.arange(n) * dt,
        u=u,
        names=tuple(names),
        groups=tuple(gnames),
        bands=tuple(bands),
        harmonics=tuple(harmonics),
        amplitudes=tuple(amps),
        phases=tuple(phases),
        rpf=np.asarray(rpf),
        rpf_schroeder=np.asarray(rpf0),
        sample_rate=fs,
        duration=T,
        R=R,
        Q=Q,
    )
