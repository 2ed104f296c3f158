"""Fast paths of the simulations, each against the computation it replaces: the compiled
hot path of models/quadrotor/model.py (derivatives, RK4 step), the sensor noise pool and
vibration cache of sim/vehicle.py, the bulk phase-1 bag (sim/phase1/bag.py) and the fused
Eq. (33) right-hand side (sim/closed_loop/eq33.py)."""

import math
import pickle
from dataclasses import replace

import numpy as np
import pytest

from lpv_sysid.control.baseline import BaselineGains
from lpv_sysid.io import bag as bg
from lpv_sysid.io import messages
from lpv_sysid.io.bag import records as records_mod
from lpv_sysid.io.bag.mcap import index as mcap_index
from lpv_sysid.models.quadrotor import Quadrotor, QuadrotorParams
from lpv_sysid.sim import closed_loop as cl
from lpv_sysid.sim import phase1
from lpv_sysid.sim.phase1 import bag as phase1_bag
from lpv_sysid.sim.vehicle import SensorConfig, SimVehicle


# --------------------------------------------------------------- reference equations
def reference_derivatives(q: Quadrotor, x, u):
    """Seed 0 Eqs. (3), (6)-(8) as written before the compiled hot path (plain Python,
    parameters looked up on every call)."""
    p = q.params
    K = p.K
    phi, th, psi = x[3], x[4], x[5]
    uu, vv, ww, pp, qq, rr = x[6:12]
    Om = list(x[12:16])
    Od = []
    for i in range(4):
        row = q.mix_inv[i].tolist()
        e = row[0] * u[0] + row[1] * u[1] + row[2] * u[2] + row[3] * u[3]
        e = 0.0 if e < 0.0 else (1.0 if e > 1.0 else e)
        d = -p.a_omega * Om[i] + p.b_omega * e
        if (Om[i] >= p.omega_max and d > 0.0) or (Om[i] <= p.omega_min and d < 0.0):
            d = 0.0
        Od.append(d)
    ell = p.arm_length
    s = ell * math.sqrt(2.0) / 2.0
    l2 = ell * ell
    O1, O2, O3, O4 = Om
    dt = 0.25 * (O1 + O2 + O3 + O4)
    da = s * (-O1 + O2 + O3 - O4)
    de = s * (O1 - O2 + O3 - O4)
    dr = O1 + O2 - O3 - O4
    S1, S2, S3, S4 = O1 * O1, O2 * O2, O3 * O3, O4 * O4
    dt2 = 0.25 * (S1 + S2 + S3 + S4)
    da2 = s * (-S1 + S2 + S3 - S4)
    de2 = s * (S1 - S2 + S3 - S4)
    dr2 = S1 + S2 - S3 - S4
    ddr = Od[0] + Od[1] - Od[2] - Od[3]
    u_, v, w, p_, q_ = uu, vv, ww, pp, qq
    Fx = u_ * (K["x_mu0"] + K["x_muw"] * w + K["x_muh"] * dt)
    Fy = v * (K["y_mu0"] + K["y_muw"] * w + K["y_muh"] * dt)
    Fz = (
        K["z_T0"] * dt2
        + K["z_mu0"] * dt
        + K["z_mu"] * (u_ * u_ + v * v)
        + K["z_muw"] * (4.0 * w * dt - p_ * da - q_ * de)
    )
    Mx = (
        K["l_T0"] * da2
        + K["l_mu0"] * da
        + K["l_muw"] * (w * da - 2.0 * l2 * p_ * dt - 0.5 * l2 * q_ * dr)
        + K["l_muh"] * v * dt
        + K["l_muh_mu0"] * v
        + K["l_muh_muw"] * v * w
        + K["l_dr"] * u_ * dr
    )
    My = (
        K["m_T0"] * de2
        + K["m_mu0"] * de
        + K["m_muw"] * (w * de - 2.0 * l2 * q_ * dt - 0.5 * l2 * p_ * dr)
        + K["m_muh"] * u_ * dt
        + K["m_muh_mu0"] * u_
        + K["m_muh_muw"] * u_ * w
        + K["m_dr"] * v * dr
    )
    Mz = (
        K["n_Q0"] * dr2
        + K["n_mu0"] * dr
        + K["n_muw"] * (w * dr + p_ * de + q_ * da)
        + K["n_muw2"] * p_ * q_
        + K["n_muh"] * (u_ * da + v * de)
        + K["n_muh_muw"] * (u_ * p_ + v * q_)
        + p.j_rotor * ddr
    )
    sf, cf, st, ct, sp, cp = (
        math.sin(phi),
        math.cos(phi),
        math.sin(th),
        math.cos(th),
        math.sin(psi),
        math.cos(psi),
    )
    xd = ct * cp * uu + (sf * st * cp - cf * sp) * vv + (cf * st * cp + sf * sp) * ww
    yd = ct * sp * uu + (sf * st * sp + cf * cp) * vv + (cf * st * sp - sf * cp) * ww
    zd = -st * uu + sf * ct * vv + cf * ct * ww
    tt = st / ct
    phid = pp + sf * tt * qq + cf * tt * rr
    thd = cf * qq - sf * rr
    psid = (sf * qq + cf * rr) / ct
    g, m = p.g, p.mass
    ud = vv * rr - ww * qq - g * st + Fx / m
    vd = ww * pp - uu * rr + g * sf * ct + Fy / m
    wd = uu * qq - vv * pp + g * cf * ct + Fz / m
    J, Ii = p.inertia, q.inertia_inv.tolist()
    h0 = J[0][0] * pp + J[0][1] * qq + J[0][2] * rr
    h1 = J[1][0] * pp + J[1][1] * qq + J[1][2] * rr
    h2 = J[2][0] * pp + J[2][1] * qq + J[2][2] * rr
    t0 = h1 * rr - h2 * qq + Mx
    t1 = h2 * pp - h0 * rr + My
    t2 = h0 * qq - h1 * pp + Mz
    pd = Ii[0][0] * t0 + Ii[0][1] * t1 + Ii[0][2] * t2
    qd = Ii[1][0] * t0 + Ii[1][1] * t1 + Ii[1][2] * t2
    rd = Ii[2][0] * t0 + Ii[2][1] * t1 + Ii[2][2] * t2
    return [xd, yd, zd, phid, thd, psid, ud, vd, wd, pd, qd, rd, *Od], (Fx, Fy, Fz)


def random_points(rng, n):
    for k in range(n):
        x = rng.normal(size=16) * np.r_[[10] * 3, [0.6] * 3, [5] * 3, [2] * 3, [0] * 4]
        x[12:16] = rng.uniform(100, 1150, 4)
        if k % 5 == 0:  # at the rotor-speed limits
            x[12:16] = rng.choice([120.0, 1100.0], 4)
        u = rng.normal(size=4) * np.r_[0.6, 0.05, 0.05, 0.3]
        if k % 4 == 0:  # saturated ESC commands
            u[0] = rng.choice([-0.5, 2.0])
        yield x.tolist(), u.tolist()


@pytest.mark.parametrize(
    "params",
    [
        QuadrotorParams(),
        QuadrotorParams(
            mass=2.1,
            j_rotor=4e-5,
            omega_min=90.0,
            inertia=((0.03, 0.001, 0.0), (0.001, 0.025, 0.0), (0.0, 0.0, 0.05)),
        ),
    ],
)
def test_compiled_hot_path_is_the_reference_equations_bit_for_bit(params):
    q = Quadrotor(params)
    rng = np.random.default_rng(4)
    h = 0.002
    for x, u in random_points(rng, 2000):
        ref, F = reference_derivatives(q, x, u)
        assert q.derivatives_list(x, u) == ref
        assert q.specific_force(np.array(x), u).tolist() == [f / params.mass for f in F]
        f = q.derivatives_list
        k1 = f(x, u)
        k2 = f([a + 0.5 * h * b for a, b in zip(x, k1)], u)
        k3 = f([a + 0.5 * h * b for a, b in zip(x, k2)], u)
        k4 = f([a + h * b for a, b in zip(x, k3)], u)
        rk4 = [
            a + h / 6.0 * (b + 2.0 * c + 2.0 * d + e) for a, b, c, d, e in zip(x, k1, k2, k3, k4)
        ]
        assert q.rk4_step(x, u, h) == rk4


def test_specialised_hot_path_drops_the_zero_terms_and_keeps_the_bits():
    """The hot path is compiled per model with the parameters folded in: the default model
    (diagonal inertia, four zero aerodynamic coefficients) runs >= 10 % fewer float
    operations than the source as written, with the same results bit for bit; a parameter
    set whose zeros are elsewhere gets its own code (the cache keys on the values)."""
    import dis

    from lpv_sysid.models.quadrotor import hot_path as quadrotor_hot_path

    def n_ops(fn):
        return sum(
            1
            for ins in dis.get_instructions(fn.__code__)
            if ins.opname.startswith("BINARY") or ins.opname == "UNARY_NEGATIVE"
        )

    rng = np.random.default_rng(11)
    for params in (
        QuadrotorParams(),
        QuadrotorParams(K={**QuadrotorParams().K, "z_mu0": -0.01, "x_mu0": 0.0}),
    ):
        q = Quadrotor(params)
        ns: dict = {}
        exec(compile(quadrotor_hot_path._HOT_PATH_SOURCE, "<as written>", "exec"), ns)
        generic = ns["_factory"](**q.hot_path_constants)
        assert n_ops(q.rk4_step) <= 0.9 * n_ops(generic[3])
        for x, u in random_points(rng, 300):
            assert q.rk4_step(x, u, 0.002) == generic[3](x, u, 0.002)
            assert q.derivatives_list(x, u) == generic[2](x, u)
    assert Quadrotor().rk4_step is not q.rk4_step


def test_quadrotor_pickles_with_its_hot_path():
    q = Quadrotor(QuadrotorParams(mass=1.9))
    q2 = pickle.loads(pickle.dumps(q))
    x = q.trim([1.0, 0.0, 0.0]).full_state.tolist()
    assert q2.params == q.params and q2.rk4_step(x, [0.5, 0, 0, 0], 0.01) == q.rk4_step(
        x, [0.5, 0, 0, 0], 0.01
    )


# ------------------------------------------------------------------------- sensors
def test_sensors_draw_the_same_noise_as_direct_generator_calls():
    """measure_state / measure_imu / measure_rotors with the block-drawn noise pool and the
    cached vibration: the values of the per-call formulas with per-call draws."""
    q = Quadrotor()
    cfg = SensorConfig(seed=7)
    tr = q.trim([2.0, -1.0, 0.5])
    veh = SimVehicle(q, cfg, tr.full_state)
    ref_rng = np.random.default_rng(7)
    ref_rng.uniform(0, 2 * np.pi, 4)  # the draws SimVehicle makes at start
    ref_rng.normal(size=(4, 3)), ref_rng.normal(size=(4, 3)), ref_rng.normal(size=(4, 3))
    ref_rng.uniform(0, 2 * np.pi, (4, 2))
    u = tr.u0.tolist()
    for k in range(3000):
        veh.step(u)
        acc, gyr = veh._vibration()
        x = np.array(veh.x)
        if k % 2 == 0:
            n = ref_rng.standard_normal(12)
            want = x.copy()
            want[0:3] += cfg.pos_std * n[0:3]
            want[3:6] += math.radians(cfg.att_std_deg) * n[3:6]
            want[6:9] += cfg.vel_std * n[6:9]
            want[9:12] += cfg.rate_std * n[9:12] + cfg.vib_state_fraction * np.array(gyr)
            assert np.array_equal(veh.measure_state(), want)
        if k % 5 == 0:
            want = x[12:16] + cfg.rotor_std * ref_rng.standard_normal(4)
            assert np.array_equal(veh.measure_rotors(), want)
        if k % 2 == 0:
            sf = q.specific_force(x, veh.u)
            n = ref_rng.standard_normal(6)
            a, w = veh.measure_imu()
            assert np.array_equal(a, sf + np.array(acc) + cfg.accel_std * n[0:3])
            assert np.array_equal(w, x[9:12] + np.array(gyr) + cfg.gyro_std * n[3:6])
    veh.x = list(veh.x)  # a new state object: vibration recomputed
    veh.rotor_phase[0] += 1.0
    assert veh._vibration() != (acc, gyr)


# ----------------------------------------------------------------- phase-1 bulk bag
@pytest.fixture(scope="module")
def short_run():
    cfg = replace(
        phase1.Phase1Config(),
        hover_validation=False,
        trim_s=1.0,
        excite_s=2.0,
        trim_average_s=0.5,
        taper_s=0.2,
        start="trim",
    )
    return phase1.run_phase1(Quadrotor(), BaselineGains(), SensorConfig(), cfg, [6])[0]


def test_bulk_phase1_bag_has_the_builders_messages(tmp_path, short_run):
    rec = short_run
    phase1.write_run_bag(rec, tmp_path / "bulk")
    f = messages.MsgFactory.rosbags()
    with bg.BagWriter(tmp_path / "ref") as w:
        for name in phase1.BAG_TOPICS:
            w.add_topic(f"/lpv_sysid/{name}", messages.TYPES[name])
        for stamp, name, msg in phase1_bag._message_items(rec, f):
            w.write(f"/lpv_sysid/{name}", stamp, msg)
    a, b = records_mod._Source(), records_mod._Source()
    mcap_index._read_fast(tmp_path / "bulk", None, a)
    mcap_index._read_fast(tmp_path / "ref", None, b)
    assert [(t, ns) for t, ns, _ in a.records] == [(t, ns) for t, ns, _ in b.records]
    assert len(a.records) == 3 * 250 + 3 * 100 + 3 * 250 * 3 + 3
    exact = 0
    for (t, _, x), (_, _, y) in zip(a.records, b.records):
        assert bg.records_close(a.types[t], x, y, rtol=1e-14, atol=1e-15), t
        exact += bytes(x) == bytes(y)
    # only the quaternions (vectorised trigonometry) may differ, in the last bits
    assert exact >= len(a.records) - 2 * 750


def test_bulk_phase1_bag_leaves_bad_samples_to_the_builders(tmp_path, short_run):
    rec = replace(short_run, state_meas=short_run.state_meas.copy())
    rec.state_meas[5, 7] = np.nan
    with pytest.raises(messages.MessageError, match="state.v_body"):
        phase1.write_run_bag(rec, tmp_path / "bad")


# ---------------------------------------------------------------------------- Eq. 33
def _model(seed=0, n=12, m=4):
    from lpv_sysid.models.lpv import PolytopicModel, ScheduledLpv

    rng = np.random.default_rng(seed)
    pm = PolytopicModel(
        vmin=[-2.0, -1.0, -3.0],
        vmax=[2.0, 1.5, 3.0],
        A=rng.normal(size=(8, n, n)) - 3 * np.eye(n),
        B=rng.normal(size=(8, n, m)),
        x0=rng.normal(size=(8, n)),
        u0=rng.normal(size=(8, m)),
    )
    return ScheduledLpv(pm, 0.1 * rng.normal(size=(8, m, n)))


def _signals(T=4.0, dt=0.05, far=False):
    t = np.arange(0.0, T + dt / 2, dt)
    amp = 3.0 if far else 1.0  # "far": v_d leaves the box (clamped weights)
    vd = np.column_stack(
        [amp * 1.5 * np.sin(1.3 * t), 0.8 * np.cos(0.7 * t), amp * 2 * np.sin(0.4 * t + 1)]
    )
    ue = np.column_stack([np.sin(f * t) for f in (1.1, 1.7, 2.3)])
    return cl.ReferenceSignals(t, vd, ue)


@pytest.mark.parametrize("far", [False, True])
@pytest.mark.parametrize("moving", [True, False])
def test_fused_eq33_rhs_equals_eq33_rhs(far, moving):
    sched = _model()
    sig = _signals(far=far)
    R = np.random.default_rng(1).normal(size=(4, 3))
    law = cl.linear_lpv_law(sched, R)
    f = cl.fused_eq33(sched, sig, None, R, 1.3, moving)
    assert f is not None
    rng = np.random.default_rng(2)
    for _ in range(200):
        t = float(rng.uniform(0, 4.0))
        seg = sig.segment(t)
        x = rng.normal(size=12)
        ref = cl.eq33_rhs(t, x, sched, sig, law, 1.3, seg, moving)
        np.testing.assert_allclose(f(t, x, seg), ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
        np.testing.assert_allclose(
            f.law(t, x, sig.at(t, seg)[0], 1.3 * sig.at(t, seg)[2]),
            law(t, x, sig.at(t, seg)[0], 1.3 * sig.at(t, seg)[2]),
            rtol=1e-12,
            atol=1e-13,
        )


def _feedforward(sched):
    rng = np.random.default_rng(3)
    pm = sched.model
    ffs = cl.FeedforwardSchedule(
        pm.vmin,
        pm.vmax,
        rng.normal(size=(8, 4 + 4, 3)),
        [0, 1, 8, 9],
        12,
        rng.normal(size=(8, 4 + 4 + 3, 3)),
        [5, 6, 7],
    )
    return ffs, (lambda t: (np.array([np.cos(t), 0.5, -t]), np.array([0.1, np.sin(t), 0.0])))


def test_fused_eq33_with_the_feedforward_law_and_simulation():
    sched = _model(5)
    sig = _signals()
    R = np.random.default_rng(6).normal(size=(4, 3))
    ffs, accel = _feedforward(sched)
    law = cl.feedforward_law(sched, R, ffs, accel)
    f = cl.fused_eq33(sched, sig, law, R, 1.0, moving_equilibrium=False)
    rng = np.random.default_rng(7)
    for _ in range(100):
        t = float(rng.uniform(0, 4.0))
        seg = sig.segment(t)
        x = rng.normal(size=12)
        ref = cl.eq33_rhs(t, x, sched, sig, law, 1.0, seg, False)
        np.testing.assert_allclose(f(t, x, seg), ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    # the whole simulation: fused (the law carries eq33_parts) vs the generic right-hand side
    # a law on another schedule of the same box (its own K, x0, u0), as phase2 builds them
    from lpv_sysid.models.lpv import ScheduledLpv

    other = ScheduledLpv(_model(8).model, sched.Kv * 0.5)
    other.model.vmin, other.model.vmax = sched.model.vmin, sched.model.vmax
    law2 = cl.feedforward_law(other, R, ffs, accel)
    f2 = cl.fused_eq33(sched, sig, law2, R, 1.0, moving_equilibrium=True)
    assert f2 is not None
    for _ in range(50):
        t = float(rng.uniform(0, 4.0))
        seg = sig.segment(t)
        x = rng.normal(size=12)
        ref = cl.eq33_rhs(t, x, sched, sig, law2, 1.0, seg, True)
        np.testing.assert_allclose(f2(t, x, seg), ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    plain = lambda t, x, v, e: law(t, x, v, e)  # noqa: E731 - a law simulate_eq33 cannot fuse
    assert cl.fused_eq33(sched, sig, plain, R, 1.0) is None
    Q = np.eye(3) * 2.0
    for lw, moving in ((None, True), (law, False)):
        cfg = cl.ClosedLoopConfig(method="rk4")
        a = cl.simulate_eq33(sched, sig, R, Q, 1.0, cfg, law=lw, moving_equilibrium=moving)
        ref_law = (
            (lambda t, x, v, e: cl.linear_lpv_law(sched, R)(t, x, v, e)) if lw is None else plain
        )
        b = cl.simulate_eq33(sched, sig, R, Q, 1.0, cfg, law=ref_law, moving_equilibrium=moving)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a.u, b.u, rtol=1e-9, atol=1e-9)
        assert a.gain == pytest.approx(b.gain, rel=1e-9) and a.n_steps == b.n_steps


# ------------------------------------------------------------------ CLI BLAS threads
@pytest.mark.parametrize(
    "argv, preset, want",
    [
        (["identify", "--bags", "x"], None, "1"),
        (["-v", "vrft", "--example", "lv100"], None, "1"),
        (["synthesize", "--models", "m"], None, "None"),
        (["identify"], "2", "2"),
        (["demo"], None, "1"),
    ],
)
def test_cli_sets_single_thread_blas_before_numpy(argv, preset, want):
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if preset is not None:
        env["OPENBLAS_NUM_THREADS"] = preset
    code = (
        "import os, sys; import lpv_sysid.cli.main as m; m._single_thread_blas(sys.argv[1:]); "
        "print(os.environ.get('OPENBLAS_NUM_THREADS'), 'numpy' in sys.modules)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, *argv],
        env=env,
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    ).stdout.split()
    assert out == [want, "False"]
