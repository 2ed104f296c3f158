"""Calibrated vertex identification (issue 13): honest standard errors, the equilibrium
re-expansion, errors in variables, the motor constants, the stored box and the coverage study.

Oracles: Monte Carlo over known truths (linear regressions with coloured errors, exact
first-order motor simulations), Student-t quantiles (scipy.stats), closed-form exponential
motor responses, the analytic linearisation and trim of models.quadrotor on simulated
phase-1 flights.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import norm
from scipy.stats import t as student_t

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident import dataprep as dp
from lpv_sysid.ident import equation_error as ee
from lpv_sysid.ident import vertex as vx
from lpv_sysid.ident.dataprep import alignment
from lpv_sysid.ident.vertex import regressor_noise_var, taylor
from lpv_sysid.models.quadrotor import Quadrotor, QuadrotorParams, mixer
from lpv_sysid.studies import coverage as cv

#: known elements that move with the identified equilibrium and carry its uncertainty (issue 20
#: item 3): gravity/kinematic terms at the identified attitude and yaw rate, e.g. A[w,theta],
#: A[v,phi], A[u,v] = r, A[p,r]
N_FIXED = 15


# ----------------------------------------------------------------------------- standard errors
def test_t_factor_is_the_student_t_quantile_ratio():
    assert ee.t_factor(3.0, None) == 1.0
    for dof in (5.0, 27.0, 58.0):
        assert ee.t_factor(3.0, dof) == pytest.approx(
            student_t.ppf(norm.cdf(3.0), dof) / 3.0, rel=1e-12
        )
    assert ee.t_factor(3.0, 27.0) > ee.t_factor(3.0, 58.0) > 1.0
    # the EWC default: as many cosines as fit below band_hz over the record, capped by 0.4 n^(2/3)
    assert ee.default_dof(3000, 0.01, 1.0) == 60
    assert ee.default_dof(3000, 0.01, 100.0) == int(0.4 * 3000 ** (2 / 3))


def test_upper_quantile_is_scipy_stats_isf_bit_for_bit():
    """upper_quantile (scipy.special, no scipy.stats import) gives scipy.stats' own numbers,
    exactly, also at the ends of the support and for invalid dof (the joint box widths and the
    t-factors recorded in the model files must not move)."""
    qs = (0.0, 5e-324, 1e-300, 1e-9, 0.01, 0.025, 0.2, 0.4999, 0.7, 1.0 - 1e-16, 1.0)
    for q in qs:
        for dof in (None, 0.0, -1.0, math.nan, 0.5, 1.0, 2.5, 27.0, 1e3, 1e6, math.inf):
            want = float(norm.isf(q) if dof is None else student_t.isf(q, dof))
            got = ee.upper_quantile(q, dof)
            assert got == want or (math.isnan(got) and math.isnan(want)), (q, dof, got, want)
    for k in (1e-3, 0.5, 3.0, 3.84, 8.3, 10.0, 40.0):  # ndtr(k) == 1 from k ~ 8.3: t.ppf = inf
        for dof in (0.5, 1.0, 5.0, 58.0, 1e5):
            assert ee.t_factor(k, dof) == float(student_t.ppf(norm.cdf(k), dof) / k), (k, dof)


def _coloured_regression(rng, n=3000, rho=0.95):
    """y = H theta + v with AR(1) regressors and AR(1) errors (both strongly coloured)."""
    H = np.column_stack(
        [lfilter([1.0], [1.0, -0.9], rng.normal(size=n)), np.sin(np.arange(n) / 40.0), np.ones(n)]
    )
    v = lfilter([1.0], [1.0, -rho], 0.3 * rng.normal(size=n))
    theta = np.array([1.5, -0.7, 0.2])
    return H @ theta + v, H, theta


def test_ewc_standard_errors_are_honest_under_coloured_residuals():
    """200 Monte Carlo fits: the EWC studentised errors are t_nu (std ~ 1, 3-sigma t-widened
    intervals cover >= 99 %); the white-residual ones are > 2.5x too small (the old fit's
    coloured-residual estimate is kept as residual_acf)."""
    rng = np.random.default_rng(5)
    z, zw = [], []
    for _ in range(200):
        y, H, theta = _coloured_regression(rng)
        d = ee.RowDesign(0, y, H, (0, 1), (), ("x0", "x1", "bias"))
        (rf,), joint, dof = ee.solve_rows([d], ee.CovarianceConfig(dof=24))
        z.append((rf.theta - theta) / rf.std)
        zw.append((rf.theta - theta) / np.sqrt(np.diag(rf.cov_white)))
        assert dof == 24.0 and np.allclose(joint, rf.cov)
    z, zw = np.array(z)[:, :2], np.array(zw)[:, :2]
    k = 3.0 * ee.t_factor(3.0, 24.0)
    assert np.mean(np.abs(z) <= k) >= 0.99
    assert 0.8 < np.std(z) < 1.25
    assert np.std(zw) > 2.5


def test_ewc_joint_covariance_has_the_cross_row_terms():
    """Two rows whose errors share one coloured process: their estimates are correlated and
    the stacked-score covariance says by how much (the equilibrium re-expansion combines
    rows); block-diagonal per-row estimates would say zero."""
    rng = np.random.default_rng(11)
    est, cross = [], []
    for _ in range(150):
        n = 2000
        x = lfilter([1.0], [1.0, -0.8], rng.normal(size=n))
        common = lfilter([1.0], [1.0, -0.9], rng.normal(size=n))
        y1 = 2.0 * x + common + 0.2 * rng.normal(size=n)
        y2 = -1.0 * x + common + 0.2 * rng.normal(size=n)
        ds = [ee.RowDesign(i, y, x[:, None], (0,), (), ("x0",)) for i, y in ((0, y1), (1, y2))]
        fits, joint, _ = ee.solve_rows(ds, ee.CovarianceConfig(dof=20))
        est.append([fits[0].theta[0], fits[1].theta[0]])
        cross.append(joint[0, 1] / math.sqrt(joint[0, 0] * joint[1, 1]))
    mc = np.corrcoef(np.array(est).T)[0, 1]
    assert mc > 0.8  # strongly correlated through the shared error
    assert np.median(cross) == pytest.approx(mc, abs=0.1)


def test_bias_compensated_ls_removes_errors_in_variables():
    """A regressor measured with noise of known variance: plain LS is attenuated (far outside
    its error bars), the bias-compensated estimate is not, and the shift is reported."""
    rng = np.random.default_rng(2)
    zl, zb = [], []
    for _ in range(60):
        n = 3000
        x = lfilter([1.0], [1.0, -0.95], 0.1 * rng.normal(size=n))
        y = 3.0 * x + 0.05 * rng.normal(size=n)
        xm = x + 0.1 * rng.normal(size=n)  # var(noise) = 0.01 ~ var(x) / 2
        ls = ee.solve_rows(
            [ee.RowDesign(0, y, xm[:, None], (0,), (), ("x0",))], ee.CovarianceConfig(dof=30)
        )[0][0]
        bc = ee.solve_rows(
            [ee.RowDesign(0, y, xm[:, None], (0,), (), ("x0",), noise_var=np.array([0.01]))],
            ee.CovarianceConfig(dof=30),
        )[0][0]
        zl.append((ls.theta[0] - 3.0) / ls.std[0])
        zb.append((bc.theta[0] - 3.0) / bc.std[0])
        assert bc.eiv_bias[0] == pytest.approx(ls.theta[0] - bc.theta[0])
    assert np.mean(zl) < -5
    assert abs(np.mean(zb)) < 0.5 and np.mean(np.abs(zb) < 3.5) >= 0.95


def test_measurement_noise_config_and_regressor_noise_variance():
    cfg = vx.IdentificationConfig.from_dict(
        {"measurement_noise": {"u": 0.03, "p": [0.008, 250.0], "rotor": [2.0, 100.0]}}
    )
    assert cfg.measurement_noise["u"] == (0.03, None) and cfg.measurement_noise["p"] == (
        0.008,
        250.0,
    )
    var, dvar, rotor = regressor_noise_var(cfg, QuadrotorParams(), 0.01)
    # white noise of std s at r Hz through the Fourier low-pass: 2 s^2 / r * f_cut (1 + 3/8 taper)
    feff = cfg.derivatives.f_cut * (1 + 0.375 * cfg.derivatives.taper)
    assert var[2] == pytest.approx(2 * 0.03**2 / 100.0 * feff, rel=2e-3)
    assert var[5] == pytest.approx(2 * 0.008**2 / 250.0 * feff, rel=2e-3)
    mix = mixer(QuadrotorParams().arm_length)
    assert var[8] == pytest.approx(2 * 4.0 / 100.0 * feff * np.sum(mix[0] ** 2), rel=2e-3)
    assert var[0] == 0.0 and dvar[2] > 0
    with pytest.raises(
        ConfigError, match=r"^identification\.measurement_noise: unknown key\(s\) \['speed'\]"
    ):
        vx.IdentificationConfig.from_dict({"measurement_noise": {"speed": 1.0}})
    with pytest.raises(ConfigError, match=r"measurement_noise\.u\[0\]: must be >= 0"):
        vx.IdentificationConfig.from_dict({"measurement_noise": {"u": [-1.0, 100.0]}})
    with pytest.raises(ConfigError, match=r"measurement_noise\.u\[1\]: the rate must be > 0"):
        vx.IdentificationConfig.from_dict({"measurement_noise": {"u": [0.1, 0.0]}})


# ----------------------------------------------------------------------------- dataprep
def test_cubic_resampling_keeps_the_band_where_linear_lost_a_percent():
    """A 100 Hz stream read 2 ms off its stamps: linear interpolation loses ~1 % at 6 Hz (the
    bias of the motor constants), the spline of dataprep loses < 0.05 %."""
    t = np.arange(0.0, 20.0, 0.01)
    tg = t[100:-100] + 0.002
    y = np.sin(2 * np.pi * 6.0 * t)[:, None]
    exact = np.sin(2 * np.pi * 6.0 * tg)
    lin = np.interp(tg, t, y[:, 0])
    spl = alignment._interp(tg, t, y)[:, 0]
    amp = lambda s: np.sqrt(2 * np.mean(s**2))  # noqa: E731
    assert 1 - amp(lin) / amp(exact) > 0.008
    assert abs(1 - amp(spl) / amp(exact)) < 5e-4
    assert np.max(np.abs(spl - exact)) < 2e-3


# ----------------------------------------------------------------------------- motor constants
def test_pinned_fraction_is_the_exact_exponential_hit_time():
    p = QuadrotorParams()
    dt = 0.01
    e = np.zeros((30, 4))
    start = np.array([p.omega_min + 40.0, 900.0, p.omega_min, 600.0])
    e[:, 1] = 0.9 * p.a_omega * p.omega_max / p.b_omega  # stays inside the limits
    e[:, 3] = p.a_omega * 600.0 / p.b_omega  # at rest at 600
    frac = vx.pinned(e, start, dt, p)
    t_hit = math.log(start[0] / p.omega_min) / p.a_omega  # Omega_inf = 0 with e = 0
    k = int(t_hit // dt)
    assert np.all(frac[:k, 0] == 0) and frac[k, 0] == pytest.approx(
        1 - (t_hit - k * dt) / dt, abs=1e-9
    )
    assert np.all(frac[k + 1 :, 0] == 1)
    assert np.all(frac[:, 1] == 0) and np.all(frac[:, 3] == 0)
    assert np.all(frac[:, 2] == 1)  # starts pinned, the command keeps it there
    e[15:, 2] = 0.5  # released when the command lifts it
    assert np.all(vx.pinned(e, start, dt, p)[15:, 2] == 0)


def _motor_data(latency: float, seed: int = 0, jitter: float = 0.01, noise: float = 2.0):
    """Rotor speeds of Eq. (8) driven by a held 250 Hz command delayed by ``latency``, exact
    per step, at 100 Hz with 2 rad/s telemetry noise, through dataprep (the command's
    anti-alias filter and centring, the grid on the rotor stamps); body states 0."""
    p = QuadrotorParams()
    rng = np.random.default_rng(seed)
    mix = mixer(p.arm_length)
    tc = np.arange(0.0, 40.0, 0.004)
    f = np.array([0.3, 0.7, 1.3, 2.1, 3.1])
    e = 0.45 + 0.08 * np.column_stack(
        [
            np.sin(2 * np.pi * f[:, None] * tc + rng.uniform(0, 6, (5, 1))).sum(0) / 3
            for _ in range(4)
        ]
    )
    e += jitter * rng.normal(size=e.shape)  # rate-loop jitter
    fine = 2000.0
    tf = np.arange(0.0, 40.0, 1 / fine)
    ef = e[np.clip(np.floor((tf - latency) / 0.004 + 1e-9).astype(int), 0, tc.size - 1)]
    ad = math.exp(-p.a_omega / fine)
    Om = np.empty((tf.size, 4))
    Om[0] = p.b_omega * ef[0] / p.a_omega
    for k in range(tf.size - 1):
        Om[k + 1] = ad * Om[k] + (1 - ad) * p.b_omega / p.a_omega * ef[k]
    tr = np.arange(0.0, 39.99, 0.01)
    ts = np.arange(0.0, 39.99, 0.004)
    zeros = np.zeros((ts.size, 3))
    streams = dp.Streams(
        "motor",
        ts,
        zeros,
        zeros,
        zeros,
        tr,
        Om[np.round(tr * fine).astype(int)] + noise * rng.normal(size=(tr.size, 4)),
        t_cmd=tc,
        u=e @ mix.T,
        t_ref=tc,
        ref=np.zeros((tc.size, 4)),
        t_excite=10.0,
    )
    return dp.align(streams, vx.IdentificationConfig(), params=p).vertex, p


def test_motor_constants_with_latency_are_identified():
    """a_Omega, b_Omega from the rotor speeds: with a 4 ms command-to-rotor latency the delay
    term recovers it and keeps a, b unbiased; without it they would be off by ~a tau = 5 %.
    The telemetry noise attenuates plain LS (errors in variables); given its level, the
    bias-compensated estimate is closer."""
    data, p = _motor_data(0.004)
    out = {}
    for name, kw in (
        ("ls", {"motor_instrument": False}),
        ("bc", {"motor_instrument": False, "measurement_noise": {"rotor": [2.0, 100.0]}}),
        ("iv", {}),
    ):
        cfg = vx.IdentificationConfig.from_dict(kw)
        x0, u0 = vx.equilibrium(data, cfg)
        dt, full, keep = vx.fit_indices(data, cfg)
        rotor_var = regressor_noise_var(cfg, p, dt)[2]
        design, tau = vx.motor_design(
            data, cfg, p, full, keep, x0, u0, data.u_eff, rotor_var=rotor_var
        )
        assert tau == pytest.approx(0.004, abs=2e-4)
        assert (design.Z is not None) == (name == "iv") and (design.noise_var is not None) == (
            name == "bc"
        )
        (rf,), joint, dof = ee.solve_rows([design], cfg.covariance, dt)
        out[name] = (-rf.theta[0], rf.theta[1], rf.std[:2])
    a, b, s = out["iv"]  # the default: the model's speeds instrument the measured ones
    k = 3.0 * ee.t_factor(3.0, 60.0)
    assert abs(a - p.a_omega) <= k * s[0] and abs(b - p.b_omega) <= k * s[1]
    assert abs(a / p.a_omega - 1) < 0.004 and abs(b / p.b_omega - 1) < 0.004
    for name in ("bc", "iv"):  # plain LS is attenuated by the telemetry noise
        assert abs(out["ls"][0] - p.a_omega) > abs(out[name][0] - p.a_omega)
    # without a latency the term finds none
    data0, _ = _motor_data(0.0, seed=1)
    cfg = vx.IdentificationConfig()
    x0, u0 = vx.equilibrium(data0, cfg)
    dt, full, keep = vx.fit_indices(data0, cfg)
    assert abs(vx.motor_design(data0, cfg, p, full, keep, x0, u0, data0.u_eff)[1]) < 3e-4


# ----------------------------------------------------------------------------- phase-1 flights
@pytest.fixture(scope="module")
def descending_run():
    """A phase-1 flight at the descending vertex [+5, -5, +5] of the nominal vehicle."""
    from lpv_sysid.control.baseline import BaselineGains
    from lpv_sysid.sim import phase1 as p1
    from lpv_sysid.sim.vehicle import SensorConfig

    q = Quadrotor()
    cfg = p1.Phase1Config()
    rec = p1.simulate_run(
        q, BaselineGains(), SensorConfig(), cfg, (5.0, -5.0, 5.0), "vertex_p5_m5_p5", seed=7
    )
    return q, rec


def test_equilibrium_reexpansion_removes_the_trim_bias(descending_run):
    """The flown trim mean is not an equilibrium (the identified model's wdot there is a few
    cm/s^2); the Jacobian at it misses the true vertex model (the linearisation at the
    equilibrium at the flown velocity) by many standard errors in A[p, da] / A[q, de]; the
    re-expanded model is centred on an equilibrium of the true dynamics and covers it."""
    q, rec = descending_run
    cfg = vx.IdentificationConfig()
    data = dp.align(dp.streams_from_record(rec), cfg).vertex
    A, B, x_e = cv.truth_model(q.params, rec, vx.trim_window((0.0, rec.t_excite), cfg))
    res = vx.identify_vertex(data, cfg)
    flat = vx.identify_vertex(data, dataclasses.replace(cfg, equilibrium=False))
    z, z_flat = cv.z_scores(res, A, B), cv.z_scores(flat, A, B)
    assert abs(res.xdot_flown[4]) > 0.01  # wdot at the flown mean
    assert max(abs(z_flat["A[p,da]"]), abs(z_flat["A[q,de]"])) > 4
    assert abs(z["A[p,da]"]) < 3 and abs(z["A[q,de]"]) < 3
    assert np.mean(np.abs(list(z.values())) <= 3) >= 0.97
    # x0, u0 of the model: an equilibrium of the true vehicle (rows u..r and the rotors)
    xd = q.derivatives12(res.x0, res.u0)
    assert np.max(np.abs(xd[2:5])) < 5e-3 and np.max(np.abs(xd[5:8])) < 0.05
    np.testing.assert_allclose(res.x0[8], x_e[8], atol=0.5)
    _, _, x_e_flown = cv.truth_model(
        q.params, rec, vx.trim_window((0.0, rec.t_excite), cfg), at="flown"
    )
    assert abs(res.x_flown[8] - x_e_flown[8]) > 1.0  # the flown mean rotor speed is not


def test_vertex_model_is_expanded_at_the_commanded_velocity(descending_run):
    """Issue 20 item 1: the LPV model is scheduled on v_d, so the vertex model is the identified
    model re-expanded at v_d (not at the flown mean velocity, which is off v_d); against the
    true linearisation at v_d the flown-point expansion misses by many standard errors."""
    q, rec = descending_run
    cfg = vx.IdentificationConfig()
    assert cfg.expand_at == "commanded"
    data = dp.align(dp.streams_from_record(rec), cfg).vertex
    A, B, x_e = cv.truth_model(q.params, rec, vx.trim_window((0.0, rec.t_excite), cfg))
    np.testing.assert_allclose(x_e[2:5], rec.v_d, atol=1e-9)
    res = vx.identify_vertex(data, cfg)
    flown = vx.identify_vertex(data, dataclasses.replace(cfg, expand_at="flown"))
    np.testing.assert_allclose(res.x0[2:5], rec.v_d, atol=1e-9)  # the model's own equilibrium
    assert np.max(np.abs(flown.x0[2:5] - np.asarray(rec.v_d))) > 0.02
    z, z_fl = cv.z_scores(res, A, B), cv.z_scores(flown, A, B)
    assert np.mean(np.abs(list(z.values())) <= 3) >= 0.97
    assert max(abs(v) for v in z_fl.values()) > 2 * max(abs(v) for v in z.values())


def test_stored_box_is_every_element_with_calibrated_std(descending_run, tmp_path):
    """vertex_models.yaml @2: every identified element (motor rows too when identified), the
    interval nominal +/- k std with k in meta; @1 files are still read and keep their tag."""
    from lpv_sysid.io.formats import MODELS_FORMAT, MODELS_FORMAT_V1, VertexModels
    from lpv_sysid.models.lpv import box_vertices

    q, rec = descending_run
    cfg = vx.IdentificationConfig(vmin=(-5, -5, -5), vmax=(5, 5, 5))
    data = dp.align(dp.streams_from_record(rec), cfg).vertex
    res = vx.identify_vertex(data, cfg, motor_prior=((12.0, 0.2), (14000.0, 150.0)))
    assert res.motor["mode"] in ("identified", "prior")
    # 43 aerodynamic + 8 motor + the known elements moving with the identified equilibrium
    assert len(res.uncertain.intervals) == 51 + N_FIXED
    results = [dataclasses.replace(res, scheduling=c) for c in box_vertices(cfg.vmin, cfg.vmax)]
    doc = vx.vertex_models_dict(results, cfg)
    assert doc["format"] == MODELS_FORMAT == "lpv_sysid/vertex_models@2"
    vm = VertexModels.from_dict(doc)
    es = vm.vertices[0].uncertain
    assert len(es) == 51 + N_FIXED and all(e.std > 0 for e in es)
    assert all(e.upper - e.nominal == pytest.approx(3 * e.std) for e in es)
    motor = [e for e in es if e.row >= 8]
    assert sorted((e.matrix, e.row, e.col) for e in motor) == sorted(
        [("A", 8 + j, 8 + j) for j in range(4)] + [("B", 8 + j, j) for j in range(4)]
    )
    assert doc["meta"]["std"]["t_factor"][0] == pytest.approx(ee.t_factor(3.0, res.fit.dof))
    vm.save(tmp_path / "m.yaml")
    assert VertexModels.load(tmp_path / "m.yaml").format_version == 2
    old = dict(doc, format=MODELS_FORMAT_V1)
    v1 = VertexModels.from_dict(old)
    assert v1.format_version == 1 and v1.to_dict()["format"] == MODELS_FORMAT_V1
    with pytest.raises(ConfigError, match=r"format: expected 'lpv_sysid/vertex_models@2' \(or "):
        VertexModels.from_dict(dict(doc, format="lpv_sysid/vertex_models@3"))


def test_motor_constants_pooled_where_a_rotor_is_pinned(descending_run):
    """At this descending vertex a rotor sits at omega_min for > 1 % of the time: the maneuver
    does not identify a_Omega, b_Omega itself but takes the other maneuvers' estimate as
    uncertain entries (identify_vertices), and its J_z terms inherit their error."""
    q, rec = descending_run
    cfg = vx.IdentificationConfig()
    data = dp.align(dp.streams_from_record(rec), cfg).vertex
    alone = vx.identify_vertex(data, cfg)
    assert alone.motor["mode"] == "known" and "speed limit" in alone.motor["reason"]
    assert len(alone.uncertain.intervals) == 43 + N_FIXED
    strict = dataclasses.replace(cfg, motor_max_pinned=1.0)
    forced = vx.identify_vertex(data, strict)
    assert forced.motor["mode"] == "identified"
    prior = vx.pooled_motor([forced])
    (a, sa), (b, sb) = prior
    assert abs(a - q.params.a_omega) < 4 * sa and abs(b - q.params.b_omega) < 4 * sb
    pooled = vx.identify_vertex(data, dataclasses.replace(cfg, motor="known"), motor_prior=prior)
    assert pooled.motor["mode"] == "prior" and len(pooled.uncertain.intervals) == 51 + N_FIXED
    iv = {(i.matrix, i.row, i.col): i for i in pooled.uncertain.intervals}
    assert iv[("A", 8, 8)].nominal == pytest.approx(-a) and iv[
        ("B", 9, 1)
    ].nominal == pytest.approx(b)
    assert iv[("B", 7, 3)].std > alone.fit.std_B[7, 3]  # J_z b_Omega with b uncertain


def test_remainder_hessians_are_exact():
    p = QuadrotorParams()
    x0 = Quadrotor(p).trim([3.0, -2.0, 1.0]).x0
    H = taylor.remainder_hessians(x0, p)
    rng = np.random.default_rng(0)
    dx = rng.normal(size=(5, 12)) * np.r_[0.05, 0.05, 1, 1, 1, 0.5, 0.5, 0.5, 40, 5, 5, 60]
    rem = taylor.remainders(x0, dx, p)
    for a in rem:
        quad = 0.5 * np.einsum("ni,kij,nj->nk", dx, H[a], dx)
        np.testing.assert_allclose(quad, rem[a], rtol=1e-7, atol=1e-9 * np.max(np.abs(rem[a])))


# ----------------------------------------------------------------------------- coverage study
def test_random_airframes_and_what_identification_is_told():
    base = QuadrotorParams()
    rng = np.random.default_rng(3)
    for _ in range(5):
        p = cv.random_airframe(base, rng, 0.25)
        f = [
            p.mass / base.mass,
            p.arm_length / base.arm_length,
            p.a_omega / base.a_omega,
            p.b_omega / base.b_omega,
        ] + [p.K[k] / base.K[k] for k in base.K if base.K[k] != 0]
        assert all(0.75 <= x <= 1.25 for x in f) and len(set(np.round(f, 6))) > 10
        told = QuadrotorParams.from_dict(cv.identification_params(p, base))
        assert (
            told.mass == p.mass and told.inertia == p.inertia and told.arm_length == p.arm_length
        )
        assert told.K == base.K and told.a_omega == base.a_omega and told.b_omega == base.b_omega
    with pytest.raises(ConfigError, match="spread"):
        cv.random_airframe(base, rng, 1.5)


def test_coverage_study_on_an_unseen_airframe():
    """One drawn airframe, one vertex, full-length flight: the stored intervals cover the
    airframe's own linearisation at its flown equilibrium (>= 97 % of 51 elements)."""
    from lpv_sysid.control.baseline import BaselineGains
    from lpv_sysid.sim import phase1 as p1
    from lpv_sysid.sim.vehicle import SensorConfig

    cfg = cv.CoverageConfig(airframes=1, seed=4, vertices=(2,))
    afs, _ = cv.run_study(
        cfg,
        QuadrotorParams(),
        BaselineGains(),
        SensorConfig(),
        p1.Phase1Config(),
        vx.IdentificationConfig(),
    )
    (af,) = afs
    assert af.params != QuadrotorParams() and af.n in (43 + N_FIXED, 51 + N_FIXED)
    assert af.fraction >= 0.97
    doc = cv.summary_dict(afs, QuadrotorParams(), cfg)
    assert doc["overall"]["elements"] == af.n and doc["overall"][
        "expected_fraction"
    ] == pytest.approx(0.9973, abs=1e-4)
    table = cv.markdown_table(afs, QuadrotorParams())
    assert f"| {af.covered} ({100 * af.fraction:.2f} %) |" in table


def test_coverage_cli(tmp_path, capsys):
    from lpv_sysid.cli.main import main

    out = tmp_path / "cov"
    assert (
        main(["coverage", "--airframes", "1", "--vertices", "3", "--seed", "2", "--out", str(out)])
        == 0
    )
    text = capsys.readouterr().out
    assert "airframe 1:" in text and f"wrote {out / 'coverage.yaml'}" in text
    import yaml

    doc = yaml.safe_load((out / "coverage.yaml").read_text())
    assert doc["format"] == "lpv_sysid/identification_coverage@1" and doc["study"]["vertices"] == [
        3
    ]
    assert doc["overall"]["elements"] in (43 + N_FIXED, 51 + N_FIXED)
    assert "| airframe | mass |" in (out / "coverage.md").read_text()
    assert main(["coverage", "--vertices", "9", "--out", str(out)]) == 2
    assert "1..8" in capsys.readouterr().err
