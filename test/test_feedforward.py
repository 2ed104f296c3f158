"""Reference feedforward (synthesis/feedforward.py, seed 2 Sec. 5.1) end to end: the matrices
F_i / F_jerk,i, the runtime law with feedforward, the derivative filter, gains.yaml round trip
and the verifier's recomputation."""

import copy
import itertools
from types import SimpleNamespace

import numpy as np
import pytest

from lpv_sysid.control.law import LpvController, LpvControllerConfig
from lpv_sysid.errors import ConfigError
from lpv_sysid.io import formats as fm
from lpv_sysid.models import quadrotor as qr
from lpv_sysid.models.lpv import PolytopicModel
from lpv_sysid.synthesis import feedforward as ff
from lpv_sysid.synthesis.verify import VerifyReport, check_feedforward

G = 9.80665
# a 4-state toy: attitude th, velocity v, rate q, actuator d; input u
TOY_NAMES = ("th", "v", "q", "d")
TOY_LAYOUT = ff.FeedforwardLayout(
    free_states=("th", "d"),
    accelerated_states=("v",),
    held_states=("q", "d"),
    kinematic_states=("th",),
    rate_states=("q",),
)


def toy(g=G, c=-0.3, k=40.0, a=12.0, b=1.4e4, e=0.0):
    """th' = q; v' = -g th + c v + e q; q' = k d; d' = -a d + b u."""
    A = np.array([[0, 0, 1, 0], [-g, c, e, 0], [0, 0, 0, k], [0, 0, 0, -a]], dtype=float)
    B = np.array([[0], [0], [0], [b]], dtype=float)
    return A, B


# ------------------------------------------------------------------ F on hand / random systems
def test_toy_F_is_the_analytic_tilt():
    A, B = toy()
    F = ff.feedforward_matrix(A, B, TOY_NAMES, TOY_LAYOUT)
    # v' = a with q' = 0, d' = 0 -> th = -a/g, d = 0, u = 0 (rows: th, d, u)
    np.testing.assert_allclose(F[:, 0], [-1.0 / G, 0.0, 0.0], atol=1e-15)


def test_toy_jerk_term_is_the_analytic_rate_and_omega_x_v_compensation():
    A, B = toy(e=5.0)  # v' also gets +5 q (the body-axis -omega x v term)
    F = ff.feedforward_matrix(A, B, TOY_NAMES, TOY_LAYOUT)
    Fj = ff.jerk_matrix(A, B, TOY_NAMES, F, TOY_LAYOUT)
    # th_ff = -a/g moves at -j/g -> q_ff = -j/g; its v' effect 5 q_ff = -5 j/g is cancelled by
    # th_j = 5 q_ff / g = -5 j / g^2 (rows: th, d, u, q)
    np.testing.assert_allclose(Fj[:, 0], [-5.0 / G**2, 0.0, 0.0, -1.0 / G], rtol=1e-12, atol=1e-15)


def test_random_quadrotor_sized_systems_produce_the_requested_acceleration():
    rng = np.random.default_rng(3)
    lay = ff.FeedforwardLayout()
    free, acc, held = lay.indices(qr.STATE_NAMES)
    for _ in range(5):
        A = rng.normal(size=(12, 12))
        B = rng.normal(size=(12, 4))
        F = ff.feedforward_matrix(A, B, qr.STATE_NAMES)
        a = rng.normal(size=3)
        dx = np.zeros(12)
        dx[free] = F[:6] @ a
        du = F[6:] @ a
        xdot = A @ dx + B @ du  # independent evaluation of the linear model
        np.testing.assert_allclose(xdot[acc], a, atol=1e-10)
        np.testing.assert_allclose(xdot[held], 0.0, atol=1e-10)
        assert np.all(dx[[2, 3, 4, 5, 6, 7]] == 0.0)  # Delta v = 0, Delta omega = 0


def test_singular_system_is_refused_with_a_clear_error():
    A, B = toy()
    A[1, 0] = 0.0  # attitude no longer moves v: no tilt gives v' = a
    with pytest.raises(ConfigError, match="ill-conditioned"):
        ff.feedforward_matrix(A, B, TOY_NAMES, TOY_LAYOUT)
    with pytest.raises(ConfigError, match="not among the model states"):
        ff.feedforward_matrix(A, B, ("x", "v", "q", "d"), TOY_LAYOUT)


# ------------------------------------------------------------------ the quadrotor
@pytest.mark.parametrize("v_body", [(0.0, 0.0, 0.0), (3.0, -2.0, 1.0)])
def test_quadrotor_F_matches_the_nonlinear_quasi_steady_tilt(v_body):
    quad = qr.Quadrotor(qr.QuadrotorParams())
    trim = quad.trim(np.array(v_body))
    A, B = quad.linearize(trim)
    F = ff.feedforward_matrix(A, B, qr.STATE_NAMES)
    a = np.array([0.5, -0.3, 0.2])
    y = F @ a
    if v_body == (0.0, 0.0, 0.0):
        # hover: theta = -a_x / g, phi = a_y / g (small-angle quasi-steady tilt)
        assert y[1] == pytest.approx(-np.arctan(a[0] / G), rel=0.02)
        assert y[0] == pytest.approx(np.arctan(a[1] / G), rel=0.02)
    # the nonlinear model at (trim + dx_ff, u0 + du_ff) accelerates by ~a, omega' ~ 0 (Eq. 3, 6)
    controller_state = trim.x0.copy()
    controller_state[[0, 1, 8, 9, 10, 11]] += y[:6]
    u = trim.u0 + y[6:]
    x16 = qr.full_state(controller_state)
    xd = quad.derivatives(x16, u)
    np.testing.assert_allclose(xd[6:9], a, atol=0.02)  # body acceleration, second-order error
    np.testing.assert_allclose(xd[9:12], 0.0, atol=0.05)  # angular acceleration
    np.testing.assert_allclose(xd[12:16], 0.0, atol=1.0)  # rotor speeds (rad/s^2, Omega ~ 600)


# ------------------------------------------------------------------ runtime law
def _toy_schedule(jerk=False):
    """2 vertices on v_d in [-1, 1]; toy 4-state plant, 1 input, feedforward layout TOY_LAYOUT."""
    K = np.array([[[0.1, 0.2, 0.3, 0.4]], [[0.3, 0.4, 0.5, 0.6]]])
    x0 = np.array([[0.0, -1.0, 0.0, 1.0], [0.2, 1.0, 0.0, 3.0]])
    u0 = np.array([[0.4], [0.6]])
    F = np.array([[[-0.1], [0.0], [0.2]], [[-0.3], [0.0], [0.4]]])  # rows th, d, u
    Fj = np.array(
        [[[0.01], [0.02], [0.03], [0.04]], [[0.03], [0.04], [0.05], [0.06]]]
    )  # th, d, u, q
    jerk_states = {"kinematic_states": ("th",), "rate_states": ("q",)} if jerk else {}
    spec = fm.FeedforwardSpec(("th", "d"), ("v",), ("q", "d"), **jerk_states)
    return SimpleNamespace(
        K=K,
        x0=x0,
        u0=u0,
        R=np.array([[2.0]]),
        Q=np.array([[1.0]]),
        gamma=1.0,
        vmin=np.array([-1.0]),
        vmax=np.array([1.0]),
        F_ff=F,
        F_jerk=Fj if jerk else None,
        feedforward=spec,
        state_names=TOY_NAMES,
    )


def test_runtime_law_with_feedforward_equals_the_formula():
    cfg = LpvControllerConfig(velocity_index=(1,))
    ctl = LpvController(_toy_schedule(), cfg)
    # v_d = 0.5 -> alpha = (0.25, 0.75): K = (0.25, 0.35, 0.45, 0.55), x0 = (0.15, 0.5, 0, 2.5),
    # u0 = 0.55, F = (-0.25, 0, 0.35); a = 2 -> dx_ff = (-0.5, 0, 0, 0), du_ff = 0.7
    x = np.array([0.1, 0.4, 0.2, 2.0])
    u, info = ctl.step(0.0, x, np.array([0.5]), np.array([0.1]), a=np.array([2.0]))
    e = x - np.array([0.15 - 0.5, 0.5, 0.0, 2.5])
    assert e == pytest.approx([0.45, -0.1, 0.2, -0.5])  # the numbers written out below
    expected = 0.55 + 0.7 + (0.25 * 0.45 - 0.35 * 0.1 + 0.45 * 0.2 - 0.55 * 0.5) + 2.0 * 0.1
    assert u[0] == pytest.approx(expected, rel=1e-13)
    assert info["feedforward"] and info["a_ff"][0] == 2.0
    # feedforward off (config) or a = 0: the seed's law
    u_off, _ = LpvController(
        _toy_schedule(), LpvControllerConfig(velocity_index=(1,), feedforward=False)
    ).step(0.0, x, np.array([0.5]), np.array([0.1]), a=np.array([2.0]))
    e0 = x - np.array([0.15, 0.5, 0.0, 2.5])
    assert u_off[0] == pytest.approx(
        0.55 + np.array([0.25, 0.35, 0.45, 0.55]) @ e0 + 0.2, rel=1e-13
    )


def test_runtime_law_jerk_term_equals_the_formula():
    ctl = LpvController(_toy_schedule(jerk=True), LpvControllerConfig(velocity_index=(1,)))
    x = np.array([0.1, 0.4, 0.2, 2.0])
    u, info = ctl.step(
        0.0, x, np.array([0.5]), np.array([0.0]), a=np.array([2.0]), j=np.array([-1.0])
    )
    # F_jerk(0.5) = (0.025, 0.035, 0.045, 0.055) * j = -1 -> th -0.025, d -0.035, u -0.045, q
    # -0.055
    x_ref = np.array([0.15 - 0.5 - 0.025, 0.5, -0.055, 2.5 - 0.035])
    K = np.array([0.25, 0.35, 0.45, 0.55])
    assert u[0] == pytest.approx(0.55 + 0.7 - 0.045 + K @ (x - x_ref), rel=1e-13)
    assert info["j_ff"][0] == -1.0


def test_derivative_filter_recovers_ramp_slope_and_constant_jerk():
    ctl = LpvController(
        _toy_schedule(jerk=True),
        LpvControllerConfig(velocity_index=(1,), ff_filter_tau=0.05, ff_jerk_tau=0.2),
    )
    x = np.zeros(4)
    dt = 0.004
    for k in range(1500):  # 6 s = 120 tau: transient gone
        t = k * dt
        v = -0.9 + 0.25 * t  # ramp 0.25 m/s^2
        _, info = ctl.step(t, x, np.array([v]), np.array([0.0]))
    assert info["a_ff"][0] == pytest.approx(0.25, rel=1e-9)
    assert info["j_ff"][0] == pytest.approx(0.0, abs=1e-9)
    ctl.reset()
    for k in range(2500):  # v = 0.05 t^2: a = 0.1 t, j = 0.1
        t = k * dt
        _, info = ctl.step(t, x, np.array([-0.9 + 0.05 * t * t]), np.array([0.0]))
    assert info["j_ff"][0] == pytest.approx(0.1, rel=1e-6)
    # a lags the true 0.1 t by the first stage's delay tau (ramp input to a first-order lag)
    assert info["a_ff"][0] == pytest.approx(0.1 * (t - 0.05), rel=1e-3)


def test_monitor_window_forgets_an_old_transient():
    sched = _toy_schedule()
    x = np.zeros(4)
    run = LpvController(sched, LpvControllerConfig(velocity_index=(1,), feedforward=False))
    win = LpvController(
        sched, LpvControllerConfig(velocity_index=(1,), feedforward=False, monitor_window=2.0)
    )
    dt = 0.01
    for k in range(2001):  # z = 3 for 1 s, then 0.5 with |u_e| = 1 throughout
        t = k * dt
        x[1] = 3.0 if t < 1.0 else 0.5
        for c in (run, win):
            c.step(t, x, np.array([0.0]), np.array([1.0]))
    # rectangle rule on steps k = 1..2000: z^2 = 9 for k <= 99 (t < 1 s), 0.25 after
    assert run.gain() == pytest.approx(np.sqrt((99 * 9.0 + 1901 * 0.25) / 2000.0), rel=1e-12)
    assert win.gain() == pytest.approx(0.5, rel=1e-3)  # exp(-19/2) weight on the transient: gone
    with pytest.raises(ConfigError):
        LpvControllerConfig.from_dict({"monitor_window": -1.0})
    with pytest.raises(ConfigError):
        LpvControllerConfig.from_dict({"ff_filter_tau": float("nan")})


# ------------------------------------------------------------------ gains.yaml and verify
LO, HI = [-5.0, -4.0, -2.0], [5.0, 4.0, 2.0]


def _quad_models():
    quad = qr.Quadrotor(qr.QuadrotorParams())
    As, Bs, x0s, u0s = [], [], [], []
    for c in itertools.product(*zip(LO, HI)):
        tr = quad.trim(np.array(c))
        A, B = quad.linearize(tr)
        As.append(A), Bs.append(B), x0s.append(tr.x0), u0s.append(tr.u0)
    return PolytopicModel(
        vmin=LO,
        vmax=HI,
        A=np.array(As),
        B=np.array(Bs),
        x0=np.array(x0s),
        u0=np.array(u0s),
        state_names=qr.STATE_NAMES,
        input_names=qr.INPUT_NAMES,
    )


@pytest.fixture(scope="module")
def quad_ff():
    model = _quad_models()
    lay = ff.FeedforwardLayout()
    F, Fj = ff.vertex_feedforward(model.A, model.B, qr.STATE_NAMES, lay)
    return model, lay, F, Fj


def _gains_doc(model, F=None, Fj=None, lay=None):
    rng = np.random.default_rng(1)
    d = {
        "format": fm.GAINS_FORMAT,
        "states": [{"name": n, "unit": u} for n, u in zip(qr.STATE_NAMES, qr.STATE_UNITS)],
        "inputs": [{"name": n, "unit": u} for n, u in zip(qr.INPUT_NAMES, qr.INPUT_UNITS)],
        "scheduling": {"names": list(qr.SCHEDULING_NAMES), "min": LO, "max": HI},
        "vertices": [
            {
                "scheduling": model.vertices[i].tolist(),
                "K": rng.normal(size=(4, 12)).tolist(),
                "x0": model.x0[i].tolist(),
                "u0": model.u0[i].tolist(),
            }
            for i in range(8)
        ],
        "R": np.diag([0.1, 0.02, 0.02, 0.05]).tolist(),
        "Q": np.eye(3).tolist(),
        "gamma": 1.0,
        "certificate": {
            "lmi": "seed 0 Lemma 1",
            "solver": "CLARABEL",
            "gamma_achieved": 0.9,
            "min_margin": 1e-6,
            "models_sha256": "0" * 64,
        },
    }
    if F is not None:
        d["feedforward"] = lay.to_dict()
        for i, v in enumerate(d["vertices"]):
            v["F_ff"] = F[i].tolist()
            if Fj is not None:
                v["F_jerk"] = Fj[i].tolist()
    return d


def test_gains_round_trip_with_and_without_feedforward(tmp_path, quad_ff):
    model, lay, F, Fj = quad_ff
    plain = fm.GainSchedule.from_dict(fm.certify_law(_gains_doc(model)))
    assert plain.F_ff is None and plain.F_jerk is None and plain.feedforward is None
    plain.save(tmp_path / "plain.yaml")
    back = fm.GainSchedule.load(tmp_path / "plain.yaml")
    assert back.F_ff is None and "feedforward" not in (tmp_path / "plain.yaml").read_text()
    gs = fm.GainSchedule.from_dict(fm.certify_law(_gains_doc(model, F, Fj, lay)))
    gs.save(tmp_path / "ff.yaml")
    back = fm.GainSchedule.load(tmp_path / "ff.yaml")
    np.testing.assert_array_equal(back.F_ff, F)
    np.testing.assert_array_equal(back.F_jerk, Fj)
    assert back.feedforward.free_states == lay.free_states and back.feedforward.rate_states == (
        "p",
        "q",
        "r",
    )
    # F_ff without F_jerk layout (older layout without the jerk keys)
    lay0 = ff.FeedforwardLayout(kinematic_states=(), rate_states=())
    only = fm.GainSchedule.from_dict(_gains_doc(model, F, None, lay0))
    assert only.F_jerk is None and only.F_ff.shape == (8, 10, 3)
    # the controller accepts the loaded schedule and interpolates F
    ctl = LpvController(back)
    assert ctl.has_ff and ctl.has_jerk


@pytest.mark.parametrize(
    "edit, msg",
    [
        (lambda d: d["vertices"][2]["F_ff"].pop(), "vertices[2].F_ff: expected shape 10x3"),
        (
            lambda d: d["vertices"][0]["F_ff"][1].__setitem__(0, float("nan")),
            "vertices[0].F_ff[1][0]: must be finite",
        ),
        (lambda d: d["vertices"][4].pop("F_ff"), "vertices[4]: missing key 'F_ff'"),
        (lambda d: d.pop("feedforward"), "vertices[0].F_ff: given but the file has no top-level"),
        (
            lambda d: d["feedforward"].__setitem__("free_states", ["phi", "psi"]),
            "feedforward.free_states",
        ),
        (lambda d: d["vertices"][1].pop("F_jerk"), "vertices[1]: missing key 'F_jerk'"),
    ],
)
def test_broken_feedforward_entries_are_named(quad_ff, edit, msg):
    model, lay, F, Fj = quad_ff
    d = copy.deepcopy(_gains_doc(model, F, Fj, lay))
    edit(d)
    with pytest.raises(ConfigError) as exc:
        fm.GainSchedule.from_dict(d)
    assert msg in str(exc.value)


def test_verify_recomputes_and_catches_a_tampered_F(quad_ff):
    model, lay, F, Fj = quad_ff
    rep = VerifyReport()
    check_feedforward(rep, model, F, lay.to_dict(), Fj)
    assert rep.passed and len(rep.rows) == 3 * 8
    bad = F.copy()
    bad[5, 1, 0] *= 1.01  # 1 % on theta of vertex 5
    rep = VerifyReport()
    check_feedforward(rep, model, bad, lay.to_dict(), Fj)
    failed = {(r.check, r.where.split()[1]) for r in rep.rows if not r.ok}
    assert failed == {("feedforward", "5"), ("ff residual", "5")}
    badj = Fj.copy()
    badj[2, 12, 1] += 0.01
    rep = VerifyReport()
    check_feedforward(rep, model, F, lay.to_dict(), badj)
    assert {(r.check, r.where.split()[1]) for r in rep.rows if not r.ok} == {("ff jerk", "2")}


# ------------------------------------------------------------------ linear model without x0'
# (lpv_closed_loop)
def test_feedforward_makes_a_ramp_an_exact_trajectory_of_the_linear_model():
    """Hover model at every vertex, x0(v_d) = v_d in the velocity entries: under the feedforward
    law
    and x' = A (x - x0) + B (u - u0) (no x0' term) the ramp v_d = c t is tracked exactly (z = 0);
    without the feedforward the same loop lags."""
    import scipy.linalg

    from lpv_sysid.models.lpv import ScheduledLpv
    from lpv_sysid.sim.closed_loop import (
        ClosedLoopConfig,
        FeedforwardSchedule,
        ReferenceSignals,
        feedforward_law,
        linear_lpv_law,
        simulate_eq33,
    )

    quad = qr.Quadrotor(qr.QuadrotorParams())
    tr = quad.trim(np.zeros(3))
    A, B = quad.linearize(tr)
    # LQR on the hover model (scaled motor states) as a stabilising gain
    Kq = -np.linalg.solve(
        np.eye(4) * 1e4,
        B.T
        @ scipy.linalg.solve_continuous_are(
            A, B, np.diag([1, 1, 1, 1, 1, 1, 1, 1, 1e-6, 1e-6, 1e-6, 1e-6]), np.eye(4) * 1e4
        ),
    )
    corners = np.array(list(itertools.product(*zip(LO, HI))))
    x0 = np.tile(tr.x0, (8, 1))
    x0[:, 2:5] = corners
    pm = PolytopicModel(
        vmin=LO,
        vmax=HI,
        A=np.tile(A, (8, 1, 1)),
        B=np.tile(B, (8, 1, 1)),
        x0=x0,
        u0=np.tile(tr.u0, (8, 1)),
    )
    sched = ScheduledLpv(pm, np.tile(Kq, (8, 1, 1)))
    F, Fj = ff.vertex_feedforward(pm.A, pm.B, qr.STATE_NAMES)
    c = np.array([0.5, -0.3, 0.2])
    t = np.arange(0.0, 4.0 + 1e-9, 0.02)
    sig = ReferenceSignals(t, np.outer(t, c), np.ones((t.size, 4)))
    ffs = FeedforwardSchedule(LO, HI, F, [0, 1, 8, 9, 10, 11], 12, Fj, [5, 6, 7])
    law = feedforward_law(sched, np.zeros((4, 4)), ffs, lambda tk: (c, np.zeros(3)))
    dx, _ = ffs.offsets(sig.v_d[0], c, np.zeros(3))
    cfg = ClosedLoopConfig(method="rk4")
    res = simulate_eq33(
        sched,
        sig,
        np.zeros((4, 4)),
        np.eye(3),
        law=law,
        moving_equilibrium=False,
        x_init=pm.x0_at(sig.v_d[0]) + dx,
        config=cfg,
    )
    assert np.max(np.abs(res.tracking_error)) < 1e-9
    lag = simulate_eq33(
        sched,
        sig,
        np.zeros((4, 4)),
        np.eye(3),
        law=linear_lpv_law(sched, np.zeros((4, 4))),
        moving_equilibrium=False,
        config=cfg,
    )
    assert np.max(np.abs(lag.tracking_error)) > 0.05
    # the seed's Eq. (33) (x0' moves the equilibrium) tracks the ramp without feedforward
    seed = simulate_eq33(
        sched,
        sig,
        np.zeros((4, 4)),
        np.eye(3),
        law=linear_lpv_law(sched, np.zeros((4, 4))),
        config=cfg,
    )
    assert np.max(np.abs(seed.tracking_error)) < 1e-9
