"""control/law/controller.py: the runtime law of seed 0 Eqs. (17), (31) on hand-computed numbers
and, step by step, against the law written from its equations."""

from types import SimpleNamespace

import numpy as np
import pytest

from lpv_sysid.control.law import LpvController, LpvControllerConfig
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.models.quadrotor import mixer


def _schedule(gamma=1.0):
    # vertex i: K_i = i * E (E = ones), x0_i = i * 0.1 * ones(12), u0_i = (i, 0, 0, 0) * 0.01 + 0.5
    K = np.array([i * np.ones((4, 12)) * 1e-3 for i in range(8)])
    x0 = np.array([i * 0.1 * np.ones(12) for i in range(8)])
    u0 = np.array([[0.5 + 0.01 * i, 0.0, 0.0, 0.0] for i in range(8)])
    return SimpleNamespace(
        K=K,
        x0=x0,
        u0=u0,
        R=np.diag([0.1, 0.2, 0.3, 0.4]),
        Q=np.diag([2.0, 4.0, 5.0]),
        gamma=gamma,
        vmin=np.array([-5.0, -5.0, -5.0]),
        vmax=np.array([5.0, 5.0, 5.0]),
    )


def test_law_equals_formula_on_hand_computed_numbers():
    ctl = LpvController(_schedule())
    # v_d = (0, -5, 5): t = (0.5, 0, 1) -> weights nonzero only at vertices (b=0, c=1): i = 1
    # and 5, alpha_1 = (1-0.5)*1*1 = 0.5, alpha_5 = 0.5 -> K = 3e-3 * ones, x0 = 0.3 * ones,
    # u0 = (0.53, 0, 0, 0)
    x = np.full(12, 1.3)
    u_e = np.array([1.0, -1.0, 2.0, 0.5])
    u, info = ctl.step(0.0, x, np.array([0.0, -5.0, 5.0]), u_e)
    # K (x - x0) = 3e-3 * 12 * 1.0 = 0.036 per channel; R u_e = (0.1, -0.2, 0.6, 0.2)
    np.testing.assert_allclose(
        u, [0.53 + 0.036 + 0.1, 0.036 - 0.2, 0.036 + 0.6, 0.036 + 0.2], rtol=1e-14
    )
    assert not info["clamped"] and not info["saturated"]


def test_weights_match_models_lpv():
    from lpv_sysid.models.lpv import multilinear_weights

    ctl = LpvController(_schedule())
    rng = np.random.default_rng(2)
    for _ in range(20):
        vd = rng.uniform(-5, 5, 3)
        np.testing.assert_allclose(
            ctl.weights(vd)[0],
            multilinear_weights(vd, -5 * np.ones(3), 5 * np.ones(3))[0],
            atol=1e-15,
        )


def test_mixer_saturation_clips_per_motor_commands():
    mix = mixer(0.225)
    ctl = LpvController(_schedule(), mix=mix)
    u, info = ctl.step(
        0.0, np.zeros(12), np.zeros(3), np.array([20.0, 0.0, 0.0, 0.0])
    )  # huge thrust
    esc = np.linalg.solve(mix, u)
    assert info["saturated"]
    assert np.all(esc <= 1.0 + 1e-12) and np.all(esc >= -1e-12)
    unsat = LpvController(_schedule()).step(
        0.0, np.zeros(12), np.zeros(3), np.array([20.0, 0, 0, 0])
    )[0]
    np.testing.assert_allclose(u, mix @ np.clip(np.linalg.solve(mix, unsat), 0, 1), rtol=1e-12)


def test_clamp_nan_time_and_shape_errors():
    ctl = LpvController(_schedule())
    u_out, info = ctl.step(0.0, np.zeros(12), np.array([9.0, 0.0, 0.0]), np.zeros(4))
    assert info["clamped"]
    u_edge, _ = LpvController(_schedule()).step(
        0.0, np.zeros(12), np.array([5.0, 0.0, 0.0]), np.zeros(4)
    )
    np.testing.assert_allclose(u_out, u_edge)
    with pytest.raises(SafetyError, match="x"):
        ctl.step(0.1, np.full(12, np.nan), np.zeros(3), np.zeros(4))
    with pytest.raises(SafetyError, match="u_e"):
        ctl.step(0.1, np.zeros(12), np.zeros(3), np.array([0, np.inf, 0, 0]))
    with pytest.raises(SafetyError, match="backwards"):
        ctl.step(-1.0, np.zeros(12), np.zeros(3), np.zeros(4))
    with pytest.raises(SafetyError, match="shapes"):
        ctl.step(1.0, np.zeros(11), np.zeros(3), np.zeros(4))


def test_rate_limit():
    ctl = LpvController(_schedule(), LpvControllerConfig(rate_limit=(1.0, 1.0, 1.0, 1.0)))
    u0, _ = ctl.step(0.0, np.zeros(12), np.zeros(3), np.zeros(4))
    u1, info = ctl.step(
        0.01, np.zeros(12), np.zeros(3), np.array([1.0, 0, 0, 0])
    )  # wants +0.1 in ut
    assert info["rate_limited"]
    np.testing.assert_allclose(u1 - u0, [0.01, 0, 0, 0], atol=1e-15)


def test_bound_monitor_gain_and_flag_only_after_enough_energy():
    # constant z: v - v_d = (2, 0, 0) -> z = Q^-1 dv = (1, 0, 0); |u_e| = 0.5 -> gain = 1 / 0.5 = 2
    ctl = LpvController(
        _schedule(gamma=1.0), LpvControllerConfig(monitor_margin=1.5, monitor_min_energy=0.1)
    )
    x = np.zeros(12)
    x[2] = 2.0
    ue = np.array([0.5, 0.0, 0.0, 0.0])
    dt = 0.01
    flags = []
    for k in range(100):
        _, info = ctl.step(k * dt, x, np.zeros(3), ue)
        flags.append((info["bound_judged"], info["bound_exceeded"]))
    assert abs(ctl.gain() - 2.0) < 1e-12
    # energy of u_e reaches 0.1 after 0.1 / 0.25 = 0.4 s = 40 steps (the first step has dt = 0)
    first_judged = [f[0] for f in flags].index(True)
    assert first_judged == 40
    assert not any(f[1] for f in flags[:first_judged]) and flags[-1][1]
    ok = LpvController(
        _schedule(gamma=1.5), LpvControllerConfig(monitor_margin=1.5, monitor_min_energy=0.1)
    )
    for k in range(100):
        _, info = ok.step(k * dt, x, np.zeros(3), ue)
    assert not info["bound_exceeded"]  # 2 < 1.5 * 1.5


def test_config_validation():
    with pytest.raises(ConfigError):
        LpvControllerConfig.from_dict({"margin": 1})
    with pytest.raises(ConfigError):
        LpvController(_schedule(), mix=np.eye(3))


# ------------------------------------------------ the fast step against the seed equations
def _shipped_schedule(non_diagonal_weights=False):
    """msg_samples/gains.yaml (8 vertices, 12 states, 4 inputs) with the reference feedforward
    F_ff and F_jerk that synthesize writes by default (synthesis.feedforward on the sample's
    certified trim linearisations), as the one gains class (io.formats.GainSchedule)."""
    import os

    from lpv_sysid.io.formats import GainSchedule, load_certified_systems
    from lpv_sysid.synthesis.feedforward import FeedforwardLayout, vertex_feedforward

    path = os.path.join(os.path.dirname(os.path.dirname(__file__)), "msg_samples", "gains.yaml")
    gs = GainSchedule.load(path)
    systems = load_certified_systems(
        path, gs.certificate, len(gs.state_names), len(gs.input_names), "gains"
    )
    A = np.array([s[0][0] for s in systems])
    B = np.array([s[0][1] for s in systems])
    layout = FeedforwardLayout()
    F, Fj = vertex_feedforward(A, B, gs.state_names, layout)
    doc = gs.to_dict()
    doc["feedforward"] = layout.to_dict()
    for i, v in enumerate(doc["vertices"]):
        v["F_ff"], v["F_jerk"] = F[i].tolist(), Fj[i].tolist()
    if non_diagonal_weights:
        doc["Q"] = [[5.0, 0.5, 0.0], [0.5, 4.0, -0.3], [0.0, -0.3, 6.0]]
        doc["R"] = (np.array(doc["R"]) + 0.01 * np.arange(16).reshape(4, 4) / 16).tolist()
    return GainSchedule.from_dict(doc), layout


class _SeedLaw:
    """The law written out from its equations, independently of control/law/controller.py:
    seed 0 Eq. 21 weights (product over axes, corners of models.lpv.box_vertices' order),
    K(alpha) = sum alpha_i K_i (Eq. 31) and likewise x0, u0, F_ff, F_jerk (seed 2 Eq. 102),
    u = u0 + du_ff + K (x - x0 - dx_ff) + R u_e, the derivative filter of the module docstring,
    mixer limits (seed 0 Eq. 7), rate limit and the Eq. 18 monitor energies."""

    def __init__(self, gs, layout, cfg, mix):
        import itertools

        self.gs, self.cfg, self.mix = gs, cfg, mix
        self.lo, self.hi = np.asarray(gs.vmin, float), np.asarray(gs.vmax, float)
        self.corners = list(itertools.product((0, 1), repeat=self.lo.size))
        names = list(gs.state_names)
        self.free = [names.index(s) for s in layout.free_states]
        self.rate = [names.index(s) for s in layout.rate_states]
        self.K, self.x0, self.u0 = gs.K, gs.x0, gs.u0
        self.F = gs.F_ff if cfg.feedforward else None
        self.Fj = gs.F_jerk if cfg.feedforward else None
        self.Qinv = np.linalg.inv(gs.Q)
        self.t_prev = self.u_prev = self.y = self.y2 = None
        self.a = self.j = np.zeros(self.lo.size)
        self.Ez = self.Ee = self.Ee_total = 0.0

    def step(self, t, x, v_d, u_e):
        s = np.clip((v_d - self.lo) / (self.hi - self.lo), 0.0, 1.0)
        alpha = np.array(
            [np.prod([s[k] if c[k] else 1.0 - s[k] for k in range(s.size)]) for c in self.corners]
        )
        dt = 0.0 if self.t_prev is None else t - self.t_prev
        if self.y is None:
            self.y, self.y2 = v_d.copy(), np.zeros_like(v_d)
        elif dt > 0:
            k1 = 1.0 - np.exp(-dt / self.cfg.ff_filter_tau)
            k2 = 1.0 - np.exp(-dt / self.cfg.ff_jerk_tau)
            y = self.y + k1 * (v_d - self.y)
            self.a = (y - self.y) / dt
            y2 = self.y2 + k2 * (self.a - self.y2)
            self.j = (y2 - self.y2) / dt
            self.y, self.y2 = y, y2
        K = np.einsum("i,ijk->jk", alpha, self.K)
        x_ref, u_ref = alpha @ self.x0, alpha @ self.u0
        if self.F is not None:
            nf, m = len(self.free), u_ref.size
            Fa = np.einsum("i,ijk->jk", alpha, self.F) @ self.a
            Fj = np.einsum("i,ijk->jk", alpha, self.Fj) @ self.j
            x_ref[self.free] += Fa[:nf] + Fj[:nf]
            x_ref[self.rate] += Fj[nf + m :]
            u_ref = u_ref + Fa[nf:] + Fj[nf : nf + m]
        u = u_ref + K @ (x - x_ref) + self.gs.R @ u_e
        lo, hi = self.cfg.u_esc_min, self.cfg.u_esc_max

        def limit(u):
            esc = np.linalg.solve(self.mix, u)
            if esc.min() < lo or esc.max() > hi:
                return self.mix @ np.clip(esc, lo, hi)
            return u

        u = limit(u)
        if self.cfg.rate_limit is not None and self.u_prev is not None:
            r = np.asarray(self.cfg.rate_limit) * dt
            if np.any(np.abs(u - self.u_prev) > r):
                u = limit(self.u_prev + np.clip(u - self.u_prev, -r, r))
        if dt > 0:
            z = self.Qinv @ (x[2:5] - v_d)
            self.Ez += z @ z * dt
            self.Ee += u_e @ u_e * dt
            self.Ee_total += u_e @ u_e * dt
        self.t_prev, self.u_prev = t, u
        return u


@pytest.mark.parametrize(
    "cfg, non_diagonal",
    [
        (LpvControllerConfig(), False),  # the shipped default: feedforward (a, j filtered)
        (LpvControllerConfig(), True),
        (LpvControllerConfig(feedforward=False, rate_limit=(2.0, 20.0, 20.0, 2.0)), False),
    ],
)
def test_step_equals_the_seed_equations_on_a_recorded_sequence(cfg, non_diagonal):
    """2000 steps at 250 Hz of a v_d that sweeps across and beyond the box, noisy states and
    excitation: every command equals the law written from its equations to 1e-12, and so do
    the monitor's gain, the clamp and saturation flags."""
    gs, layout = _shipped_schedule(non_diagonal)
    mix = mixer(0.225)
    ctl = LpvController(gs, cfg, mix=mix)
    ref = _SeedLaw(gs, layout, cfg, mix)
    rng = np.random.default_rng(7)
    n, dt = 2000, 0.004
    tt = np.arange(n) * dt
    vd = np.column_stack([6.0 * np.sin(0.9 * tt), 3.0 * np.cos(0.5 * tt), 5.5 * np.sin(0.3 * tt)])
    vd = vd + 0.01 * np.round(tt * 100)[:, None] % 2  # a 50 Hz staircase on top
    x = np.tile(gs.x0.mean(axis=0), (n, 1)) + 0.05 * rng.normal(size=(n, 12))
    x[:, 2:5] = vd + 0.3 * rng.normal(size=(n, 3))
    ue = 0.3 * rng.normal(size=(n, 4))
    n_sat = n_clamped = 0
    for k in range(n):
        u, info = ctl.step(tt[k], x[k], vd[k], ue[k])
        u_ref = ref.step(tt[k], x[k], vd[k], ue[k])
        np.testing.assert_allclose(u, u_ref, rtol=0, atol=1e-12)
        s = (vd[k] - gs.vmin) / (gs.vmax - gs.vmin)
        assert info["clamped"] == bool(np.any((s < 0) | (s > 1)))
        n_sat += info["saturated"]
        n_clamped += info["clamped"]
    assert 0 < n_clamped < n and n_sat > 0  # both branches exercised
    assert ctl.gain() == pytest.approx(np.sqrt(ref.Ez / ref.Ee), rel=1e-12)
    if cfg.feedforward:
        np.testing.assert_allclose(info["a_ff"], ref.a, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(info["j_ff"], ref.j, rtol=1e-12, atol=1e-12)


def test_rejected_state_leaves_the_law_untouched():
    """A non-finite x is refused before the derivative filter or the monitor move: the next
    good step gives the command of a law that never saw the bad one."""
    gs, _ = _shipped_schedule()
    a, b = LpvController(gs, mix=mixer(0.225)), LpvController(gs, mix=mixer(0.225))
    x = gs.x0.mean(axis=0)
    for ctl in (a, b):
        ctl.step(0.0, x, np.zeros(3), np.zeros(4))
    bad = x.copy()
    bad[7] = np.inf
    with pytest.raises(SafetyError, match="non-finite input in x"):
        a.step(0.004, bad, np.array([1.0, 0.0, 0.0]), np.zeros(4))
    ua, _ = a.step(0.008, x, np.array([0.5, 0.0, 0.0]), np.full(4, 0.1))
    ub, _ = b.step(0.008, x, np.array([0.5, 0.0, 0.0]), np.full(4, 0.1))
    np.testing.assert_array_equal(ua, ub)
    assert a.gain() == b.gain()
