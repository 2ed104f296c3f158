"""Seed 0 Eq. (33) closed loop against analytic LTI solutions and an independent H-inf norm."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal
from scipy.linalg import solve_continuous_are

from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.sim.closed_loop import (
    ClosedLoopConfig,
    ReferenceSignals,
    hinf_norm_grid,
    l2_norm,
    performance_matrix,
    simulate_eq33,
    x0_dot,
)

RNG = np.random.default_rng(7)
N_X, N_U = 5, 5  # small system; velocity states are indices 2, 3, 4 as in DESIGN.md


class AffineModel:
    """Test-local ScheduledModel: affine in v_d, with K(v_d) chosen so A + B K = Acl."""

    def __init__(self, A0, A1, B, Acl, x0c, G, u0c, H):
        self.A0, self.A1, self.Bm, self.Acl = A0, A1, B, Acl
        self.x0c, self.G, self.u0c, self.H = x0c, G, u0c, H

    def A(self, v_d):
        return self.A0 + v_d[0] * self.A1

    def B(self, v_d):
        return self.Bm

    def K(self, v_d):
        return np.linalg.solve(self.Bm, self.Acl - self.A(v_d))

    def x0(self, v_d):
        return self.x0c + self.G @ v_d

    def u0(self, v_d):
        return self.u0c + self.H @ v_d

    def dx0_dvd(self, v_d):
        return self.G


def _stable_acl(A, B):
    P = solve_continuous_are(A, B, np.eye(A.shape[0]), np.eye(B.shape[1]))
    return A - B @ (B.T @ P)


def _model(scheduled: bool) -> AffineModel:
    A0 = RNG.normal(size=(N_X, N_X))
    B = RNG.normal(size=(N_X, N_U)) + 2 * np.eye(N_X)
    Acl = _stable_acl(A0, B)
    A1 = 0.1 * RNG.normal(size=(N_X, N_X)) if scheduled else np.zeros((N_X, N_X))
    G = RNG.normal(size=(N_X, 3)) if scheduled else np.zeros((N_X, 3))
    H = RNG.normal(size=(N_U, 3)) if scheduled else np.zeros((N_U, 3))
    return AffineModel(A0, A1, B, Acl, RNG.normal(size=N_X), G, RNG.normal(size=N_U), H)


def _signals(T=4.0, dt=0.01, scheduled=True):
    t = np.arange(0.0, T + dt / 2, dt)
    f = np.array([0.7, 1.3, 2.1, 3.4, 4.6])
    ue = np.stack([np.sin(2 * np.pi * f[i] * t + i) for i in range(N_U)], axis=1)
    vd = np.zeros((t.size, 3)) + np.array([1.0, -2.0, 0.5])
    if scheduled:
        vd[:, 0] = 4.0 * np.sin(2 * np.pi * 0.3 * t)
        vd[:, 1] += 1.5 * np.sin(2 * np.pi * 0.2 * t)
        vd[:, 2] += np.cos(2 * np.pi * 0.1 * t)
    return ReferenceSignals(t, vd, ue)


Q = np.diag([2.0, 3.0, 4.0])
R = np.diag([0.3, 0.2, 0.1, 0.4, 0.25])


def _lsim_z(model, sig, kappa):
    C = performance_matrix(Q, N_X)
    sys = signal.StateSpace(model.Acl, model.Bm @ R * kappa, C, np.zeros((3, N_U)))
    _, z, xs = signal.lsim(sys, sig.u_e, sig.t, X0=np.zeros(N_X), interp=True)
    return z, xs


@pytest.mark.parametrize("method", ["RK45", "rk4"])
def test_single_vertex_matches_lsim(method):
    """Constant v_d: Eq. (33) is LTI, dx' = (A+BK) dx + B R kappa u_e (FOH input, exact in
    lsim)."""
    model = _model(scheduled=False)
    sig = _signals(scheduled=False)
    res = simulate_eq33(
        model, sig, R, Q, gamma=1.0, config=ClosedLoopConfig(kappa=1.7, method=method)
    )
    z_ref, dx_ref = _lsim_z(model, sig, 1.7)
    scale = np.max(np.abs(z_ref))
    assert scale > 1e-3
    np.testing.assert_allclose(res.z_model, z_ref, atol=2e-6 * scale, rtol=0)
    np.testing.assert_allclose(
        res.x, dx_ref + model.x0(sig.v_d[0]), atol=1e-5 * np.max(np.abs(dx_ref))
    )
    # z_model of Eq. (19b) is the velocity perturbation from x0 scaled by Q^-1; z of Eq. (18)
    # differs from it by the (constant here) offset Q^-1 (v0(v_d) - v_d)
    np.testing.assert_allclose(res.z_model, np.linalg.solve(Q, res.dx[:, 2:5].T).T, atol=1e-12)
    offset = np.linalg.solve(Q, model.x0(sig.v_d[0])[2:5] - sig.v_d[0])
    np.testing.assert_allclose(res.z, res.z_model + offset, atol=1e-12)
    np.testing.assert_allclose(res.ue_norm, l2_norm(sig.t, 1.7 * sig.u_e))


@pytest.mark.parametrize("method", ["RK45", "rk4"])
def test_scheduled_reference_uses_eq34(method):
    """v_d(t) varies, A(v_d) varies but A + B K(v_d) is constant: x - x0(v_d(t)) must follow the
    LTI response exactly, which only holds when x0' of Eq. (34) is in the right-hand side."""
    model = _model(scheduled=True)
    sig = _signals(scheduled=True)
    res = simulate_eq33(model, sig, R, Q, config=ClosedLoopConfig(kappa=1.0, method=method))
    z_ref, dx_ref = _lsim_z(model, sig, 1.0)
    np.testing.assert_allclose(res.dx, dx_ref, atol=1e-5 * np.max(np.abs(dx_ref)))
    np.testing.assert_allclose(res.z_model, z_ref, atol=1e-5 * np.max(np.abs(z_ref)))
    # and the equilibrium moved a lot, so omitting x0' would have been visible
    assert np.ptp(res.x[:, 0]) > 10 * np.max(np.abs(dx_ref[:, 0]))


def test_x0_dot_is_chain_rule():
    model = _model(scheduled=True)
    sig = _signals(scheduled=True)
    t, h = 1.234, 1e-6
    vd, vd_dot, _ = sig.at(t)
    fd = (model.x0(sig.at(t + h)[0]) - model.x0(sig.at(t - h)[0])) / (2 * h)
    np.testing.assert_allclose(x0_dot(model, vd, vd_dot), fd, rtol=1e-6, atol=1e-8)


def test_hinf_grid_first_order_oracle():
    """G(s) = b / (s + a): ||G||_inf = b / a at w = 0; resonant 2nd order:
    peak 1/(2 zeta sqrt(1-zeta^2))."""
    nrm, w = hinf_norm_grid(np.array([[-2.0]]), np.array([[3.0]]), np.array([[1.0]]))
    assert nrm == pytest.approx(1.5, rel=1e-9) and w == 0.0
    wn, zeta = 3.0, 0.1
    A = np.array([[0.0, 1.0], [-(wn**2), -2 * zeta * wn]])
    nrm, w = hinf_norm_grid(A, np.array([[0.0], [wn**2]]), np.array([[1.0, 0.0]]))
    assert nrm == pytest.approx(1 / (2 * zeta * np.sqrt(1 - zeta**2)), rel=1e-6)
    assert w == pytest.approx(wn * np.sqrt(1 - 2 * zeta**2), rel=1e-4)
    assert hinf_norm_grid(np.array([[1.0]]), np.eye(1), np.eye(1))[0] == np.inf


def test_l2_gain_bounded_by_hinf_and_reaches_it_at_peak():
    """Achieved ||z||/||u_e|| <= ||C (sI - Acl)^-1 B R||_inf, and a sinusoid at the peak frequency
    along the top singular direction approaches the bound (so the check can fail)."""
    model = _model(scheduled=True)
    C = performance_matrix(Q, N_X)
    Bw = model.Bm @ R
    hinf, wpk = hinf_norm_grid(model.Acl, Bw, C)
    sig = _signals(scheduled=True)
    res = simulate_eq33(model, sig, R, Q, gamma=hinf, config=ClosedLoopConfig(method="rk4"))
    assert 0 < res.gain_model <= hinf

    G = C @ np.linalg.solve(1j * wpk * np.eye(N_X) - model.Acl, Bw)
    v = np.linalg.svd(G)[2].conj()[0]
    T = 60.0
    t = np.arange(0.0, T, 0.01)
    ue = np.real(np.outer(np.exp(1j * wpk * t), v))
    peak = ReferenceSignals(t, np.tile([0.5, 0.0, 0.0], (t.size, 1)), ue)
    res = simulate_eq33(model, peak, R, Q, gamma=hinf, config=ClosedLoopConfig(method="rk4"))
    assert 0.9 * hinf < res.gain_model <= hinf * (1 + 1e-6)
    # kappa scales u_e and z alike: the gain does not change (seed 0 Sec. VII)
    res2 = simulate_eq33(
        model, peak, R, Q, gamma=hinf, config=ClosedLoopConfig(method="rk4", kappa=3.0)
    )
    assert res2.gain_model == pytest.approx(res.gain_model, rel=1e-9)
    assert res2.ue_norm == pytest.approx(3.0 * res.ue_norm, rel=1e-12)


def test_bad_inputs():
    with pytest.raises(ConfigError, match="kappa"):
        ClosedLoopConfig(kappa=-1.0)
    t = np.arange(5) * 0.1
    with pytest.raises(ConfigError, match="NaN"):
        ReferenceSignals(t, np.full((5, 3), np.nan), np.zeros((5, 2)))
    with pytest.raises(ConfigError, match="increasing"):
        ReferenceSignals(t[::-1], np.zeros((5, 3)), np.zeros((5, 2)))
    model = _model(scheduled=False)
    model.Acl = -model.Acl + 5 * np.eye(N_X)  # unstable closed loop
    sig = _signals(T=30.0, scheduled=False)
    with pytest.raises(SafetyError, match="diverged"):
        simulate_eq33(
            model, sig, R, Q, config=ClosedLoopConfig(method="rk4", divergence_bound=1e3)
        )


def test_eq34_multilinear_model_against_finite_differences():
    """x0' of Eq. (34) with the multilinear interpolation of models/lpv/polytope.py (vertex
    equilibria that are not affine in v_d) equals the central difference of x0(v_d(t))."""
    from lpv_sysid.models.lpv import PolytopicModel, ScheduledLpv

    rng = np.random.default_rng(3)
    n, m = 4, 2
    A = rng.normal(size=(8, n, n))
    B = rng.normal(size=(8, n, m))
    pm = PolytopicModel(
        vmin=[-5, -5, -5],
        vmax=[5, 5, 5],
        A=A,
        B=B,
        x0=rng.normal(size=(8, n)),
        u0=rng.normal(size=(8, m)),
    )
    sched = ScheduledLpv(pm, rng.normal(size=(8, m, n)))
    t = np.arange(0.0, 10.0, 0.01)
    vd = np.column_stack([4 * np.sin(0.7 * t), 3 * np.cos(0.4 * t), 2 * np.sin(1.1 * t + 0.3)])
    sig = ReferenceSignals(t, vd, np.zeros((t.size, 1)))
    h = 1e-6
    for tk in (0.123, 2.505, 7.777):  # inside FOH segments (slope is one-sided at samples)
        v, vdot, _ = sig.at(tk)
        fd = (sched.x0(sig.at(tk + h)[0]) - sched.x0(sig.at(tk - h)[0])) / (2 * h)
        np.testing.assert_allclose(x0_dot(sched, v, vdot), fd, rtol=1e-5, atol=1e-7)
    # and against the analytic derivative of the smooth reference (FOH slope -> true slope)
    tk = 3.3
    v_true = np.array([4 * np.sin(0.7 * tk), 3 * np.cos(0.4 * tk), 2 * np.sin(1.1 * tk + 0.3)])
    vdot_true = np.array(
        [2.8 * np.cos(0.7 * tk), -1.2 * np.sin(0.4 * tk), 2.2 * np.cos(1.1 * tk + 0.3)]
    )
    fd = (sched.x0(v_true + h * vdot_true) - sched.x0(v_true - h * vdot_true)) / (2 * h)
    np.testing.assert_allclose(x0_dot(sched, v_true, vdot_true), fd, rtol=1e-6, atol=1e-8)


def test_lemma1_gains_frozen_point_gain_below_certificate():
    """Gains from the Lemma 1 synthesis (synthesis.hinf_lmi) on the 12-state quadrotor-like
    polytope: at a frozen interior v_d, Eq. (33) is LTI and its achieved L2 gain is below the
    independent H-inf norm, which is below the certified gamma."""
    from lpv_sysid.models.lpv import ScheduledLpv
    from lpv_sysid.synthesis.example_models import quadrotor_like_polytope
    from lpv_sysid.synthesis.hinf import HinfOptions, excitation_R, output_Q, synthesize_hinf
    from lpv_sysid.synthesis.hinf import performance_matrix as pm_C

    pm = quadrotor_like_polytope()
    Rq, Qq = excitation_R([0.1] * 4, 30.0), output_Q([5.0] * 3, 30.0)
    res = synthesize_hinf(pm, Rq, pm_C(Qq, 12, (2, 3, 4)), HinfOptions(gamma=1.0))
    sched = ScheduledLpv(pm, res.K)
    vd = np.array([1.5, -2.0, 0.7])
    t = np.arange(0.0, 20.0, 0.01)
    ue = np.column_stack(
        [np.sin(2 * np.pi * f * t + k) for k, f in enumerate((0.6, 1.1, 1.9, 2.7))]
    )
    ue /= np.sqrt(np.trapz(np.sum(ue**2, axis=1), t))  # unit energy, Eq. (26)
    sig = ReferenceSignals(t, np.tile(vd, (t.size, 1)), ue)
    out = simulate_eq33(sched, sig, Rq, Qq, gamma=1.0, config=ClosedLoopConfig(method="rk4"))
    Acl = sched.A(vd) + sched.B(vd) @ sched.K(vd)
    hinf, _ = hinf_norm_grid(Acl, sched.B(vd) @ Rq, performance_matrix(Qq, 12))
    assert out.ue_norm == pytest.approx(1.0, rel=1e-3)
    assert 0 < out.gain_model <= hinf <= res.gamma_certified <= 1.0
