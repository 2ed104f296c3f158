"""Identification core against independent oracles (seed 0 Appendix B, Eqs. 22-25).

Oracles: exact LTI simulation with known (A, B) (scipy lsim, FOH), closed-form filter
responses, hand-computed TIC/NRMSE, LP feasibility for polytope containment.
"""

import numpy as np
import pytest
from scipy.signal import lfilter

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.ident import derivatives as dv
from lpv_sysid.ident import equation_error as ee
from lpv_sysid.ident import metrics as mt
from lpv_sysid.ident.vertex import uncertainty as unc
from lpv_sysid.sim import synthetic as syn


@pytest.fixture(scope="module")
def lti():
    rng = np.random.default_rng(1)
    A, B = syn.random_stable_system(5, 2, rng)
    t = np.arange(0, 30, 0.01)
    u = syn.multisine(t, 2, (0.1, 3.0), 1.0, rng)
    d = syn.simulate(A, B, u, t)
    maskA = np.abs(rng.normal(size=A.shape)) > 0.5
    maskB = np.ones(B.shape, bool)
    maskB[0, 0] = False
    return A, B, maskA, maskB, d


# ----------------------------------------------------------------------------- derivatives
def test_savgol_gain_matches_closed_form_and_filtered_sinusoid():
    dt, window, m = 0.01, 21, 10
    f = np.array([0.5, 1.0, 2.0, 5.0])
    k = np.arange(1, m + 1)
    w = 2 * np.pi * f * dt
    closed = np.array([np.sum(k * np.sin(k * ww)) / (ww * np.sum(k**2)) for ww in w])
    np.testing.assert_allclose(dv.savgol_gain(f, dt, window, 2), closed, rtol=1e-12)
    assert closed[2] == pytest.approx(0.837, abs=1e-3)  # 17 % loss at 2 Hz (docstring)
    # the actual filter applied to a sinusoid shows exactly that gain in the interior
    t = np.arange(0, 10, dt)
    x = np.sin(2 * np.pi * 2.0 * t)
    _, xd = dv.savgol_smooth_differentiate(x, dt, window_s=window * dt, polyorder=2)
    true = 2 * np.pi * 2.0 * np.cos(2 * np.pi * 2.0 * t)
    np.testing.assert_allclose(xd[50:-50], closed[2] * true[50:-50], atol=1e-9)
    # polyorder 4 (default): < 1 % loss at 2 Hz
    assert abs(1 - dv.savgol_gain([2.0], dt, 21, 4)[0]) < 0.01


def test_fourier_derivative_exact_in_band_and_zero_above():
    dt = 0.01
    t = np.arange(1001) * dt
    T = t[-1]
    # sine-series components + a ramp are represented exactly by the odd extension
    x = np.sin(np.pi * 7 * t / T) + 0.4 * np.sin(np.pi * 30 * t / T) + 0.1 * t + 2.0
    xs, xd = dv.fourier_smooth_differentiate(x, dt, f_cut=3.0, taper=0.0)
    true = (
        np.pi * 7 / T * np.cos(np.pi * 7 * t / T)
        + 0.4 * np.pi * 30 / T * np.cos(np.pi * 30 * t / T)
        + 0.1
    )
    np.testing.assert_allclose(xd, true, atol=1e-9)
    np.testing.assert_allclose(xs, x, atol=1e-10)
    # a 9.95 Hz component is removed completely by a 6 Hz cut-off
    hf = np.sin(np.pi * 199 * t / T)
    xs2, xd2 = dv.fourier_smooth_differentiate(x + hf, dt, f_cut=6.0, taper=0.0)
    np.testing.assert_allclose(xd2, true, atol=1e-9)
    # roll-off gain formula
    assert dv.fourier_gain([6.0 * 1.15], 6.0, 0.3)[0] == pytest.approx(0.5)


def test_fourier_derivative_reduces_white_noise():
    rng = np.random.default_rng(3)
    dt = 0.01
    t = np.arange(0, 20, dt)
    x = np.sin(2 * np.pi * 1.0 * t)
    xn = x + 0.01 * rng.normal(size=t.size)
    _, xd = dv.fourier_smooth_differentiate(xn, dt, 5.0)
    fd = np.gradient(xn, dt)
    true = 2 * np.pi * np.cos(2 * np.pi * t)
    err_f = np.std((xd - true)[100:-100])
    err_fd = np.std((fd - true)[100:-100])
    assert err_f < err_fd / 5


def test_derivative_config_errors():
    with pytest.raises(ConfigError, match="method"):
        dv.DerivativeConfig.from_dict({"method": "spline"})
    with pytest.raises(ConfigError, match="unknown"):
        dv.DerivativeConfig.from_dict({"cutoff": 3})
    with pytest.raises(ConfigError, match="at least 8"):
        dv.fourier_smooth_differentiate(np.zeros(5), 0.01, 3.0)
    with pytest.raises(ConfigError, match="NaN"):
        dv.fourier_smooth_differentiate(np.array([0, 1, np.nan, 3, 4, 5, 6, 7, 8.0]), 0.01, 3.0)


# ----------------------------------------------------------------------------- Appendix B
def test_noise_free_estimates_match_truth(lti):
    A, B, maskA, maskB, d = lti
    f = ee.fit(d.xdot, d.x, d.u, A, B, maskA, maskB)
    assert np.max(np.abs(f.A - A) / np.maximum(np.abs(A), 1e-12)) < 1e-6
    assert np.max(np.abs(f.B - B) / np.maximum(np.abs(B), 1e-12)) < 1e-6
    for rf in f.rows:
        assert rf.r2 == pytest.approx(1.0, abs=1e-9)  # perfect fit -> R^2 = 1
    # known elements are copied, not estimated
    np.testing.assert_array_equal(f.A[~maskA], A[~maskA])
    assert np.all(f.std_A[~maskA] == 0)


def test_known_elements_enter_the_measurement(lti):
    """Eq. (41): wrong known elements bias the estimates of that row only."""
    A, B, maskA, maskB, d = lti
    A_wrong = A.copy()
    i, j = np.argwhere(~maskA)[0]
    A_wrong[i, j] += 1.0
    f = ee.fit(d.xdot, d.x, d.u, A_wrong, B, maskA, maskB)
    other = [r for r in range(5) if r != i and maskA[r].any()]
    np.testing.assert_allclose(f.A[other], A[other], rtol=1e-6, atol=1e-9)
    assert np.max(np.abs(f.A[i] - A[i])[maskA[i]]) > 1e-3


def _zscores(A, B, f, use_white=False):
    z = []
    for rf in f.rows:
        truth = np.concatenate([A[rf.row, list(rf.cols_A)], B[rf.row, list(rf.cols_B)]])
        s = np.sqrt(np.diag(rf.cov_white)) if use_white else rf.std
        z.extend((rf.theta - truth) / s)
    return np.array(z)


def test_coverage_white_noise(lti):
    """Eq. (44) white measurement noise: 3-sigma intervals cover the truth in >= 95 %."""
    A, B, maskA, maskB, d = lti
    rng = np.random.default_rng(7)
    z = np.concatenate(
        [
            _zscores(
                A,
                B,
                ee.fit(d.xdot + 0.5 * rng.normal(size=d.xdot.shape), d.x, d.u, A, B, maskA, maskB),
            )
            for _ in range(25)
        ]
    )
    assert z.size > 400
    assert np.mean(np.abs(z) < 3) >= 0.95
    assert 0.8 < np.std(z) < 1.25  # the standard errors are the right size


def test_coloured_residual_correction(lti):
    """AR(1) residuals: s^2 (H^T H)^-1 is far too optimistic, the corrected covariance is not."""
    A, B, maskA, maskB, d = lti
    rng = np.random.default_rng(11)
    zc, zw = [], []
    for _ in range(25):
        e = lfilter([1.0], [1.0, -0.95], 0.2 * rng.normal(size=d.xdot.shape), axis=0)
        f = ee.fit(d.xdot + e, d.x, d.u, A, B, maskA, maskB)
        zc.append(_zscores(A, B, f))
        zw.append(_zscores(A, B, f, use_white=True))
    zc, zw = np.concatenate(zc), np.concatenate(zw)
    assert np.mean(np.abs(zc) < 3) >= 0.95
    assert 0.7 < np.std(zc) < 1.5
    assert np.std(zw) > 2.5  # uncorrected errors bars are > 2.5x too small
    assert np.mean(np.abs(zw) < 3) < 0.8


def test_coverage_with_noisy_states_and_fourier_derivatives(lti):
    A, B, maskA, maskB, d = lti
    rng = np.random.default_rng(5)
    z = []
    for _ in range(12):
        xs, xd = dv.fourier_smooth_differentiate(
            d.x + 0.01 * rng.normal(size=d.x.shape), 0.01, 5.0
        )
        us = dv.smooth(d.u, 0.01, dv.DerivativeConfig(f_cut=5.0))
        f = ee.fit(xd[100:-100], xs[100:-100], us[100:-100], A, B, maskA, maskB)
        z.append(_zscores(A, B, f))
    assert np.mean(np.abs(np.concatenate(z)) < 3) >= 0.95


def test_fit_errors(lti):
    A, B, maskA, maskB, d = lti
    x = d.x.copy()
    j = int(np.argwhere(maskA[1])[0][0])
    x[:, j] = 0.0
    with pytest.raises(SolverError, match="identically zero"):
        ee.fit(d.xdot, x, d.u, A, B, maskA, maskB)
    x = d.x.copy()
    cols = np.nonzero(maskA[1])[0]
    x[:, cols[1]] = 2.0 * x[:, cols[0]]
    with pytest.raises(SolverError, match="linearly dependent"):
        ee.fit(d.xdot, x, d.u, A, B, maskA, maskB)
    with pytest.raises(SolverError, match="samples"):
        ee.fit(d.xdot[:3], d.x[:3], d.u[:3], A, B, maskA, maskB)
    with pytest.raises(ConfigError, match="shape"):
        ee.fit(d.xdot, d.x, d.u, A, B[:, :1], maskA, maskB)
    bad = d.x.copy()
    bad[5, 0] = np.nan
    with pytest.raises(ConfigError, match="NaN"):
        ee.fit(d.xdot, bad, d.u, A, B, maskA, maskB)


# ----------------------------------------------------------------------------- Eqs. (24)-(25)
def test_tic_nrmse_hand_computed():
    xm = np.array([1.0, 2.0, 3.0, 4.0])
    xf = np.array([1.0, 2.0, 2.0, 6.0])
    # errors 0 0 1 -2 -> rms = sqrt(5/4); rms(xm) = sqrt(30/4); rms(xf) = sqrt(45/4)
    assert mt.tic(xm, xf) == pytest.approx(np.sqrt(5 / 4) / (np.sqrt(30 / 4) + np.sqrt(45 / 4)))
    assert mt.nrmse(xm, xf) == pytest.approx(np.sqrt(5 / 4) / 5.0)
    assert mt.tic(xf, xf) == 0.0
    assert mt.tic(-xf, xf) == pytest.approx(1.0)  # worst case
    assert mt.r_squared(xf, xf) == 1.0
    with pytest.raises(ConfigError, match="range"):
        mt.nrmse(xm, np.ones(4))
    with pytest.raises(ConfigError):
        mt.tic(xm, xf[:3])


def test_axis_metrics_and_plot(tmp_path):
    rng = np.random.default_rng(0)
    xf = rng.normal(size=(200, 12))
    xm = xf + 0.1 * rng.normal(size=(200, 12))
    m = mt.axis_metrics(xm, xf)
    assert set(m["tic"]) == set(mt.AXES)
    assert m["tic"]["pdot"] == pytest.approx(mt.tic(xm[:, 5], xf[:, 5]))
    mt.plot_validation(np.arange(200) * 0.01, xm, xf, str(tmp_path / "fig4.png"))
    assert (tmp_path / "fig4.png").stat().st_size > 1000


# ----------------------------------------------------------------------------- Eqs. (22)-(23)
def _elements(A, B, maskA, maskB, rel=0.1):
    out = []
    for i, j in np.argwhere(maskA):
        out.append(("A", i, j, A[i, j], rel * abs(A[i, j]) + 1e-3))
    for i, j in np.argwhere(maskB):
        out.append(("B", i, j, B[i, j], rel * abs(B[i, j]) + 1e-3))
    return out


def test_uncertainty_box_and_reductions(lti):
    A, B, maskA, maskB, _ = lti
    els = _elements(A, B, maskA, maskB)
    p = len(els)
    assert p > 8
    # truth perturbed inside the box (2.5 sigma in every element)
    rng = np.random.default_rng(2)
    A_t, B_t = A.copy(), B.copy()
    for m, i, j, nom, s in els:
        (A_t if m == "A" else B_t)[i, j] = nom + rng.uniform(-2.5, 2.5) * s
    # influence: 2^p_max corners, kept intervals widened, others nominal
    cfg = unc.UncertaintyConfig(k_sigma=3.0, method="influence", p_max=3, output_states=(0, 1, 2))
    uv = unc.build(A, B, els, cfg)
    assert uv.M == 8 and uv.inflation >= 1.0
    kept = [iv for iv in uv.intervals if iv.corner]
    assert len(kept) == 3
    infl = np.array([iv.influence for iv in uv.intervals])
    assert min(iv.influence for iv in kept) >= np.sort(infl)[-3] - 1e-15
    for iv, (m, i, j, nom, s) in zip(uv.intervals, els):
        if not iv.corner:
            assert iv.lower == pytest.approx(nom - 3 * s) and iv.upper == pytest.approx(
                nom + 3 * s
            )
    # hybrid: strict containment of every point of the box (LP oracle)
    cfg_h = unc.UncertaintyConfig(method="hybrid", p_max=2, output_states=(0, 1, 2))
    uh = unc.build(A, B, els, cfg_h)
    assert uh.M == 4 * (p - 2 + 1)
    assert unc.contains(uh, A_t, B_t)
    assert not unc.contains(uv, A_t, B_t)  # the 'influence' polytope is not a containment
    # outside the box -> not contained
    m, i, j, nom, s = els[0]
    A_out = A_t.copy()
    (A_out if m == "A" else B_t)[i, j] = nom + (1 + 3 * p) * 3 * s
    assert not unc.contains(uh, A_out, B_t)
    # full box on a small subset equals the textbook 2^p corners
    ub = unc.build(A, B, els[:4], unc.UncertaintyConfig(method="box", output_states=(0, 1, 2)))
    assert ub.M == 16
    with pytest.raises(ConfigError, match="corners"):
        unc.build(
            A, B, els, unc.UncertaintyConfig(method="box", max_corners=64, output_states=(0, 1, 2))
        )


def test_influence_matches_finite_difference(lti):
    A, B, maskA, maskB, _ = lti
    els = _elements(A, B, maskA, maskB)[:5]
    cfg = unc.UncertaintyConfig(output_states=(0, 1), n_freq=7)
    ivs = unc.intervals_from_elements(els, 1.0)
    infl = unc.influence(A, B, ivs, cfg)
    C = np.eye(5)[[0, 1]]
    w = 2 * np.pi * np.geomspace(*cfg.freq_hz, cfg.n_freq)

    def G(Am, Bm, wq):
        return C @ np.linalg.solve(1j * wq * np.eye(5) - Am, Bm)

    for k, iv in enumerate(ivs):
        h = 1e-7
        Ap, Bp = A.copy(), B.copy()
        (Ap if iv.matrix == "A" else Bp)[iv.row, iv.col] += h
        sens = max(np.linalg.norm((G(Ap, Bp, wq) - G(A, B, wq)) / h) for wq in w)
        assert infl[k] == pytest.approx(0.5 * (iv.upper - iv.lower) * sens, rel=1e-4)


def test_sidak_joint_coverage():
    """k from sidak_k covers all p Gaussian errors jointly with probability 1 - alpha."""
    assert unc.sidak_k(1, 0.05) == pytest.approx(1.959964, abs=1e-5)
    k = unc.sidak_k(43, 0.05)
    z = np.random.default_rng(0).normal(size=(20000, 43))
    joint = np.mean(np.max(np.abs(z), axis=1) < k)
    assert joint == pytest.approx(0.95, abs=0.006)
    assert np.mean(np.max(np.abs(z), axis=1) < 3.0) == pytest.approx(0.9973**43, abs=0.01)
    els = [("A", 0, j, 1.0, 0.1) for j in range(5)]
    A = -np.eye(5)
    uv = unc.build(
        A,
        np.ones((5, 1)),
        els,
        unc.UncertaintyConfig(method="box", joint_alpha=0.05, output_states=(0,)),
    )
    assert uv.intervals[0].upper - 1.0 == pytest.approx(0.1 * max(3.0, unc.sidak_k(5, 0.05)))
