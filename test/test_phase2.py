"""Phase-2 simulation: nonlinear quadrotor under an LPV law vs the Eq. (33) LPV closed loop,
safety supervisor, signal handling."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import solve_continuous_are

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.files import sha256_file
from lpv_sysid.models.lpv import PolytopicModel, ScheduledLpv, box_vertices
from lpv_sysid.models.quadrotor import Quadrotor
from lpv_sysid.sim.closed_loop import (
    ClosedLoopConfig,
    ReferenceSignals,
    linear_lpv_law,
    simulate_eq33,
)
from lpv_sysid.sim.phase2 import (
    EXCITATION_CHANNELS,
    REFERENCE_CHANNELS,
    load_signals,
    reference_signals,
    regressor_correlation_block,
    simulate_nonlinear,
)
from lpv_sysid.sim.vehicle import SensorConfig, SimVehicle

BOX = 2.0
Q = 5.0 * np.eye(3)
R = np.diag([0.02, 0.002, 0.002, 0.02])
QUIET = SensorConfig(
    pos_std=0,
    att_std_deg=0,
    vel_std=0,
    rate_std=0,
    rotor_std=0,
    vib_accel=0,
    vib_accel_blade=0,
    vib_gyro=0,
)


@pytest.fixture(scope="module")
def lpv():
    """Vertex trims + analytic linearisations of the quadrotor, LQR gain per vertex: a simple
    stabilising LPV law (not the Lemma 1 synthesis) over the box [-2, 2]^3 m/s."""
    quad = Quadrotor()
    A, B, X0, U0, K = [], [], [], [], []
    Qw = np.diag([1, 1, 20, 20, 20, 0.1, 0.1, 0.1, 1e-6, 1e-4, 1e-4, 1e-6])
    Rw = np.diag([10.0, 100.0, 100.0, 10.0])
    for v in box_vertices([-BOX] * 3, [BOX] * 3):
        tr = quad.trim(v)
        a, b = quad.linearize(tr)
        P = solve_continuous_are(a, b, Qw, Rw)
        A.append(a)
        B.append(b)
        X0.append(tr.x0)
        U0.append(tr.u0)
        K.append(-np.linalg.solve(Rw, b.T @ P))
    pm = PolytopicModel(
        vmin=[-BOX] * 3,
        vmax=[BOX] * 3,
        A=np.array(A),
        B=np.array(B),
        x0=np.array(X0),
        u0=np.array(U0),
    )
    return quad, ScheduledLpv(pm, np.array(K))


def _signals(T, vd_fn, seed=0, dt=0.01):
    t = np.arange(0.0, T + dt / 2, dt)
    rng = np.random.default_rng(seed)
    ue = np.column_stack(
        [np.sin(2 * np.pi * f * t + p) for f, p in zip([1.1, 1.7, 2.3, 2.9], rng.uniform(0, 6, 4))]
    )
    return ReferenceSignals(t, vd_fn(t), ue)


class Sink:
    def __init__(self):
        self.samples, self.statuses = [], []

    def sample(self, t, x16, imu, Om, v_d, ue, u):
        self.samples.append((t, ue.copy()))

    def status(self, t, level, message, values):
        self.statuses.append((t, level, message, dict(values)))


def test_constant_reference_nonlinear_agrees_with_eq33(lpv):
    """Constant v_d, noise-free sensors: the nonlinear quadrotor and the Eq. (33) closed loop of
    its own linearisation respond alike to the same excitation (only ZOH at 100 Hz and
    second-order terms differ)."""
    quad, sched = lpv
    sig = _signals(3.0, lambda t: np.tile([1.0, -0.5, 0.3], (t.size, 1)))
    eq33 = simulate_eq33(sched, sig, R, Q, gamma=1.0, config=ClosedLoopConfig(method="rk4"))
    veh = SimVehicle(quad, QUIET, x0=quad.trim(sig.v_d[0]).full_state)
    nl = simulate_nonlinear(
        veh, linear_lpv_law(sched, R), sig, Q, [-BOX] * 3, [BOX] * 3, gamma=1.0
    )
    assert nl.completed and nl.safety_event is None and nl.t.size == sig.t.size
    excursion = np.max(np.abs(eq33.tracking_error))
    assert excursion > 5e-3  # the excitation does move the vehicle
    assert np.max(np.abs(nl.v - eq33.x[:, 2:5])) < 0.25 * excursion
    assert nl.gain == pytest.approx(eq33.gain, rel=0.1)
    assert nl.gain < 1.0 and eq33.gain < 1.0


def test_noisy_nonlinear_run_stays_bounded_and_tracks(lpv):
    quad, sched = lpv
    sig = _signals(
        4.0,
        lambda t: np.column_stack(
            [
                1.5 * np.sin(2 * np.pi * 0.2 * t),
                np.sin(2 * np.pi * 0.15 * t),
                0.5 * np.sin(2 * np.pi * 0.1 * t),
            ]
        ),
    )
    veh = SimVehicle(quad, SensorConfig(seed=3), x0=quad.trim(sig.v_d[0]).full_state)
    sink = Sink()
    nl = simulate_nonlinear(
        veh, linear_lpv_law(sched, R), sig, Q, [-BOX] * 3, [BOX] * 3, kappa=2.0, sink=sink
    )
    assert nl.completed and np.all(np.isfinite(nl.controller_state))
    assert np.max(np.abs(nl.v - nl.v_d)) < 1.0
    assert np.max(np.abs(nl.controller_state[:, :2])) < math.radians(30)
    np.testing.assert_allclose(nl.ue, 2.0 * np.array([sig.at(t)[2] for t in nl.t]))
    assert len(sink.samples) == nl.t.size and sink.statuses[-1][1] == "OK"
    block = regressor_correlation_block(
        nl.t, nl.controller_state, quad.params.arm_length, "nonlinear", nl.extra["Omega"]
    )
    assert set(block["axes"]) == set("XYZLMN")
    C = np.array(block["axes"]["Z"]["corr"], dtype=float)
    assert C.shape == (4, 4) and np.allclose(np.diag(C), 1.0)


def test_supervisor_stops_run_with_excitation_off(lpv):
    """A huge excitation multiplier throws the vehicle out of the box: the run stops, the
    event names the cause, the last status says excitation off, nothing after the trip."""
    quad, sched = lpv
    sig = _signals(6.0, lambda t: np.zeros((t.size, 3)))
    veh = SimVehicle(quad, QUIET, x0=quad.trim(np.zeros(3)).full_state)
    sink = Sink()
    nl = simulate_nonlinear(
        veh,
        linear_lpv_law(sched, R),
        sig,
        Q,
        [-BOX] * 3,
        [BOX] * 3,
        kappa=400.0,
        box_margin=0.5,
        sink=sink,
    )
    assert not nl.completed
    assert nl.safety_event.split()[0] in ("out_of_box", "bound_exceeded", "non_finite")
    assert nl.t[-1] < sig.t[-1]
    level, msg, values = sink.statuses[-1][1:]
    assert level == "ERROR" and values["excitation"] == "off" and "excitation off" in msg
    if nl.safety_event.startswith("out_of_box"):
        assert "measured body velocity" in nl.safety_event


def test_non_finite_command_is_a_safety_event(lpv):
    quad, sched = lpv
    sig = _signals(1.0, lambda t: np.zeros((t.size, 3)))
    veh = SimVehicle(quad, QUIET, x0=quad.trim(np.zeros(3)).full_state)
    base = linear_lpv_law(sched, R)

    def law(t, x, vd, ue):
        return base(t, x, vd, ue) * (np.nan if t >= 0.5 else 1.0)

    nl = simulate_nonlinear(veh, law, sig, Q, [-BOX] * 3, [BOX] * 3)
    assert not nl.completed and nl.safety_event.startswith("non_finite at t=0.500")
    assert nl.t[-1] == pytest.approx(0.49)


def test_signal_channels_by_name(tmp_path):
    names = ["ue_r", "w_d", "u_d", "ue_t", "v_d", "ue_e", "ue_a"]
    t = np.arange(0, 1, 0.1)
    u = np.outer(t, np.arange(1, 8))
    sig = reference_signals(t, u, names)
    np.testing.assert_allclose(sig.v_d, u[:, [2, 4, 1]])
    np.testing.assert_allclose(sig.u_e, u[:, [3, 6, 5, 0]])
    assert len(REFERENCE_CHANNELS + EXCITATION_CHANNELS) == 7
    with pytest.raises(ConfigError, match="ue_a"):
        reference_signals(t, u[:, :6], names[:6])
    np.savez(tmp_path / "signals.npz", t=t, u=u, names=np.array(names))
    assert load_signals(tmp_path, duration=0.5).t[-1] == pytest.approx(0.5)
    np.savez(tmp_path / "bad.npz", t=t, u=u)
    with pytest.raises(ConfigError, match="names"):
        load_signals(tmp_path / "bad.npz")
    with pytest.raises(ConfigError, match="not found"):
        load_signals(tmp_path / "nowhere")


def test_full_run_writes_bag_summary_and_report(lpv, tmp_path):
    """run(): Eq. (33) + nonlinear + rosbag2 + summary.yaml; the bag reads back through
    io/bag + io/messages with the values that were flown, and the report picks it all up."""
    import yaml

    from lpv_sysid.io import messages
    from lpv_sysid.io.bag import read_bag
    from lpv_sysid.report import write_report
    from lpv_sysid.sim.phase2 import Phase2Config, Phase2Problem, run

    quad, sched = lpv
    pm = sched.model
    problem = Phase2Problem(
        vmin=pm.vmin,
        vmax=pm.vmax,
        K=sched.Kv,
        x0=pm.x0,
        u0=pm.u0,
        R=R,
        Q=Q,
        gamma=1.0,
        A=pm.A,
        B=pm.B,
    )
    t = np.arange(0.0, 1.5 + 1e-9, 0.02)
    sig = ReferenceSignals(
        t,
        np.column_stack([0.5 * np.sin(t), 0 * t, 0.2 * t]),
        np.column_stack([np.sin(2 * np.pi * f * t) for f in (1.0, 1.5, 2.0, 2.5)]),
    )
    res = run(
        problem,
        sig,
        Phase2Config(kappa=2.0, superposition=True),
        quad.params,
        SensorConfig(seed=1),
        tmp_path / "phase2",
    )
    nl, eq = res.records["nonlinear"], res.records["eq33"]
    assert nl.completed and eq.completed
    summary = yaml.safe_load(res.summary_path.read_text())
    assert summary["kappa"] == 2.0 and summary["gamma"] == 1.0
    assert summary["nonlinear"]["total_ratio"] == pytest.approx(nl.gain)
    assert summary["eq33"]["total_ratio"] == pytest.approx(eq.gain)
    # with --superposition the nonlinear u_e -> z gain is the two-flight difference
    assert summary["nonlinear"]["excitation_gain"] == pytest.approx(
        summary["nonlinear"]["superposition"]["gain"]
    )
    assert set(summary["regressor_correlation"]["axes"]) == set("XYZLMN")
    assert summary["regressor_correlation"]["source"] == "nonlinear"
    assert summary["regressor_correlation"]["complete_run"] is True
    # the limits the run was supervised against are recorded (the report's margins use them)
    assert summary["limits"] == {
        "max_tilt_deg": 60.0,
        "box_margin": 1.0,
        "monitor_margin": 1.2,
        "monitor_min_energy": 0.05,
        "arm_length": quad.params.arm_length,
    }

    bag = read_bag(tmp_path / "phase2" / "bag")
    names = {k.rsplit("/", 1)[-1]: v for k, v in bag.items()}
    assert set(names) == {
        "state",
        "rotor_speeds",
        "imu",
        "velocity_reference",
        "excitation",
        "actuator_command",
        "status",
    }
    assert len(names["excitation"]) == nl.t.size == 151  # 1.5 s at 100 Hz
    _, ue = messages.excitation_from_joint_state(names["excitation"][40][1])
    np.testing.assert_allclose(ue, nl.ue[40] / 2.0, rtol=1e-12)  # normalised u_e on the wire
    _, u = messages.actuator_command_from_joint_state(names["actuator_command"][40][1])
    np.testing.assert_allclose(u, nl.u[40], rtol=1e-12)
    _, vd, _ = messages.reference_from_twist(names["velocity_reference"][100][1])
    np.testing.assert_allclose(vd, nl.v_d[100], atol=1e-12)  # FRD after the FLU round trip
    st = messages.state_from_odometry(names["state"][100][1])
    assert np.max(np.abs(st.v_body - nl.v[100])) < 0.2  # measured vs true (noise)
    _, statuses = messages.status_from_diagnostic_array(names["status"][-1][1])
    assert statuses[0].message == "phase 2 excitation complete"

    report = write_report(tmp_path).read_text()
    d = summary["nonlinear"]["decomposition"]
    assert (
        f"| nonlinear quadrotor | {nl.excitation_gain:.4g} | yes | superposition | "
        f"{d['offset']['ratio']:.4g} | "
        f"{d['tracking']['ratio']:.4g} | {nl.gain:.4g} | completed |"
    ) in report
    assert "Computed from the nonlinear quadrotor simulation data, 151 samples." in report
    assert "not recorded in the summary" not in report
    sp = summary["nonlinear"]["superposition"]
    assert sp["complete"] and 0 < sp["gain"] < 1.0


def _write_files(lpv, d):
    """vertex_models.yaml + gains.yaml (through io.formats) and a 7-channel signals.npz."""
    from lpv_sysid.io import formats as F
    from lpv_sysid.models import quadrotor as qr

    quad, sched = lpv
    pm = sched.model
    chans = lambda names, units: [{"name": n, "unit": u} for n, u in zip(names, units)]  # noqa: E731
    head = {
        "states": chans(qr.STATE_NAMES, qr.STATE_UNITS),
        "inputs": chans(qr.INPUT_NAMES, qr.INPUT_UNITS),
        "scheduling": {"names": list(qr.SCHEDULING_NAMES), "min": [-BOX] * 3, "max": [BOX] * 3},
    }
    corners = box_vertices([-BOX] * 3, [BOX] * 3)
    models = dict(
        format=F.MODELS_FORMAT,
        time="continuous",
        **head,
        vertices=[
            {
                "scheduling": c.tolist(),
                "x0": pm.x0[i].tolist(),
                "u0": pm.u0[i].tolist(),
                "A": pm.A[i].tolist(),
                "B": pm.B[i].tolist(),
            }
            for i, c in enumerate(corners)
        ],
    )
    F.VertexModels.from_dict(models).save(d / "vertex_models.yaml")
    gains = dict(
        format=F.GAINS_FORMAT,
        **head,
        vertices=[
            {
                "scheduling": c.tolist(),
                "K": sched.Kv[i].tolist(),
                "x0": pm.x0[i].tolist(),
                "u0": pm.u0[i].tolist(),
            }
            for i, c in enumerate(corners)
        ],
        R=R.tolist(),
        Q=Q.tolist(),
        gamma=1.0,
        certificate={
            "lmi": "none: LQR test gains",
            "solver": "scipy CARE",
            "gamma_achieved": 1.0,
            "min_margin": 0.0,
            "models_sha256": sha256_file(d / "vertex_models.yaml"),
        },
    )
    F.GainSchedule.from_dict(F.certify_law(gains)).save(d / "gains.yaml")
    (d / "signals").mkdir()
    t = np.arange(0.0, 3.0, 0.02)
    names = ["u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r"]
    u = np.column_stack(
        [np.sin(2 * np.pi * 0.3 * t), 0.5 * np.cos(2 * np.pi * 0.2 * t), 0 * t]
        + [np.sin(2 * np.pi * f * t) for f in (1.0, 1.5, 2.0, 2.5)]
    )
    np.savez(d / "signals" / "signals.npz", t=t, u=u, names=np.array(names))


def _parse(argv):
    import argparse

    from lpv_sysid.cli.design.simulate import _add_phase2_arguments as add_phase2_arguments

    p = argparse.ArgumentParser()
    add_phase2_arguments(p)
    return p.parse_args(argv)


def test_cli_entry_point_runs_from_files(lpv, tmp_path, capsys):
    import yaml

    from lpv_sysid.cli.design import run_phase2

    _write_files(lpv, tmp_path)
    args = _parse(
        [
            "--gains",
            str(tmp_path / "gains.yaml"),
            "--signals",
            str(tmp_path / "signals"),
            "--out",
            str(tmp_path / "phase2"),
            "--kappa",
            "1.5",
            "--ramp",
            "0.5",
            "--no-bag",
        ]
    )
    assert run_phase2(args) == 0
    out = capsys.readouterr().out
    assert (
        "eq33     : u_e -> z gain " in out
        and "total ||z||/||kappa u_e|| " in out
        and "wrote " in out
    )
    s = yaml.safe_load((tmp_path / "phase2" / "summary.yaml").read_text())
    assert s["kappa"] == 1.5 and s["eq33"]["completed"] and s["nonlinear"]["completed"]
    assert s["signals"]["duration"] == pytest.approx(
        0.5 + 3.0 + 0.5
    )  # ramp + one period + ramp (ExcitationCore)
    # the models file found next to the gains: a changed models file is refused (sha256)
    text = (tmp_path / "vertex_models.yaml").read_text()
    (tmp_path / "vertex_models.yaml").write_text(
        text.replace("continuous", "continuous  # edited")
    )
    args = _parse(
        [
            "--gains",
            str(tmp_path / "gains.yaml"),
            "--signals",
            str(tmp_path / "signals"),
            "--out",
            str(tmp_path / "p2b"),
            "--no-bag",
        ]
    )
    with pytest.raises(ConfigError, match="models_sha256"):
        run_phase2(args)
    with pytest.raises(ConfigError, match="gains file .*nope.yaml not found"):
        run_phase2(
            _parse(["--gains", str(tmp_path / "nope.yaml"), "--signals", "x", "--out", "y"])
        )
    with pytest.raises(ConfigError, match="kappa"):
        run_phase2(
            _parse(
                [
                    "--gains",
                    str(tmp_path / "gains.yaml"),
                    "--signals",
                    "x",
                    "--out",
                    "y",
                    "--kappa",
                    "-1",
                ]
            )
        )


def test_runtime_law_bound_monitor_stops_the_run(lpv):
    """The onboard law (control.lpv_controller) with a gamma far below what the loop achieves:
    its bound monitor flags, the supervisor latches bound_exceeded and the run stops."""
    from lpv_sysid.sim.phase2 import Phase2Problem, RuntimeLaw

    quad, sched = lpv
    pm = sched.model
    ok = Phase2Problem(
        vmin=pm.vmin, vmax=pm.vmax, K=sched.Kv, x0=pm.x0, u0=pm.u0, R=R, Q=Q, gamma=1.0
    )
    sig = _signals(3.0, lambda t: np.tile([0.5, 0.0, 0.0], (t.size, 1)))
    law = RuntimeLaw(ok, quad.mix)
    nl = simulate_nonlinear(
        SimVehicle(quad, QUIET, x0=quad.trim(sig.v_d[0]).full_state),
        law,
        sig,
        Q,
        pm.vmin,
        pm.vmax,
        gamma=1.0,
    )
    assert nl.completed and law.steps == nl.t.size
    # same law as linear_lpv_law where nothing saturates
    ref = linear_lpv_law(sched, R)
    x = nl.x_meas = nl.extra["x_meas"][50]
    np.testing.assert_allclose(
        RuntimeLaw(ok, quad.mix)(0.0, x, sig.v_d[50], sig.u_e[50]),
        ref(0.0, x, sig.v_d[50], sig.u_e[50]),
        rtol=1e-12,
        atol=1e-12,
    )
    tight = Phase2Problem(
        vmin=pm.vmin, vmax=pm.vmax, K=sched.Kv, x0=pm.x0, u0=pm.u0, R=R, Q=Q, gamma=1e-4
    )
    nl = simulate_nonlinear(
        SimVehicle(quad, QUIET, x0=quad.trim(sig.v_d[0]).full_state),
        RuntimeLaw(tight, quad.mix),
        sig,
        Q,
        pm.vmin,
        pm.vmax,
        gamma=1e-4,
    )
    assert not nl.completed and nl.safety_event.startswith("bound_exceeded")
    assert "bound monitor" in nl.safety_event


def test_bag_failure_keeps_results_and_names_the_problem(lpv, tmp_path, monkeypatch):
    """A recording failure mid-flight (e.g. full disk) raises BagError naming it; the Eq. (33)
    results and a summary saying what failed are still written."""
    import yaml

    from lpv_sysid.errors import BagError
    from lpv_sysid.sim import phase2

    quad, sched = lpv
    pm = sched.model
    problem = phase2.Phase2Problem(
        vmin=pm.vmin,
        vmax=pm.vmax,
        K=sched.Kv,
        x0=pm.x0,
        u0=pm.u0,
        R=R,
        Q=Q,
        gamma=1.0,
        A=pm.A,
        B=pm.B,
    )
    sig = _signals(1.0, lambda t: np.zeros((t.size, 3)))
    from lpv_sysid.io.bag import BagWriter

    real_write_many = BagWriter.write_many

    def failing_write_many(self, rows):
        rows = list(rows)
        ok = [r for r in rows if r[1] <= 0.5e9]
        real_write_many(self, ok)  # the disk fills up after 0.5 s of flight
        if len(ok) < len(rows):
            raise BagError(f"bag {self.path}: write failed: [Errno 28] No space left on device")
        return len(rows)

    monkeypatch.setattr(BagWriter, "write_many", failing_write_many)
    with pytest.raises(BagError, match="No space left"):
        phase2.run(problem, sig, phase2.Phase2Config(), quad.params, QUIET, tmp_path / "p2")
    s = yaml.safe_load((tmp_path / "p2" / "summary.yaml").read_text())
    assert s["eq33"]["completed"] and "No space left" in s["nonlinear"]["skipped"]
    assert (tmp_path / "p2" / "eq33.npz").is_file()
    from lpv_sysid.io.bag import read_bag

    got = read_bag(tmp_path / "p2" / "bag")  # what was recorded is readable
    assert len(got["/lpv_sysid/state"]) == 51  # 0 .. 0.5 s at 100 Hz


def test_superposition_isolates_the_excitation_response(lpv):
    """Constant v_d at a true trim, noise-free: the reference-only flight stays at the trim, so
    z_e equals the excited flight's z and its gain equals the direct gain; with a moving v_d the
    reference-only flight carries the tracking lag and z_e removes it (gain_e << direct gain)."""
    from lpv_sysid.sim.phase2 import RuntimeLaw, excitation_gain_by_superposition

    quad, sched = lpv
    pm = sched.model
    from lpv_sysid.sim.phase2 import Phase2Problem

    prob = Phase2Problem(
        vmin=pm.vmin, vmax=pm.vmax, K=sched.Kv, x0=pm.x0, u0=pm.u0, R=R, Q=Q, gamma=1.0
    )
    from lpv_sysid.control.law import LpvControllerConfig

    # the largest declared margin: the direct flight's monitor stays quiet on these short runs
    law = lambda: RuntimeLaw(prob, quad.mix, LpvControllerConfig(monitor_margin=10.0))  # noqa: E731
    corner = np.array([BOX, -BOX, BOX])  # vertex: x0/u0 are the exact trim
    sig = _signals(2.0, lambda t: np.tile(corner, (t.size, 1)))
    veh = lambda: SimVehicle(quad, QUIET, x0=quad.trim(corner).full_state)  # noqa: E731
    sp = excitation_gain_by_superposition(veh, law, sig, Q, pm.vmin, pm.vmax, kappa=1.0)
    direct = simulate_nonlinear(veh(), law(), sig, Q, pm.vmin, pm.vmax)
    assert sp["complete"] and sp["reference_only_z_norm"] < 1e-6 * direct.z_norm
    assert sp["gain"] == pytest.approx(direct.gain, rel=1e-4)
    moving = _signals(
        3.0, lambda t: np.column_stack([1.5 * np.sin(2 * np.pi * 0.3 * t), 0 * t, 0 * t])
    )
    veh0 = lambda: SimVehicle(quad, SensorConfig(seed=2), x0=quad.trim(np.zeros(3)).full_state)  # noqa: E731
    sp = excitation_gain_by_superposition(veh0, law, moving, Q, pm.vmin, pm.vmax, kappa=1.0)
    direct = simulate_nonlinear(veh0(), law(), moving, Q, pm.vmin, pm.vmax)
    assert sp["gain"] < 0.5 * direct.gain and sp["reference_only_z_norm"] > sp["z_norm"]
