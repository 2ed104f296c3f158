"""Orthogonal phase-optimised multisines (seed 0 Sec. V): allocation, orthogonality, spectra,
RPF, normalisation (Eq. 26) and the weights R, Q (Eqs. 27-28), against independent oracles."""

import os

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError
from lpv_sysid.signals import metrics
from lpv_sysid.signals.multisine import (
    SignalsConfig,
    allocate_harmonics,
    design,
    load_config,
    schroeder_phases,
    synthesize,
)
from lpv_sysid.signals.weights import energy, excitation_weight, performance_weight

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DELTA_E = [0.05, 0.01, 0.02, 0.04]
DELTA_V = [1.0, 2.0, 0.5]

# Small phase-2-like design: T = 40 s, 25 Hz (N = 1000). Reference band [0.025, 0.5] Hz holds
# harmonics 1..20 -> 7/7/6 per channel (>= 5); excitation band (0.5, 5] Hz holds 21..200 ->
# 45 per channel (>= 30).
SMALL = {
    "duration": 40.0,
    "sample_rate": 25.0,
    "groups": [
        {
            "name": "reference",
            "channels": ["u_d", "v_d", "w_d"],
            "band": [0.025, 0.5],
            "peak": [5.0, 4.0, 3.0],
        },
        {
            "name": "excitation",
            "channels": ["ue_t", "ue_a", "ue_e", "ue_r"],
            "band": [0.5, 5.0],
            "energy": 1.0,
            "power_fraction": [0.25, 0.25, 0.25, 0.25],
        },
    ],
    "weights": {
        "group": "excitation",
        "excitation_magnitudes": DELTA_E,
        "velocity_magnitudes": DELTA_V,
    },
}


@pytest.fixture(scope="module")
def phase2():
    return design(load_config(os.path.join(ROOT, "config", "signals_phase2.yaml")))


@pytest.fixture(scope="module")
def sig():
    return design(SignalsConfig.from_dict(SMALL))


# ---------------------------------------------------------------- RPF function, hand-computed
def test_rpf_of_sine_square_triangle_by_hand():
    n = 400
    t = np.arange(n) / n
    # a sine sampled at its peaks: (max - min) = 2a, rms = a / sqrt(2) -> RPF = 1
    assert metrics.relative_peak_factor(3.0 * np.sin(2 * np.pi * 5 * t)) == pytest.approx(
        1.0, abs=1e-12
    )
    # square wave +-a: range 2a, rms a -> 2a / (2 sqrt(2) a) = 1/sqrt(2)
    sq = np.where(t < 0.5, 2.0, -2.0)
    assert metrics.relative_peak_factor(sq) == pytest.approx(1 / np.sqrt(2), abs=1e-12)
    # a hand-picked 4-sample signal: [1, 0, -3, 2] -> range 5, rms sqrt(14/4)
    assert metrics.relative_peak_factor(np.array([1.0, 0.0, -3.0, 2.0])) == pytest.approx(
        5.0 / (2 * np.sqrt(2) * np.sqrt(3.5)), rel=1e-14
    )
    # triangle: rms a/sqrt(3) -> sqrt(3)/sqrt(2) (sampled symmetric triangle, exact peaks)
    tri = 1.0 - 4.0 * np.abs(t - 0.5)
    r = np.sqrt(np.mean(tri**2))
    assert metrics.relative_peak_factor(tri) == pytest.approx(
        2.0 / (2 * np.sqrt(2) * r), rel=1e-14
    )
    assert r == pytest.approx(1 / np.sqrt(3), rel=1e-4)
    with pytest.raises(ConfigError, match="zero"):
        metrics.relative_peak_factor(np.zeros(5))


def test_schroeder_phases_flat_closed_form():
    m = 12
    phi = schroeder_phases(np.ones(m))
    k = np.arange(1, m + 1)
    expected = np.mod(-np.pi * k * (k - 1) / m, 2 * np.pi)  # Schroeder 1970, flat spectrum
    d = np.angle(np.exp(1j * (phi - expected)))
    assert np.max(np.abs(d)) < 1e-12


def test_synthesize_matches_sum_of_cosines():
    n, h = 64, np.array([3, 5, 11])
    a, p = np.array([1.0, 0.5, 2.0]), np.array([0.1, -1.0, 2.5])
    k = np.arange(n)
    ref = sum(ai * np.cos(2 * np.pi * hi * k / n + pi) for ai, hi, pi in zip(a, h, p))
    assert np.max(np.abs(synthesize(n, h, a, p) - ref)) < 1e-12


# ---------------------------------------------------------------- allocation and orthogonality
def test_allocation_interleaved_disjoint(sig):
    h = [set(x.tolist()) for x in sig.harmonics]
    for i in range(len(h)):
        for j in range(i + 1, len(h)):
            assert not h[i] & h[j]
    assert sorted(set().union(*h[:3])) == list(range(1, 21))  # [0.025, 0.5] Hz, f0 = 0.025
    assert sorted(set().union(*h[3:])) == list(range(21, 201))  # (0.5, 5] Hz
    assert sig.harmonics[0].tolist() == list(range(1, 21, 3))  # interleaved: 1, 4, 7, ...
    assert sig.harmonics[4].tolist() == list(range(22, 201, 4))


def test_allocation_too_few_harmonics_names_group():
    cfg = SignalsConfig.from_dict(
        {
            "duration": 10.0,
            "sample_rate": 10.0,
            "groups": [{"name": "narrow", "channels": ["a", "b", "c"], "band": [0.1, 0.2]}],
        }
    )
    with pytest.raises(ConfigError, match="narrow"):
        allocate_harmonics(cfg.groups, 10.0, 10.0)


def test_orthogonality_over_one_period(sig):
    # independent of metrics.correlation_matrix: normalised inner products of mean-removed columns
    u = sig.u - sig.u.mean(axis=0)
    g = u.T @ u
    c = g / np.sqrt(np.outer(np.diag(g), np.diag(g)))
    off = np.abs(c - np.eye(c.shape[0]))
    assert off.max() < 1e-9
    assert metrics.max_cross_correlation(sig.u) < 1e-9


def test_energy_only_at_allocated_harmonics(sig):
    n = sig.t.size
    X = np.fft.fft(sig.u, axis=0)  # independent of metrics.power_spectrum
    for j, h in enumerate(sig.harmonics):
        p = np.abs(X[: n // 2, j]) ** 2
        other = np.ones(p.size, dtype=bool)
        other[h] = False
        assert p[other].sum() / p.sum() < 1e-20
        # flat spectrum: every allocated harmonic carries the same power
        assert np.ptp(p[h]) / p[h].mean() < 1e-9
    content = metrics.harmonic_content(sig.u, sig.harmonics)
    assert all(c.leakage_fraction < 1e-20 and c.foreign_fraction < 1e-20 for c in content)


def test_power_spectrum_parseval_and_amplitude():
    n, fs = 200, 20.0
    t = np.arange(n) / fs
    x = 2.0 * np.cos(2 * np.pi * 1.0 * t + 0.3)  # 1 Hz = bin 10
    f, P = metrics.power_spectrum(x, fs)
    assert f[10] == pytest.approx(1.0)
    assert P[10, 0] == pytest.approx(2.0, rel=1e-12)  # a^2 / 2
    assert P.sum() == pytest.approx(np.mean(x**2), rel=1e-12)


# ---------------------------------------------------------------- RPF targets
def test_rpf_small_set_and_improvement(sig):
    for j, h in enumerate(sig.harmonics):
        r = metrics.relative_peak_factor(sig.u[:, j])
        assert r == pytest.approx(sig.rpf[j], rel=1e-12)
        assert h.size >= 5 and r <= 1.25, (sig.names[j], r)
        # 45 harmonics (< 100): 1.06 here; the 1.05 target is checked on the phase-2 set below
        if h.size >= 30:
            assert r <= 1.06, (sig.names[j], r)
        assert r < sig.rpf_schroeder[j] - 0.1


def test_rpf_targets_phase2_set(phase2):
    """Issue 3 targets on the shipped 7-channel set: <= 1.05 with >= 30 harmonics, <= 1.25
    with >= 5; and every pair orthogonal to 1e-9 over the period."""
    for j, h in enumerate(phase2.harmonics):
        r = metrics.relative_peak_factor(phase2.u[:, j])
        assert h.size >= 5
        assert r <= (1.05 if h.size >= 30 else 1.25), (phase2.names[j], h.size, r)
    assert metrics.max_cross_correlation(phase2.u) < 1e-9
    assert [h.size for h in phase2.harmonics] == [7, 7, 6, 113, 113, 112, 112]
    assert phase2.Q == pytest.approx(np.sqrt(300.0) * np.eye(3))


def test_channels_start_and_end_near_zero(sig):
    for j in range(len(sig.names)):
        x = sig.u[:, j]
        step = np.max(np.abs(np.diff(x)))
        ends = max(abs(x[0]), abs(x[-1]))
        # an upward zero crossing sits between the last and the first sample of the period,
        # chosen so both ends are small compared with the largest sample-to-sample step
        assert x[0] >= 0 > x[-1]
        assert ends < 0.5 * step
        if sig.groups[j] == "reference":  # slow channels: within 5 % of the peak
            assert ends < 0.05 * np.max(np.abs(x))


def test_evaluate_is_the_sum_of_sinusoids(sig):
    assert np.max(np.abs(sig.evaluate(sig.t) - sig.u)) < 1e-10
    # periodic in T
    t = np.array([0.37, 12.5])
    assert np.max(np.abs(sig.evaluate(t + sig.duration) - sig.evaluate(t))) < 1e-9


# ---------------------------------------------------------------- scaling, Eq. (26)-(28)
def test_reference_scaled_to_box(sig):
    for j, peak in zip(range(3), (5.0, 4.0, 3.0)):
        assert np.max(np.abs(sig.u[:, j])) == pytest.approx(peak, rel=1e-12)


def test_unit_energy_eq26(sig):
    ue = sig.u[:, 3:]
    assert energy(ue, 1 / sig.sample_rate) == pytest.approx(1.0, rel=1e-12)
    # independent: Parseval on the designed amplitudes, int_0^T a^2 cos^2 = T a^2 / 2
    e2 = sum(sig.duration * np.sum(a**2) / 2 for a in sig.amplitudes[3:])
    assert e2 == pytest.approx(1.0, rel=1e-10)
    # even power split: each channel 1/4 of the energy
    for j in range(3, 7):
        assert energy(sig.u[:, j], 1 / sig.sample_rate) ** 2 == pytest.approx(0.25, rel=1e-12)


def test_R_Q_formulas_by_hand(sig):
    T = 40.0
    R = np.diag([np.sqrt(4 * T / 2) * d for d in DELTA_E])  # Eq. (27), n_u = 4
    Q = np.diag([np.sqrt(3 * T) * d for d in DELTA_V])  # Eq. (28), n_z = 3
    assert np.allclose(sig.R, R, rtol=1e-14, atol=0)
    assert np.allclose(sig.Q, Q, rtol=1e-14, atol=0)
    assert sig.R[0, 0] == pytest.approx(np.sqrt(80.0) * 0.05)
    assert excitation_weight([1.0, 2.0], 8.0) == pytest.approx(
        np.diag([np.sqrt(8.0), 2 * np.sqrt(8.0)])
    )
    assert performance_weight([2.0], 9.0) == pytest.approx(np.array([[6.0]]))  # sqrt(1 * 9) * 2
    with pytest.raises(ConfigError):
        excitation_weight([1.0, -1.0], 10.0)


def test_R_ue_has_magnitude_delta(sig):
    # seed 0: "results in the effective excitation inputs having magnitudes Delta": the half
    # range of (R u_e)_i is Delta_i * RPF_i exactly when the energy is split evenly.
    e = sig.u[:, 3:] @ sig.R.T
    half = 0.5 * (e.max(axis=0) - e.min(axis=0))
    assert np.allclose(half, np.array(DELTA_E) * sig.rpf[3:], rtol=1e-10)


def test_power_fraction_and_spectrum_shape():
    cfg = SignalsConfig.from_dict(
        {
            "duration": 20.0,
            "sample_rate": 10.0,
            "groups": [
                {
                    "name": "g",
                    "channels": ["a", "b"],
                    "band": [0.5, 3.0],
                    "energy": 2.0,
                    "power_fraction": [0.8, 0.2],
                    "spectrum": {"a": [[0.5, 2.0], [3.0, 1.0]]},
                }
            ],
            "optimisation": {"max_iter": 20, "clip_iter": 10},
        }
    )
    s = design(cfg)
    dt = 0.1
    assert energy(s.u[:, 0], dt) ** 2 == pytest.approx(0.8 * 4.0, rel=1e-12)
    assert energy(s.u[:, 1], dt) ** 2 == pytest.approx(0.2 * 4.0, rel=1e-12)
    # channel a: amplitude falls linearly from 2 at 0.5 Hz to 1 at 3 Hz (relative shape)
    f = s.harmonics[0] / 20.0
    shape = np.interp(f, [0.5, 3.0], [2.0, 1.0])
    a = s.amplitudes[0]
    assert np.allclose(a / a[0], shape / shape[0], rtol=1e-12)
    _, P = metrics.power_spectrum(s.u[:, 0], 10.0)
    assert np.allclose(np.sqrt(2 * P[s.harmonics[0], 0]), a, rtol=1e-9)
