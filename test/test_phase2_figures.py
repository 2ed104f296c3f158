"""Honest phase-2 figures (issue 13, item 5): the u_e -> z gain that gamma bounds, reported apart
from the equilibrium offset and the reference tracking, in summary.yaml, the CLI line and the
report.

Oracles: the Eq. (33) closed loop run again with -u_e (exact superposition of a linear model),
the offset Q^-1 (v0 - v_d) computed by hand from the vertex equilibria, a known FIR response.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.linalg import solve_continuous_are
from scipy.signal import lfilter

from lpv_sysid.models.lpv import PolytopicModel, ScheduledLpv, box_vertices
from lpv_sysid.models.quadrotor import Quadrotor
from lpv_sysid.sim import phase2 as p2
from lpv_sysid.sim.closed_loop import (
    ClosedLoopConfig,
    ReferenceSignals,
    excitation_response_fir,
    l2_norm,
    simulate_eq33,
)

BOX = 2.0
Q = 5.0 * np.eye(3)
R = np.diag([0.02, 0.002, 0.002, 0.02])
OFFSET = np.array([0.3, -0.2, 0.4])  # the vertex equilibria fly v_d + OFFSET (seed 0 Table 1)


@pytest.fixture(scope="module")
def problem():
    """LQR-stabilised vertex linearisations over [-2, 2]^3 whose equilibria sit OFFSET away
    from the commanded velocity."""
    quad = Quadrotor()
    A, B, X0, U0, K = [], [], [], [], []
    Qw = np.diag([1, 1, 20, 20, 20, 0.1, 0.1, 0.1, 1e-6, 1e-4, 1e-4, 1e-6])
    Rw = np.diag([10.0, 100.0, 100.0, 10.0])
    for v in box_vertices([-BOX] * 3, [BOX] * 3):
        tr = quad.trim(v + OFFSET)
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
    sched = ScheduledLpv(pm, np.array(K))
    return p2.Phase2Problem(
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
    ), quad


def _signals(T=6.0, dt=0.02):
    t = np.arange(0.0, T + dt / 2, dt)
    v_d = np.column_stack(
        [1.2 * np.sin(2 * np.pi * 0.15 * t), 0.8 * np.cos(2 * np.pi * 0.1 * t), 0.3 + 0 * t]
    )
    ue = np.column_stack(
        [np.sin(2 * np.pi * f * t + ph) for f, ph in zip((1.1, 1.7, 2.3, 2.9), (0, 1, 2, 3))]
    )
    return ReferenceSignals(t, v_d, ue)


def test_offset_output_is_q_inverse_of_the_equilibrium_velocity_error(problem):
    pr, _ = problem
    sig = _signals()
    z_off = p2.offset_output(pr, sig.v_d)
    np.testing.assert_allclose(
        z_off, np.tile(np.linalg.solve(Q, OFFSET), (sig.t.size, 1)), atol=1e-9
    )


def test_eq33_gain_is_the_excitation_part_by_exact_superposition(problem):
    """Eq. (33): z(+u_e) - z(-u_e) = 2 z_e; the unexcited run stays on x0(v_d), so z_e is also
    z - z_offset; the total ratio mixes in the offset and is several times larger."""
    pr, _ = problem
    sig = _signals()
    cfg = ClosedLoopConfig(kappa=1.0)
    plus = simulate_eq33(pr.scheduled(), sig, R, Q, 1.0, cfg)
    minus = simulate_eq33(
        pr.scheduled(), ReferenceSignals(sig.t, sig.v_d, -sig.u_e), R, Q, 1.0, cfg
    )
    z_e = 0.5 * (plus.z - minus.z)
    want = l2_norm(sig.t, z_e) / l2_norm(sig.t, plus.ue)
    d = p2.decompose_eq33(pr, sig, plus, p2.Phase2Config())
    assert d["excitation"]["gain"] == pytest.approx(want, rel=1e-6)
    assert d["tracking"]["ratio"] < 1e-6 * want  # no tracking part in Eq. (33)
    off = l2_norm(sig.t, np.tile(np.linalg.solve(Q, OFFSET), (sig.t.size, 1))) / l2_norm(
        sig.t, plus.ue
    )
    assert d["offset"]["ratio"] == pytest.approx(off, rel=1e-9)
    assert d["total"]["ratio"] == pytest.approx(plus.gain, rel=1e-12)
    assert plus.gain > 3 * d["excitation"]["gain"]  # what used to be reported as "the gain"
    # the mirrored-run branch (taken when a law is given, e.g. the feedforward path) agrees
    from lpv_sysid.sim.closed_loop import linear_lpv_law

    d2 = p2.decompose_eq33(pr, sig, plus, p2.Phase2Config(), law=linear_lpv_law(pr.scheduled(), R))
    assert d2["method"].endswith("the same run with -u_e)")
    assert d2["excitation"]["gain"] == pytest.approx(
        want, rel=1e-5
    )  # the law path vs the fused one


def test_fir_regression_recovers_a_known_excitation_response():
    """z = FIR(u_e) + slow tracking error + noise: the regression above the reference band
    finds the FIR part's norm (the nonlinear flight has no unexcited twin)."""
    rng = np.random.default_rng(1)
    dt = 0.01
    t = np.arange(0.0, 60.0, dt)
    ue = np.column_stack(
        [
            np.sin(2 * np.pi * f * t + ph)
            for f, ph in zip((0.9, 1.6, 2.4, 3.3), rng.uniform(0, 6, 4))
        ]
    )
    h = [0.02 * np.exp(-np.arange(40) / 8.0), -0.01 * np.exp(-np.arange(40) / 5.0)]
    z_e = np.column_stack(
        [
            lfilter(h[0], 1, ue[:, 0]) + lfilter(h[1], 1, ue[:, 2]),
            lfilter(h[1], 1, ue[:, 1]),
            lfilter(h[0], 1, ue[:, 3]),
        ]
    )
    track = np.column_stack(
        [0.05 * np.sin(2 * np.pi * 0.05 * t), 0.04 * np.cos(2 * np.pi * 0.08 * t), 0 * t]
    )
    z = z_e + track + 1e-4 * rng.normal(size=z_e.shape)
    est, info = excitation_response_fir(t, z, ue)
    assert l2_norm(t, est) / l2_norm(t, ue) == pytest.approx(
        l2_norm(t, z_e) / l2_norm(t, ue), rel=0.03
    )
    assert info["fit_r2"] > 0.95
    d = p2.gain_decomposition(t, z, ue, np.zeros_like(z), est, "FIR")
    assert d["tracking"]["ratio"] == pytest.approx(l2_norm(t, track) / l2_norm(t, ue), rel=0.1)


def test_summary_cli_and_report_put_the_excitation_gain_first(problem, tmp_path):
    """summary.yaml (@2): excitation_gain (what gamma bounds, within_gamma refers to it),
    total_ratio and the decomposition; the CLI line starts with the gain; the report's table
    has the gain, the offset and the tracking in separate columns."""
    from lpv_sysid.cli.design import format_gain_line
    from lpv_sysid.report import gain_row

    pr, quad = problem
    sig = _signals()
    res = p2.run(
        pr, sig, p2.Phase2Config(run_nonlinear=False), quad.params, None, tmp_path / "phase2"
    )
    s = yaml.safe_load(res.summary_path.read_text())
    assert s["format"] == "lpv_sysid/phase2_summary@2"
    e = s["eq33"]
    rec = res.records["eq33"]
    assert e["excitation_gain"] == pytest.approx(rec.decomposition["excitation"]["gain"])
    assert e["total_ratio"] == pytest.approx(rec.gain) and "gain" not in e
    assert e["within_gamma"] is True and e["excitation_gain"] < 0.5 * e["total_ratio"]
    assert set(e["decomposition"]) >= {"method", "excitation", "offset", "tracking", "total"}
    line = format_gain_line(rec, 1.0)
    assert line.startswith(f"u_e -> z gain {rec.excitation_gain:.3g} (<= gamma 1)")
    assert f"total ||z||/||kappa u_e|| {rec.gain:.3g}" in line and "equilibrium offset" in line
    row = gain_row("Eq. (33)", e, 1.0)
    assert row[1] == pytest.approx(e["excitation_gain"]) and row[2] is True
    assert row[4] == pytest.approx(e["decomposition"]["offset"]["ratio"]) and row[
        6
    ] == pytest.approx(rec.gain)
    # an older summary (@1, only the mixed ratio) is shown as total with the gain unknown
    old = gain_row("old", {"gain": 0.29, "completed": True}, 1.0)
    assert (
        old[1] is None and old[2] is None and old[6] == 0.29 and old[3].startswith("not separated")
    )
