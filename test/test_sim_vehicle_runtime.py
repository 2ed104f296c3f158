"""nodes/sim_vehicle_runtime directly (no rclpy, no stand-in): lock-step rules on a simulated
pace clock. Defaults: physics 500 Hz (dt 2 ms), state 250 Hz (every 2nd step), catch-up
0.1 s (50 steps)."""

import os
import subprocess
import sys

import numpy as np
import pytest

from lpv_sysid.io import messages
from lpv_sysid.sim.vehicle import SensorConfig
from lpv_sysid.sim.vehicle_node import (
    LOCKSTEP_RESEND_S,
    SLIP_LOG_PERIOD_S,
    SimVehicleRuntime,
    SimVehicleSettings,
)

MS = 1_000_000  # ns


def runtime(t0_ns=0, **settings):
    log = []
    rt = SimVehicleRuntime(
        SimVehicleSettings(**settings),
        SensorConfig(),
        messages.MsgFactory.rosbags(),
        t0_ns=t0_ns,
        log=lambda level, text: log.append((level, text)),
    )
    return rt, log


def stamps(out, topic):
    return [messages.stamp_ns_of(m) for t, m in out if t == topic]


def record_steps(rt):
    applied = []
    real_step = rt.vehicle.step
    rt.vehicle.step = lambda u: (applied.append((rt.k, list(u))), real_step(u))[1]
    return applied


def engaged_at_k2(**settings):
    """Lockstep lpv runtime, engaged by a command stamped 0, waiting at k = 2 (t = 4 ms)
    since pace 10 ms."""
    rt, log = runtime(mode="lpv", lockstep=True, **settings)
    rt.on_tick(2 * MS)  # k = 0 -> 1 (not engaged yet)
    assert rt.on_command(0.0, rt.u, 3 * MS) == [] and rt.engaged
    out = rt.on_tick(10 * MS)  # due 5: stops at the state sample k = 2
    assert rt.k == 2 and rt.awaiting == [2, 10 * MS, 0]
    assert stamps(out, "state") == [4 * MS]
    return rt, log


def test_runtime_modules_never_import_rclpy():
    code = (
        "import sys; import lpv_sysid.sim.vehicle_node.runtime, "
        "lpv_sysid.flight.excitation; print('rclpy' in sys.modules)"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=root, env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"


def test_free_run_publishes_clock_before_each_state_sample():
    rt, _ = runtime(mode="lpv", lockstep=True)
    out = rt.on_tick(10 * MS)  # 5 physics steps, sim time from 0
    assert rt.k == 5 and rt.physics_stamp_ns() == 10 * MS
    topics = [t for t, _ in out]
    assert topics[:2] == ["clock", "state"]
    assert stamps(out, "state") == [0, 4 * MS, 8 * MS]
    clock = [messages.stamp_ns_from_time(m.clock) for t, m in out if t == "clock"]
    assert clock == [0, 4 * MS, 8 * MS]
    assert stamps(out, "imu") == [0, 4 * MS, 8 * MS]  # 250 Hz
    assert stamps(out, "rotor_speeds") == [0]  # 100 Hz: every 5th step
    # every clock is followed at once by the state of its instant
    assert all(topics[i + 1] == "state" for i, t in enumerate(topics) if t == "clock")


def test_unanswered_state_sample_is_resent_every_resend_period():
    rt, _ = engaged_at_k2()
    assert LOCKSTEP_RESEND_S == 0.05
    assert rt.on_tick(10 * MS + 49 * MS) == []  # 49 ms of wall time: not yet
    out = rt.on_tick(10 * MS + 51 * MS)
    assert stamps(out, "state") == [4 * MS] and [t for t, _ in out] == ["state"]
    assert rt.on_tick(10 * MS + 99 * MS) == []
    assert stamps(rt.on_tick(10 * MS + 101 * MS), "state") == [4 * MS]
    assert rt.lockstep_resends == 2 and rt.k == 2 and rt.awaiting == [2, 10 * MS, 2]


def test_the_command_of_the_sample_releases_the_physics_and_is_held_from_it():
    rt, _ = engaged_at_k2()
    applied = record_steps(rt)
    u_new = [rt.u[0] + 0.01, 0.0, 0.0, 0.0]
    assert rt.on_command(0.0, u_new, 20 * MS) == []  # a command of another instant
    assert rt.k == 2
    out = rt.on_command(0.004, u_new, 20 * MS)  # stamped with the state at k = 2
    # released: steps 2 and 3 with u_new, then waits at the next state sample k = 4
    assert rt.k == 4 and rt.awaiting == [4, 20 * MS, 0]
    assert applied == [(2, pytest.approx(u_new)), (3, pytest.approx(u_new))]
    assert stamps(out, "state") == [8 * MS] and rt.slip_ns == 0
    assert rt.lockstep_timeouts == 0 and rt.lockstep_resends == 0


def test_timeout_after_lockstep_timeout_s_runs_on_without_the_controller():
    rt, log = engaged_at_k2(lockstep_timeout_s=0.3)
    wall = 10 * MS
    for dt in range(5, 300, 10):  # waited 5, 15, ..., 295 ms: resends at 55, 105, ... 255
        rt.on_tick(wall + dt * MS)
    assert rt.k == 2 and rt.lockstep_resends == 5 and rt.lockstep_timeouts == 0
    out = rt.on_tick(wall + 305 * MS)  # waited 305 ms > 0.3 s
    assert rt.lockstep_timeouts == 1 and not rt.engaged and rt.awaiting is None
    assert log[-1] == (
        "warn",
        "lockstep: no actuator_command or lockstep_ack for the state at t=0.004 s within 0.3 s "
        "of wall time: running on without it",
    )
    # ran on by max_catch_up_s (50 steps: states at 8 ... 100 ms), the rest slipped:
    # pace 315 ms = 210 ms slipped + 104 ms of physics + 1 ms not yet due
    assert rt.k == 52 and stamps(out, "state") == [k * 2 * MS for k in range(4, 51, 2)]
    assert rt.slip_ns == 210 * MS
    assert not rt.handed_back
    rt.on_tick(wall + 305 * MS + 20 * MS)  # 10 steps on: command 0.1 s old at t = 0.104 s
    assert rt.handed_back and log[-1] == (
        "warn",
        "actuator_command stale: baseline holds (hand-back)",
    )


def test_physics_waits_while_the_reference_is_older_than_the_lag():
    rt, log = runtime(mode="baseline", lockstep=True, lockstep_reference_lag_s=0.03)
    rt.on_tick(2 * MS)  # k = 1
    rt.on_reference(0.0, np.zeros(3), 0.0, 2 * MS)  # on sim time (2 ms old): engaged
    assert rt.ref_engaged and log == [
        ("info", "lockstep: velocity_reference on sim time; the physics waits for it")
    ]
    rt.on_tick(100 * MS)  # due 50: stops at the first state instant > 30 ms after stamp 0
    assert rt.k == 16 and rt.physics_stamp_ns() == 32 * MS
    assert rt.awaiting == [16, 100 * MS, 0]
    rt.on_tick(400 * MS)  # a reference wait is never resent (only the state is best effort)
    assert rt.k == 16 and rt.lockstep_resends == 0
    rt.on_reference(0.002, np.zeros(3), 0.0, 400 * MS)  # 2 ms: the wait at 32 ms is over
    assert rt.k == 18 and rt.awaiting[0] == 18  # and the next one at 36 ms begins
    # a reference publisher that stops: after lockstep_timeout_s (1 s) no longer waited for
    rt.on_tick(400 * MS + 1001 * MS)
    assert not rt.ref_engaged and rt.lockstep_timeouts == 1 and rt.k > 18
    assert "no velocity_reference for the state at t=0.036 s" in log[-1][1]


def test_a_reference_not_on_sim_time_does_not_engage():
    rt, _ = runtime(mode="baseline", lockstep=True, lockstep_reference_lag_s=0.03)
    rt.on_tick(2 * MS)
    rt.on_reference(1.7e9, np.zeros(3), 0.0, 2 * MS)  # wall-clock stamp
    assert not rt.ref_engaged
    rt.on_tick(100 * MS)
    assert rt.k == 50 and rt.awaiting is None


def test_real_time_slip_is_counted_and_its_warning_throttled():
    t0 = 1_000_000_000
    rt, log = runtime(t0_ns=t0)  # real time: the node clock paces, stamps on it
    rt.on_tick(t0 + 20 * MS)
    assert rt.k == 10 and rt.slip_ns == 0 and rt.physics_stamp_ns() == t0 + 20 * MS
    rt.on_tick(t0 + 1020 * MS)  # 1 s stall: 0.1 s made up, 0.9 s slipped
    assert rt.k == 60 and rt.slip_ns == 900 * MS
    assert rt.physics_stamp_ns() == t0 + 1020 * MS
    assert log == [
        ("warn", "simulation 1.000 s behind the clock: slipping real time (total 0.900 s)")
    ]
    rt.on_tick(t0 + 2020 * MS)  # slips again within SLIP_LOG_PERIOD_S: silent
    assert rt.slip_ns == 1800 * MS and len(log) == 1
    rt.on_tick(t0 + 1020 * MS + round(SLIP_LOG_PERIOD_S * 1e9))
    assert len(log) == 2 and "total" in log[-1][1]


def test_status_reports_the_real_time_factor_and_counters():
    rt, _ = engaged_at_k2()
    rt.on_tick(10 * MS + 51 * MS)  # one resend
    rt.on_command(0.004, rt.u, 70 * MS)  # released at pace 70 ms: runs to k = 4
    first = rt.status(70 * MS)  # since the start: 4 steps (8 ms) in 70 ms
    _, (st,) = messages.status_from_diagnostic_array(first)
    assert messages.stamp_ns_of(first) == 8 * MS  # lockstep: physics time
    assert st.level == 0 and st.message == "lpv" and st.name == "/lpv_sysid/sim_vehicle"
    v = st.values
    assert float(v["real_time_factor"]) == pytest.approx(round(8 / 70, 4))
    assert (v["lockstep_engaged"], v["lockstep_resends"], v["lockstep_timeouts"]) == (
        "true",
        "1",
        "0",
    )
    rt.on_command(0.008, rt.u, 80 * MS)  # k 4 -> 6 (waits at 6) in the next 10 ms
    _, (st,) = messages.status_from_diagnostic_array(rt.status(80 * MS))
    assert float(st.values["real_time_factor"]) == pytest.approx(0.4)  # 4 ms per 10 ms
