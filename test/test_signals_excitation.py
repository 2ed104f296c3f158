"""Excitation core: O(1) table lookup against the analytic multisine, fades, abort,
progress, time ordering, phase-1 reference."""

import math

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError, LpvSysidError, SafetyError
from lpv_sysid.signals.excitation import (
    ABORTED,
    DONE,
    IDLE,
    RAMP_IN,
    RAMP_OUT,
    RUNNING,
    ExcitationCore,
    TimeOrderError,
    phase1_reference,
)
from lpv_sysid.signals.multisine import SignalsConfig, design
from lpv_sysid.signals.prbs import prbs

FAST = {"max_iter": 20, "clip_iter": 10, "restarts": 0, "p_stages": [4, 64]}


@pytest.fixture(scope="module")
def sig2():
    return design(
        SignalsConfig.from_dict(
            {
                "duration": 20.0,
                "sample_rate": 20.0,
                "optimisation": FAST,
                "groups": [
                    {
                        "name": "reference",
                        "channels": ["u_d", "v_d", "w_d"],
                        "band": [0.05, 0.5],
                        "peak": 5.0,
                    },
                    {
                        "name": "excitation",
                        "channels": ["ue_t", "ue_a", "ue_e", "ue_r"],
                        "band": [0.5, 4.0],
                        "energy": 1.0,
                    },
                ],
            }
        )
    )


@pytest.fixture(scope="module")
def sig1():
    return design(
        SignalsConfig.from_dict(
            {
                "duration": 30.0,
                "sample_rate": 50.0,
                "optimisation": FAST,
                "groups": [
                    {
                        "name": "reference",
                        "channels": ["u_ref", "v_ref", "w_ref", "r_ref"],
                        "band": [0.2, 2.0],
                        "peak": [1.0, 1.0, 0.5, 0.5],
                    }
                ],
            }
        )
    )


def _bound(sig, cols):
    # linear interpolation error <= dt^2/8 * max|x''| <= dt^2/8 * sum a_k w_k^2
    dt = 1 / sig.sample_rate
    w0 = 2 * np.pi / sig.duration
    return np.array(
        [dt**2 / 8 * np.sum(sig.amplitudes[j] * (w0 * sig.harmonics[j]) ** 2) for j in cols]
    )


def test_lookup_matches_analytic_multisine(sig2):
    core = ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=3.0, ramp=0.0)
    ts = 3.0 + np.sort(np.random.default_rng(1).uniform(0, 20.0, 400))
    exact = sig2.evaluate(ts - 3.0)
    got = np.array([np.concatenate([s.velocity, s.u_e]) for s in map(core.sample, ts)])
    err = np.max(np.abs(got - exact), axis=0)
    assert np.all(err <= _bound(sig2, range(7)))
    assert np.all(err > 0)  # the bound is not vacuous: points are off-grid
    # on the grid the lookup returns the table itself
    core = ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=0.0, ramp=0.0)
    for k in (0, 1, 57, 399):
        s = core.sample(k / 20.0)
        assert np.allclose(s.velocity, sig2.u[k, :3], rtol=0, atol=1e-12)
        assert np.allclose(s.u_e, sig2.u[k, 3:], rtol=0, atol=1e-12)


def test_fade_in_out_timeline(sig2):
    r, t0 = 2.0, 5.0
    core = ExcitationCore.phase2(
        sig2.t, sig2.u, sig2.names, start_time=t0, ramp=r, offset=(1.0, 0.0, -1.0)
    )
    assert core.end_time == pytest.approx(t0 + 20.0 + 2 * r)
    s = core.sample(4.0)
    assert s.phase == IDLE and s.fraction == 0.0
    assert np.array_equal(s.velocity, [1.0, 0.0, -1.0]) and np.array_equal(s.u_e, np.zeros(4))
    # half-way through the ramp-in: raised cosine = 0.5 of the periodic signal at (tau - r) mod T
    s = core.sample(t0 + 1.0)
    assert s.phase == RAMP_IN
    x = sig2.evaluate([20.0 - 1.0])[0]
    tol = _bound(sig2, range(7))
    assert np.all(np.abs(s.u_e - 0.5 * x[3:]) <= 0.5 * tol[3:])
    assert np.all(
        np.abs(s.velocity - np.array([1.0, 0.0, -1.0]) - 0.5 * x[:3]) <= 0.5 * tol[:3] + 1e-12
    )
    # the whole central period is the untouched table
    s = core.sample(t0 + r + 3.0)
    assert s.phase == RUNNING
    assert np.allclose(s.u_e, sig2.u[60, 3:], atol=1e-15)
    assert s.fraction == pytest.approx((r + 3.0) / 24.0)
    s = core.sample(core.end_time - 0.5)
    assert s.phase == RAMP_OUT
    env = 0.5 - 0.5 * math.cos(math.pi * 0.5 / r)
    x = sig2.evaluate([(20.0 + r - 0.5 - r) % 20.0])[0]
    assert np.all(np.abs(s.u_e - env * x[3:]) <= tol[3:])
    s = core.sample(core.end_time)
    assert s.phase == DONE and s.fraction == 1.0
    assert np.array_equal(s.velocity, [1.0, 0.0, -1.0]) and not np.any(s.u_e)


def test_output_is_continuous_through_ramps(sig2):
    core = ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=1.0, ramp=1.0)
    ts = np.arange(0.0, core.end_time + 1.0, 0.002)
    v, r, ue = core.evaluate(ts)
    # starts and ends at exactly zero, no jump larger than the signal's own slope allows
    assert not np.any(ue[0]) and not np.any(ue[-1]) and not np.any(v[0])
    slope = np.max(np.abs(np.diff(sig2.u, axis=0)), axis=0) * sig2.sample_rate
    jumps = np.max(np.abs(np.diff(np.hstack([v, ue]), axis=0)), axis=0)
    assert np.all(jumps <= 0.002 * (slope + np.max(np.abs(sig2.u), axis=0) * math.pi / 2) + 1e-12)


def test_evaluate_equals_sample(sig2):
    core = ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=0.5, ramp=1.5)
    ts = np.linspace(0.0, core.end_time + 1.0, 777)
    v, r, ue = core.evaluate(ts)
    for k in range(0, 777, 7):
        s = core.sample(ts[k])
        assert np.allclose(s.velocity, v[k], atol=1e-14) and np.allclose(s.u_e, ue[k], atol=1e-14)
        assert s.yaw_rate == pytest.approx(r[k], abs=1e-14)


def test_abort_fades_to_zero_within_one_ramp(sig2):
    ramp = 1.0
    core = ExcitationCore.phase2(
        sig2.t, sig2.u, sig2.names, start_time=0.0, ramp=ramp, offset=(2.0, 0.0, 0.0)
    )
    before = core.sample(7.3)
    assert before.phase == RUNNING
    core.abort()
    assert core.aborted and core.progress.phase == ABORTED
    at = core.sample(7.3)  # same instant: continuous, starts from the current value
    assert np.allclose(at.velocity, before.velocity) and np.allclose(at.u_e, before.u_e)
    mid = core.sample(7.3 + 0.5 * ramp)
    ref = sig2.evaluate([(7.3 + 0.5 - ramp) % 20.0])[0]
    assert np.allclose(mid.u_e, 0.5 * ref[3:], atol=_bound(sig2, range(3, 7)).max())
    assert mid.velocity[0] == pytest.approx(0.5 * 2.0 + 0.5 * ref[0], abs=_bound(sig2, [0])[0])
    for t in (7.3 + ramp, 7.3 + ramp + 0.01, 30.0, 100.0):
        s = core.sample(t)
        assert s.phase == ABORTED
        assert not np.any(s.velocity) and s.yaw_rate == 0.0 and not np.any(s.u_e)
    core.abort()  # idempotent


def test_abort_during_ramp_in_starts_from_envelope(sig2):
    core = ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=0.0, ramp=2.0)
    a = core.sample(0.5)
    core.abort(0.5)
    b = core.sample(0.5)
    assert np.allclose(a.u_e, b.u_e)
    # envelope at 0.5 s of a 2 s raised cosine is 0.1464...; the abort fade multiplies it
    c = core.sample(1.5)  # 1 s into a 2 s fade -> 0.5
    ref = sig2.evaluate([(1.5 - 2.0) % 20.0])[0]
    env = (0.5 - 0.5 * math.cos(math.pi * 0.25)) * 0.5
    assert np.allclose(c.u_e, env * ref[3:], atol=_bound(sig2, range(3, 7)).max())
    assert not np.any(core.sample(2.5).u_e)


def test_abort_with_zero_ramp_is_immediate(sig1):
    core = phase1_reference([3.0, 0.0, 0.0], sig1, trim=1.0, ramp=0.0)
    core.sample(5.0)
    core.abort()
    s = core.sample(5.0)
    assert not np.any(s.velocity) and s.yaw_rate == 0.0


def test_time_going_backwards_is_an_error(sig2):
    core = ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=0.0)
    core.sample(1.0)
    core.sample(1.0)  # same stamp is fine
    with pytest.raises(TimeOrderError, match="before the last sample"):
        core.sample(0.999)
    with pytest.raises(TimeOrderError):
        core.sample(float("nan"))
    assert issubclass(TimeOrderError, SafetyError) and issubclass(TimeOrderError, LpvSysidError)
    with pytest.raises(TimeOrderError):
        core.abort(float("nan"))
    # an abort time before the last sample cannot fade what was already output: it starts now
    assert core.abort(0.5) == 1.0


def test_monotonic_time_absorbs_a_clock_jump_back():
    from lpv_sysid.signals.excitation import MonotonicTime

    clock = MonotonicTime(period=0.01)
    assert clock.map(100.0) == (100.0, 0.0)
    assert clock.map(100.01) == (100.01, 0.0)
    t, jump = clock.map(3.0)  # e.g. sim time restarted
    assert jump == pytest.approx(97.01) and t == pytest.approx(100.02)
    t2, jump2 = clock.map(3.5)  # then runs on from there, re-based
    assert jump2 == 0.0 and t2 == pytest.approx(100.52)
    with pytest.raises(TimeOrderError):
        clock.map(float("nan"))


def test_progress(sig2):
    core = ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=10.0, ramp=2.0)
    assert core.progress.phase == IDLE and core.progress.fraction == 0.0
    core.sample(10.0 + 12.0)
    assert core.progress.phase == RUNNING and core.progress.fraction == pytest.approx(0.5)


def test_bad_tables_and_channels(sig2):
    with pytest.raises(ConfigError, match="not in the signal set"):
        ExcitationCore(
            sig2.t, sig2.u, sig2.names, start_time=0.0, velocity_channels=("u_d", "v_d", "nope")
        )
    bad = sig2.u.copy()
    bad[5, 2] = np.nan
    with pytest.raises(ConfigError, match="NaN"):
        ExcitationCore.phase2(sig2.t, bad, sig2.names, start_time=0.0)
    with pytest.raises(ConfigError, match="uniform"):
        t = sig2.t.copy()
        t[3] += 0.01
        ExcitationCore.phase2(t, sig2.u, sig2.names, start_time=0.0)
    with pytest.raises(ConfigError, match="ramp"):
        ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=0.0, ramp=-1.0)


def test_non_periodic_table_ramps_inside():
    t, x = prbs(10.0, 50.0, 0.2, 0.1, 0.4, seed=1)
    u = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    core = ExcitationCore(
        t,
        u,
        ["a", "b", "c"],
        start_time=0.0,
        velocity_channels=("a", "b", "c"),
        ramp=1.0,
        periodic=False,
    )
    assert core.end_time == pytest.approx(t[-1])
    assert core.sample(0.0).velocity[0] == 0.0
    s = core.sample(5.0)
    assert s.velocity[0] == x[250]


def test_phase1_reference_vertex_trim_and_excitation(sig1):
    vertex = [5.0, -5.0, 2.0]
    core = phase1_reference(vertex, sig1)
    assert core.start_time == 10.0 and core.end_time == pytest.approx(40.0)
    ts = np.array([0.0, 9.99, 10.0 + 7.31, 39.99, 40.0, 45.0])
    v, r, ue = core.evaluate(ts)
    assert np.array_equal(v[[0, 1, 4, 5]], np.tile(vertex, (4, 1)))
    assert not np.any(ue) and np.array_equal(r[[0, 1, 4, 5]], np.zeros(4))
    exact = sig1.evaluate([7.31])[0]
    tol = _bound(sig1, range(4))
    assert np.all(np.abs(v[2] - vertex - exact[:3]) <= tol[:3])
    assert abs(r[2] - exact[3]) <= tol[3]


def test_phase1_reference_default_design():
    core = phase1_reference([0.0, 0.0, 0.0])
    assert core.end_time == pytest.approx(40.0)
    v, r, _ = core.evaluate(np.arange(10.0, 40.0, 0.02))
    assert np.max(np.abs(v), axis=0) == pytest.approx([1.0, 1.0, 0.5], rel=1e-9)
    assert np.max(np.abs(r)) == pytest.approx(0.5, rel=1e-9)


def test_several_periods_repeat_exactly(sig2):
    core = ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=0.0, ramp=1.0)
    core2 = ExcitationCore(
        sig2.t,
        sig2.u,
        sig2.names,
        start_time=0.0,
        ramp=1.0,
        periods=3,
        excitation_channels=("ue_t", "ue_a", "ue_e", "ue_r"),
    )
    assert core2.end_time == pytest.approx(3 * 20.0 + 2.0) and core.end_time == pytest.approx(22.0)
    ts = np.arange(1.0, 21.0, 0.37)
    _, _, a = core2.evaluate(ts)
    _, _, b = core2.evaluate(ts + 20.0)
    _, _, c = core2.evaluate(ts + 40.0)
    assert np.allclose(a, b, atol=1e-12) and np.allclose(a, c, atol=1e-12)
    with pytest.raises(ConfigError, match="periods"):
        ExcitationCore(sig2.t, sig2.u, sig2.names, start_time=0.0, periods=0)


def test_abort_before_any_sample_outputs_zero(sig1):
    core = phase1_reference([3.0, 1.0, 0.0], sig1, trim=5.0, ramp=1.0)
    core.abort()
    for t in (0.0, 6.0, 20.0):
        s = core.sample(t)
        assert s.phase == ABORTED and not np.any(s.velocity) and s.yaw_rate == 0.0


def test_abort_stamped_ahead_is_clamped_to_now(sig2):
    """An abort stamped 1 s in the future (issue 12 item 5) fades from the last sample on:
    half way through the 1 s raised cosine the excitation is exactly half of the undisturbed
    signal (before, it kept full amplitude until the stamp); zero after one ramp."""
    core = ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=0.0, ramp=1.0)
    ref = ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=0.0, ramp=1.0)
    core.sample(5.0)
    assert core.abort(6.0) == 5.0
    s = core.sample(5.5)
    np.testing.assert_allclose(s.u_e, 0.5 * ref.sample(5.5).u_e, rtol=1e-12, atol=1e-15)
    assert np.any(s.u_e) and s.phase == ABORTED
    assert not np.any(core.sample(6.0).u_e) and not np.any(core.sample(6.0).velocity)


def test_from_file_and_status(sig2, tmp_path):
    from lpv_sysid.signals.store import save_npz

    path = str(tmp_path / "signals.npz")
    save_npz(path, sig2.t, sig2.u, sig2.names)
    core = ExcitationCore.from_file(path, "phase2", start_time=1.0, ramp=1.0)
    ref = ExcitationCore.phase2(sig2.t, sig2.u, sig2.names, start_time=1.0, ramp=1.0)
    assert np.array_equal(core.sample(8.1).u_e, ref.sample(8.1).u_e)
    st = core.status()
    assert st["phase"] == RUNNING and st["aborted"] == "false"
    assert float(st["remaining_s"]) == pytest.approx(core.end_time - 8.1)
    assert float(st["progress"]) == pytest.approx(7.1 / 22.0, abs=1e-4)
    with pytest.raises(ConfigError, match="phase"):
        ExcitationCore.from_file(path, "phase3", start_time=0.0)
    with pytest.raises(ConfigError, match="no such file"):
        ExcitationCore.from_file(str(tmp_path / "missing.npz"), "phase2", start_time=0.0)
    # phase-1 core refuses a phase-2 table, naming the missing channel
    with pytest.raises(ConfigError, match="u_ref"):
        ExcitationCore.from_file(path, "phase1", start_time=0.0, vertex_velocity=[0, 0, 0])


def test_phase1_signals_parameters():
    from lpv_sysid.signals.excitation import phase1_signals

    s = phase1_signals(
        duration=20.0, band=(0.25, 1.0), peaks=(0.5, 0.4, 0.3, 0.2), sample_rate=20.0
    )
    assert s.names == ("u_ref", "v_ref", "w_ref", "r_ref") and s.t.size == 400
    assert np.max(np.abs(s.u), axis=0) == pytest.approx([0.5, 0.4, 0.3, 0.2], rel=1e-12)
    assert sorted(np.concatenate(s.harmonics).tolist()) == list(
        range(5, 21)
    )  # 0.25..1 Hz, f0 = 0.05
