"""The one u_e -> z FIR regression (sim/closed_loop/excitation_fir.py) behind the phase-2
simulation and the PX4 chain's gain (flight/phase2/analysis.excitation_gain)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.phase2 import excitation_gain
from lpv_sysid.sim.closed_loop import excitation_response_fir


def _data(fs: float = 50.0, T: float = 60.0):
    """Multisine u_e (0.5-3 Hz) through a known FIR + a large slow tracking error."""
    t = np.arange(0.0, T, 1.0 / fs)
    rng = np.random.default_rng(3)
    ue = np.zeros((t.size, 4))
    for k in range(4):
        for f in rng.uniform(0.5, 3.0, 15):
            ue[:, k] += np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    h = 0.2 * np.exp(-np.arange(10) / 3.0)  # ue_0 -> z_0, DC gain sum(h)
    z_e = np.zeros((t.size, 3))
    z_e[:, 0] = lfilter(h, 1, ue[:, 0])
    z_e[:, 2] = -0.05 * ue[:, 3]
    z = z_e + np.column_stack([1.5 * np.sin(2 * np.pi * 0.04 * t), 0 * t, 0 * t])
    return t, z, ue, z_e, h


def test_fir_response_matches_the_true_one_and_its_peak_gain():
    t, z, ue, z_e, h = _data()
    est, info = excitation_response_fir(t, z, ue)
    a, b = np.searchsorted(t, info["window_s"][0]), np.searchsorted(t, info["window_s"][1]) + 1
    err = np.linalg.norm(est[a:b] - z_e[a:b]) / np.linalg.norm(z_e[a:b])
    assert err < 0.02
    # oracle: the largest |H(f)| of the known FIRs over the excited band (0.5-3 Hz)
    f = np.linspace(0.5, 3.0, 400)
    Hf = np.abs(np.exp(-2j * np.pi * np.outer(f, np.arange(h.size)) / 50.0) @ h)
    assert info["fir_peak_gain"] == pytest.approx(max(Hf.max(), 0.05), rel=0.05)
    assert info["fit_r2"] > 0.99 and info["lags"] == 50


def test_chain_gain_is_the_same_regression():
    """flight.phase2.excitation_gain reports what excitation_response_fir fitted (one regression:
    before, chain had its own copy that differed in grid and window)."""
    t, z, ue, z_e, _ = _data()
    fs = 50.0
    g = excitation_gain(t, z, ue, fs)
    est, info = excitation_response_fir(t, z, ue, fs=fs)
    assert g["fit_r2"] == info["fit_r2"] and g["fir_peak_gain"] == info["fir_peak_gain"]
    a, b = g["window"]
    assert t[a] == pytest.approx(info["window_s"][0]) and t[b - 1] == pytest.approx(
        info["window_s"][1]
    )
    want = math.sqrt((z_e[a:b] ** 2).sum() / (ue[a:b] ** 2).sum())
    assert g["energy_ratio"] == pytest.approx(want, rel=0.02)


def test_too_few_samples():
    t, z, ue, _, _ = _data(T=10.0)  # 500 samples < 4 x 50 lags x 4 inputs
    with pytest.raises(ConfigError, match="too few for 50 lags x 4 inputs"):
        excitation_response_fir(t, z, ue)
    assert "too few" in excitation_gain(t, z, ue, 50.0)["error"]
