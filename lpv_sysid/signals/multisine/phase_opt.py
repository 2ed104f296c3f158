"""Phase optimisation of one multisine channel (Schroeder 1970; Morelli 2021, SIDPAC mkmsswp).

A channel is ``x_n = sum_k a_k cos(2 pi h_k n / N + phi_k)``, n = 0..N-1, on the uniform
grid of one period T = N / fs, with harmonic indices ``h_k`` of f0 = 1/T. Its rms is fixed by
the amplitudes (Parseval, ``rms^2 = sum a_k^2 / 2``), so minimising the relative peak
factor ``RPF = (max x - min x) / (2 sqrt(2) rms)`` is minimising the peak-to-peak range.

Because ``max x - min x = 2 min_c max_n |x_n - c|``, the range is a Chebyshev norm, and it
is approached, after a few iterations of clipping (Van der Ouderaa et al. 1988) from the
Schroeder start, by minimising the smooth p-norm ``(mean |x_n - c|^p)^(1/p)`` over the phases
and the offset ``c`` with p increasing (the L_p continuation of Guillaume et al. 1991, which
SIDPAC's iterative peak-factor minimisation also approximates). Each stage is a
``scipy.optimize.minimize(method="L-BFGS-B")`` with the analytic gradient; signal and
gradient both cost one real FFT, because ``d x_n / d phi_k = -a_k sin(2 pi h_k n/N + phi_k)``
gives ``sum_n g_n dx_n/dphi_k = -a_k Im(exp(i phi_k) conj(G_{h_k}))`` with ``G = rfft(g)``.
The RPF is evaluated on the sample grid, i.e. on the signal that is actually commanded.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import fft as sfft

from lpv_sysid.configuration import fields as cf


def synthesize(
    n_samples: int, harmonics: np.ndarray, amplitudes: np.ndarray, phases: np.ndarray
) -> np.ndarray:
    """``x_n = sum_k a_k cos(2 pi h_k n / N + phi_k)`` by one inverse real FFT."""
    X = np.zeros(n_samples // 2 + 1, dtype=complex)
    X[harmonics] = 0.5 * n_samples * amplitudes * np.exp(1j * phases)
    return sfft.irfft(X, n=n_samples)


def schroeder_phases(amplitudes: np.ndarray, phi1: float = 0.0) -> np.ndarray:
    """Schroeder (1970) phases for the component powers ``p_k = a_k^2 / sum a^2``:

    ``phi_k = phi_1 - 2 pi sum_{i<k} (k - i) p_i`` (k = 1..M), which reduces to
    ``phi_k = phi_1 - pi k (k-1) / M`` (up to a linear term) for a flat spectrum.
    Component k is the k-th allocated harmonic of the channel, as in SIDPAC mkmsswp.
    """
    a = np.asarray(amplitudes, dtype=float)
    p = a * a / np.sum(a * a)
    m = a.size
    k = np.arange(1, m + 1)
    phi = np.empty(m)
    for j in range(m):  # O(M^2) with M <= a few hundred: negligible next to the optimiser
        i = np.arange(1, j + 1)
        phi[j] = phi1 - 2.0 * np.pi * np.sum((k[j] - i) * p[:j])
    return np.mod(phi, 2.0 * np.pi)


def rpf_of(x: np.ndarray) -> float:
    return float((x.max() - x.min()) / (2.0 * np.sqrt(2.0) * np.sqrt(np.mean(x * x))))


@dataclass(frozen=True)
class PhaseOptOptions:
    """Options of :func:`optimise_phases` (config key ``optimisation``), declared once.

    >>> PhaseOptOptions.from_dict({"max_iter": 10}).max_iter
    10
    """

    p_stages: tuple[float, ...] = cf.numbers(
        (4.0, 16.0, 64.0, 256.0, 1024.0), "exponents p of the L_p crest-factor stages", lo=2.0
    )
    max_iter: int = cf.count(150, "L-BFGS-B iterations per stage", hi=100_000)
    clip_iter: int = cf.count(
        100, "iterative-clipping iterations before the L_p stages", hi=100_000
    )
    clip_level: float = cf.number(
        0.9,
        "clipping level, fraction of the current half range",
        lo=0.0,
        lo_open=True,
        hi=1.0,
        hi_open=True,
    )
    restarts: int = cf.count(3, "extra starts from random phases (best kept)", hi=1_000)
    restart_max_harmonics: int = cf.count(
        40, "restarts only for channels with at most this many harmonics"
    )
    seed: int = cf.count(0, "seed of the random restarts")

    def __post_init__(self) -> None:
        cf.normalize_fields(self, "optimisation")

    @classmethod
    def from_dict(cls, d: Any, where: str = "optimisation") -> "PhaseOptOptions":
        return cls(**cf.parse_fields(cls, d, where))


class _PNormObjective:
    """``f(phi, c) = (mean |x_n(phi) - c|^p)^(1/p)`` and its gradient, one FFT each way."""

    def __init__(self, n: int, h: np.ndarray, a: np.ndarray, p: float):
        self.n, self.h, self.a, self.p = n, h, a, p
        self.X = np.zeros(n // 2 + 1, dtype=complex)
        self.scale = 0.5 * n * a
        self.threshold = 10.0 ** (-30.0 / p)

    def __call__(self, z: np.ndarray) -> tuple[float, np.ndarray]:
        phi, c = z[:-1], z[-1]
        e = np.exp(1j * phi)
        self.X[self.h] = self.scale * e
        y = sfft.irfft(self.X, n=self.n) - c
        ay = np.abs(y)
        m = ay.max()
        # Only samples with (|y|/max)^p > 1e-30 contribute: skipping the rest is exact to
        # 1e-30 relative and avoids subnormal arithmetic (which made pow() 20x slower).
        act = np.flatnonzero(ay > m * self.threshold)
        s = np.sum((ay[act] / m) ** self.p) / self.n
        f = m * s ** (1.0 / self.p)
        g = np.zeros(self.n)
        g[act] = (ay[act] / f) ** (self.p - 1.0) * np.sign(y[act]) / self.n  # df/dy_n
        G = sfft.rfft(g)
        grad = np.empty_like(z)
        grad[:-1] = -self.a * np.imag(e * np.conj(G[self.h]))
        grad[-1] = -g.sum()
        return float(f), grad


def clip_phases(n: int, h: np.ndarray, a: np.ndarray, phi: np.ndarray, iters: int, level: float):
    """Iterative clipping (Van der Ouderaa, Schoukens & Renneboog 1988).

    Clip the signal at ``level`` of its half range about the mid-range, take the phases of
    the clipped signal's FFT at the allocated harmonics, keep the amplitudes; repeat.
    Returns the phases of the lowest RPF seen and that RPF.
    """
    best_phi, best = phi, rpf_of(synthesize(n, h, a, phi))
    for _ in range(iters):
        x = synthesize(n, h, a, phi)
        mid, half = 0.5 * (x.max() + x.min()), 0.5 * (x.max() - x.min())
        phi = np.angle(sfft.rfft(np.clip(x, mid - level * half, mid + level * half))[h])
        val = rpf_of(synthesize(n, h, a, phi))
        if val < best:
            best_phi, best = phi, val
    return best_phi, best


def _optimise_from(n, h, a, phi0, options) -> tuple[np.ndarray, float]:
    from scipy.optimize import minimize  # here: scipy.optimize costs ~0.1 s to import

    best_phi, best = clip_phases(n, h, a, phi0, options.clip_iter, options.clip_level)
    z = np.concatenate([best_phi, [0.0]])
    for p in options.p_stages:
        obj = _PNormObjective(n, h, a, p)
        res = minimize(
            obj,
            z,
            jac=True,
            method="L-BFGS-B",
            options={"maxiter": options.max_iter, "gtol": 1e-12, "ftol": 1e-13},
        )
        z = res.x
        val = rpf_of(synthesize(n, h, a, z[:-1]))
        if val < best:
            best_phi, best = np.mod(z[:-1], 2 * np.pi), val
    return best_phi, best


def optimise_phases(
    n_samples: int,
    harmonics: np.ndarray,
    amplitudes: np.ndarray,
    phases0: np.ndarray,
    options: PhaseOptOptions = PhaseOptOptions(),
) -> tuple[np.ndarray, float]:
    """Minimise the sampled RPF of one channel over its phases; returns ``(phases, rpf)``.

    Starts from ``phases0`` (Schroeder) and, for channels of at most
    ``options.restart_max_harmonics`` harmonics, ``options.restarts`` random phase vectors
    (with many harmonics the Schroeder start beat every random start in our trials, with
    few harmonics random starts often find a better optimum); from each start runs iterative
    clipping,
    then the L_p continuation of the module docstring, and keeps the phases of the lowest
    sampled RPF seen (never worse than the start). A single sinusoid is returned as is.
    """
    h = np.asarray(harmonics, dtype=int)
    a = np.asarray(amplitudes, dtype=float)
    phi0 = np.asarray(phases0, dtype=float)
    if h.size <= 1 or options.max_iter == 0:
        return phi0.copy(), rpf_of(synthesize(n_samples, h, a, phi0))
    rng = np.random.default_rng(options.seed)
    best_phi, best = _optimise_from(n_samples, h, a, phi0, options)
    n_restarts = options.restarts if h.size <= options.restart_max_harmonics else 0
    for _ in range(n_restarts):
        start = rng.uniform(0.0, 2.0 * np.pi, size=phi0.size)
        phi, val = _optimise_from(n_samples, h, a, start, options)
        if val < best:
            best_phi, best = phi, val
    return best_phi, best


def zero_start_shift(x: np.ndarray) -> int:
    """Sample shift s so ``x[(n + s) % N]`` starts and ends near zero.

    Among the upward zero crossings ``x[s-1] < 0 <= x[s]`` (the wrap from the last sample
    to the first one of the shifted period) picks the one that minimises
    ``max(|x[s-1]|, |x[s]|)``, so both the first and the last sample are close to zero. A
    circular shift by whole samples keeps the sampled values (and so the RPF and the
    harmonic content) exactly. Like SIDPAC mkmsswp's time shift to a zero crossing.
    """
    prev = np.roll(x, 1)
    cand = np.flatnonzero((prev < 0.0) & (x >= 0.0))
    if cand.size == 0:
        return int(np.argmin(np.abs(x)))
    return int(cand[np.argmin(np.maximum(np.abs(x[cand]), np.abs(prev[cand])))])
