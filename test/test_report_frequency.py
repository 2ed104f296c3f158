"""The report's frequency-response view (issue 23 item 3): the Welch MIMO estimate of
``S_yu S_uu^-1`` on a linear system simulated here with orthogonal multisines equals the
system's ``(jwI - A)^-1 B`` at each channel's harmonics, with coherence ~1 (noise-free)."""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from lpv_sysid.report.sections_phase1 import model_response, spectral_estimate


def test_spectral_estimate_recovers_the_frequency_response():
    rng = np.random.default_rng(7)
    n, m, fs, T = 6, 4, 100.0, 200.0
    A = 0.3 * rng.normal(size=(n, n))
    A -= (np.max(np.linalg.eigvals(A).real) + 1.0) * np.eye(n)
    B = rng.normal(size=(n, m))
    t = np.arange(int(T * fs)) / fs
    df = 0.05  # period 20 s; Welch segments of two periods: lines on even bins, Hann leakage
    # only to the odd ones (a segment of one period would spread each line onto the
    # neighbouring harmonics of the other channels)
    harm = {j: [k for k in range(3, 40) if k % m == j] for j in range(m)}  # orthogonal
    u = np.column_stack(
        [sum(np.cos(2 * np.pi * k * df * t + 0.3 * k * k) for k in harm[j]) for j in range(m)]
    )
    E = expm(np.block([[A, B], [np.zeros((m, n + m))]]) / fs)
    # first-order hold inputs (trapezoid) make the sampled response match the continuous one
    Phi, Gam = E[:n, :n], E[:n, n:]
    x = np.zeros((t.size, n))
    for k in range(1, t.size):
        x[k] = Phi @ x[k - 1] + Gam @ (0.5 * (u[k - 1] + u[k]))
    f, H, coh, share = spectral_estimate(x[2000:], u[2000:], fs, 4000)
    G = model_response(A, B, f)
    for j in range(m):
        bins = [int(round(k * df / (f[1] - f[0]))) for k in harm[j]]
        assert np.all(share[bins, j] > 0.99)
        rel = np.abs(H[bins, :, j] - G[bins, :, j]) / np.abs(G[bins, :, j])
        assert np.max(rel) < 0.02, np.max(rel)
        assert np.min(coh[bins]) > 0.999
