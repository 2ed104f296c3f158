"""Timing of the phase-2 loop (issue 11 item 3) on the cores and through the rclpy stand-in:
the declared timeout rule, the controller stepping on each state sample (``tick_source:
state``), the reference between its messages (``reference_hold``) and sim_vehicle's lock-step
on sim time. The same graph under a real Jazzy: test_ros_phase2.py.

Measured under real Jazzy on 2 loaded cores before these changes: the shipped
``state_timeout_s: 0.02`` aborted 0.7 s after start (state delivery latency p99 31 ms, max
62 ms), and the wall-clock loop (~14 ms mean delay) went unstable: the demo gains tolerate
8-12 ms of loop delay at 250 Hz.
"""

import os

import numpy as np
import pytest
import rclpy
import rclpy._standin as standin
import yaml
from lpv_test_gains import write_gains
from nav_msgs.msg import Odometry
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState

from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.controller import TIMEOUT_PERIODS, ControllerRuntime, ControllerSettings
from lpv_sysid.io import messages

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "config")
STREAMS = {
    "state_timeout_s": "state_rate_hz",
    "rotor_timeout_s": "rotor_rate_hz",
    "reference_timeout_s": "reference_rate_hz",
    "excitation_timeout_s": "excitation_rate_hz",
}


@pytest.fixture(scope="module")
def gains(tmp_path_factory):
    return write_gains(tmp_path_factory.mktemp("g") / "gains.yaml", box=2.0)


def shipped() -> dict:
    with open(os.path.join(CONFIG, "lpv_controller.yaml")) as fh:
        (body,) = yaml.safe_load(fh).values()
    return body["ros__parameters"]


# --------------------------------------------------------------- the declared timeout rule
@pytest.mark.parametrize("timeout, rate", sorted(STREAMS.items()))
def test_a_timeout_below_two_periods_plus_latency_is_refused(gains, timeout, rate):
    base = {
        "gains_file": gains,
        "input_latency_s": 0.03,
        "state_timeout_s": 0.5,
        "rotor_timeout_s": 0.5,
        "reference_timeout_s": 0.5,
        "excitation_timeout_s": 0.5,
    }
    least = 2.0 / 100.0 + 0.03  # the rule, by hand: 2 / rate + latency
    ControllerSettings(**{**base, rate: 100.0, timeout: least})  # exactly the rule: valid
    with pytest.raises(ConfigError) as exc:
        ControllerSettings(**{**base, rate: 100.0, timeout: least - 0.001})
    msg = str(exc.value)
    assert f"{timeout} 0.049 s is below 2 / {rate}" in msg and "= 0.05 s" in msg


def test_the_shipped_config_obeys_the_rule_and_the_old_state_timeout_would_not(gains):
    p = shipped()
    assert TIMEOUT_PERIODS == 2
    for timeout, rate in STREAMS.items():
        assert p[timeout] >= 2.0 / p[rate] + p["input_latency_s"], timeout
    ControllerSettings.from_dict({**p, "gains_file": gains})
    # the value that aborted under real Jazzy (issue 11) against the latency measured there
    with pytest.raises(ConfigError, match="state_timeout_s 0.02 s is below"):
        ControllerSettings.from_dict({**p, "gains_file": gains, "state_timeout_s": 0.02})


def test_stamp_tolerance_covers_one_state_period(gains):
    with pytest.raises(ConfigError, match=r"below one state period \(1 / state_rate_hz = 0.01"):
        ControllerSettings(gains_file=gains, state_rate_hz=100.0, stamp_tolerance_s=0.005)
    ControllerSettings(gains_file=gains, state_rate_hz=100.0, stamp_tolerance_s=0.01)


# ------------------------------------------------------------ tick_source: state (runtime)
def runtime(gains, **kw):
    return ControllerRuntime(
        ControllerSettings(gains_file=gains, **kw), messages.MsgFactory.rosbags()
    )


def centre_inputs(rt):
    gs = rt.schedule
    x0 = gs.x0.mean(axis=0)
    return x0[:8], np.linalg.solve(rt.mix, x0[8:])


def by_hand(rt, rigid_body_state, om, u_e):
    """u = u0 + K (x - x0) + R u_e at v_d = 0, the box centre: every vertex weighs 1/8."""
    gs = rt.schedule
    x = np.concatenate([rigid_body_state, rt.mix @ om])
    return gs.u0.mean(0) + gs.K.mean(0) @ (x - gs.x0.mean(0)) + gs.R @ u_e


def test_state_ticks_compute_each_command_on_its_own_sample(gains):
    rt = runtime(gains, tick_source="state")
    rigid_body_state, om = centre_inputs(rt)
    ue = np.array([0.01, -0.02, 0.005, 0.0])
    f = messages.MsgFactory.rosbags()
    t0 = 100.0
    rt.on_sample("rotor_speeds", t0, om, t0)
    rt.on_sample("velocity_reference", t0, np.zeros(4), t0)
    rt.on_sample("excitation", t0, ue, t0)
    assert rt.start(t0)[0]
    rng = np.random.default_rng(3)
    for k in range(1, 6):
        t = t0 + 0.004 * k
        xk = rigid_body_state + rng.normal(0.0, 0.01, 8)
        msg = messages.odometry_from_state(
            f, round(t * 1e9), np.zeros(3), [xk[0], xk[1], 0.0], xk[2:5], xk[5:8]
        )
        # delivered 1 ms late: the command is the law at the sample's stamp, on the sample
        out = rt.on_input("state", msg, t + 0.001)
        assert [topic for topic, _ in out] == ["actuator_command"]
        cmd = out[0][1]
        assert messages.stamp_ns_of(cmd) == round(t * 1e9)
        s = messages.state_from_odometry(msg)
        x_sent = np.concatenate([s.euler[:2], s.v_body, s.omega])
        np.testing.assert_allclose(cmd.position, by_hand(rt, x_sent, om, ue), atol=1e-12)
        assert rt.on_input("state", msg, t + 0.002) == []  # the same sample again: nothing
        assert rt.on_timer(t + 0.002) == []  # the timer only watches
    assert rt.commands == 5


def test_state_ticks_see_the_inputs_by_stamp_not_by_arrival(gains):
    """tick_source state: the command at a state sample uses the newest sample of each other
    stream stamped at or before it, whatever order the transport delivered them in (measured
    on PX4 SITL through the ROS graph, newest-received: 6-9 % of the commands were not
    reproduced by a replay of the bag). A sample stamped at or before a state already ticked
    arrives late: the next state's command uses it, and it is counted in the status."""
    rt = runtime(gains, tick_source="state")
    rigid_body_state, om = centre_inputs(rt)
    f = messages.MsgFactory.rosbags()
    ue = [np.array([0.01 * k, -0.02, 0.005 * k, 0.0]) for k in range(4)]
    t0 = 100.0
    for topic, v in (("rotor_speeds", om), ("velocity_reference", np.zeros(4))):
        rt.on_sample(topic, t0, v, t0)
    rt.on_sample("excitation", t0, ue[0], t0)

    def state(t):
        msg = messages.odometry_from_state(
            f,
            round(t * 1e9),
            np.zeros(3),
            [*rigid_body_state[:2], 0.0],
            rigid_body_state[2:5],
            rigid_body_state[5:8],
        )
        out = rt.on_input("state", msg, t + 0.003)
        return np.asarray(out[0][1].position)

    assert rt.start(t0)[0]
    t1, t2, t3 = t0 + 0.01, t0 + 0.02, t0 + 0.03
    # ue[1] stamped after the state at t1 but delivered before it: not that state's input
    rt.on_sample("excitation", t1 + 0.002, ue[1], t1 + 0.0025)
    np.testing.assert_allclose(state(t1), by_hand(rt, rigid_body_state, om, ue[0]), atol=1e-12)
    np.testing.assert_allclose(state(t2), by_hand(rt, rigid_body_state, om, ue[1]), atol=1e-12)
    assert rt.late_inputs == 0
    # ue[2] stamped before the state at t2 but delivered after it: late, used at t3
    rt.on_sample("excitation", t2 - 0.001, ue[2], t2 + 0.004)
    assert rt.late_inputs == 1
    np.testing.assert_allclose(state(t3), by_hand(rt, rigid_body_state, om, ue[2]), atol=1e-12)
    status = rt.status(t3 + 0.003)
    (st,) = status.status
    assert {kv.key: kv.value for kv in st.values}["late_input_count"] == "1"


def test_state_ticks_timer_still_aborts_a_silent_state_stream(gains):
    rt = runtime(gains, tick_source="state")
    rigid_body_state, om = centre_inputs(rt)
    for topic, v in (
        ("state", rigid_body_state),
        ("rotor_speeds", om),
        ("velocity_reference", np.zeros(4)),
        ("excitation", np.zeros(4)),
    ):
        rt.on_sample(topic, 10.0, v, 10.0)
    rt.start(10.0)
    t, out = 10.0, []
    while not out:
        t += 0.004
        for topic, v in (
            ("rotor_speeds", om),
            ("velocity_reference", np.zeros(4)),
            ("excitation", np.zeros(4)),
        ):
            rt.on_sample(topic, t, v, t)
        out = rt.on_timer(t)
    assert [topic for topic, _ in out] == ["status"]
    assert rt.supervisor.event.reason == "stale"
    assert "state" in rt.supervisor.event.detail
    assert t - 10.0 == pytest.approx(0.02 + 0.004, abs=0.0041)  # default timeout 0.02 s


def test_start_waits_for_every_input_stream(gains):
    """Measured under real Jazzy: started the moment its service appeared, before discovery
    had matched the excitation node, the controller latched a stale abort 0.1 s later."""
    rt = runtime(gains)
    rigid_body_state, om = centre_inputs(rt)
    samples = [
        ("state", rigid_body_state),
        ("rotor_speeds", om),
        ("velocity_reference", np.zeros(4)),
        ("excitation", np.zeros(4)),
    ]
    for i, (topic, v) in enumerate(samples):
        ok, why = rt.start(10.0, wait_for_inputs=True)
        assert not ok and not rt.supervisor.armed
        assert why.startswith(f"no {', '.join(t for t, _ in samples[i:])} received yet")
        rt.on_sample(topic, 10.0, v, 10.0)
    assert rt.start(10.0, wait_for_inputs=True) == (True, "LPV control started")


def test_timer_ticks_are_unchanged_by_state_samples(gains):
    rt = runtime(gains)  # tick_source: timer (default)
    rigid_body_state, om = centre_inputs(rt)
    f = messages.MsgFactory.rosbags()
    for topic, v in (
        ("rotor_speeds", om),
        ("velocity_reference", np.zeros(4)),
        ("excitation", np.zeros(4)),
    ):
        rt.on_sample(topic, 5.0, v, 5.0)
    rt.start(5.0)
    msg = messages.odometry_from_state(
        f,
        5_004_000_000,
        np.zeros(3),
        [rigid_body_state[0], rigid_body_state[1], 0.0],
        rigid_body_state[2:5],
        rigid_body_state[5:8],
    )
    assert rt.on_input("state", msg, 5.004) == []
    ((topic, cmd),) = rt.on_timer(5.006)
    assert topic == "actuator_command" and messages.stamp_ns_of(cmd) == 5_006_000_000


# --------------------------------------------------------------------- reference_hold
@pytest.mark.parametrize("hold", ["foh", "zoh"])
def test_reference_between_its_messages(gains, hold):
    """A ramp v_d = 0.5 t (m/s) sent at 100 Hz, read at 250 Hz: foh gives the ramp itself
    between messages (the table is linear there), zoh the value of the last message."""
    rt = runtime(gains, reference_hold=hold)
    slope = 0.5
    worst = 0.0
    for m in range(20):
        tm = 1.0 + 0.01 * m
        rt.on_sample("velocity_reference", tm, np.array([slope * tm, 0.0, 0.0, 0.0]), tm)
        for k in range(3):
            t = tm + 0.004 * k  # before the next message
            got = rt.reference_at(t)[0]
            want = slope * t if hold == "foh" else slope * tm
            if m >= 1:  # (a slope needs two messages)
                assert got == pytest.approx(want, abs=1e-12)
                worst = max(worst, abs(got - slope * t))
    assert (worst < 1e-12) == (hold == "foh")
    assert rt.limiter.limited == 0  # inside the design envelope


def test_foh_extrapolation_is_bounded_by_the_reference_timeout(gains):
    rt = runtime(gains, reference_hold="foh")
    for m in range(5):
        tm = 1.0 + 0.01 * m
        rt.on_sample("velocity_reference", tm, np.array([0.5 * tm, 0.0, 0.0, 0.0]), tm)
    assert rt.limiter.limited == 0
    # 0.5 m/s^2 from 0.52 m/s at 1.04 s: 0.1 s (reference_timeout_s) ahead at most, one
    # 10 ms period (1 / reference_rate_hz) back at most
    assert rt.reference_at(5.0)[0] == pytest.approx(0.52 + 0.5 * 0.1, abs=1e-12)
    assert rt.reference_at(0.0)[0] == pytest.approx(0.52 - 0.5 * 0.01, abs=1e-12)


# ------------------------------------------------------- sim_vehicle lock-step (stand-in)
@pytest.fixture
def fresh():
    standin.reset()
    yield
    rclpy.try_shutdown()


def lockstep_vehicle(*pairs):
    from lpv_sysid.nodes.sim_vehicle_node import SimVehicleNode

    args = [
        "n",
        "--ros-args",
        "--params-file",
        os.path.join(CONFIG, "sim_vehicle.yaml"),
        "-p",
        "mode:=lpv",
        "-p",
        "lockstep:=true",
    ]
    for k, v in pairs:
        args += ["-p", f"{k}:={v}"]
    rclpy.init(args=args)
    return SimVehicleNode(namespace="lpv_sysid")


class Answerer:
    """A controller stand-in: answers each state sample with the trim command stamped with
    the sample's stamp (what lpv_controller does with tick_source: state)."""

    def __init__(self, node, u, answer=True):
        self.node, self.u, self.answer = node, list(u), answer
        self.f = messages.MsgFactory.rclpy()
        self.states, self.clock = [], []
        be = QoSProfile(depth=1000, reliability=QoSReliabilityPolicy.BEST_EFFORT)
        self.pub = node.create_publisher(JointState, "/lpv_sysid/actuator_command", 10)
        node.create_subscription(Odometry, "/lpv_sysid/state", self.on_state, be)
        node.create_subscription(
            ClockMsg,
            "/clock",
            lambda m: self.clock.append(messages.stamp_ns_from_time(m.clock)),
            1000,
        )

    def on_state(self, msg):
        self.states.append(messages.stamp_ns_of(msg))
        if self.answer:
            self.pub.publish(
                messages.actuator_command_msg(self.f, messages.stamp_ns_of(msg), self.u)
            )


def test_lockstep_sim_time_starts_at_zero_and_publishes_the_clock(fresh):
    node = lockstep_vehicle()
    probe = Answerer(rclpy.create_node("probe"), node.runtime.u, answer=False)
    standin.spin_nodes([node, probe.node], 0.2)
    # not engaged (nobody commands): free-runs paced by the steady clock, sim time from 0
    assert probe.states[:3] == [0, 4_000_000, 8_000_000]
    assert probe.clock == probe.states  # /clock: one per state, same time
    assert not node.runtime.engaged and len(probe.states) >= 49


def test_lockstep_waits_for_the_command_of_each_state_sample(fresh):
    node = lockstep_vehicle()
    ctl = Answerer(rclpy.create_node("controller"), node.runtime.u)
    ex = standin.spin_nodes([node, ctl.node], 0.5)
    assert node.runtime.engaged
    applied = []
    real_step = node.runtime.vehicle.step
    node.runtime.vehicle.step = lambda u: (
        applied.append((node.runtime.k, list(u))),
        real_step(u),
    )[1]
    # the controller goes silent: the physics stops at the next state sample ...
    ctl.answer = False
    standin.spin_for(ex, 0.5)
    k_stuck = node.runtime.k
    assert k_stuck % node.runtime.d_state == 0 and node.runtime.awaiting[0] == k_stuck
    standin.spin_for(ex, 0.3)
    assert node.runtime.k == k_stuck  # ... and stays there (wall 0.8 s < 1 s)
    assert node.runtime.lockstep_resends >= 5  # the sample is sent again (best effort)
    assert ctl.states[-1] == k_stuck * node.runtime.dt_ns  # the resent sample: same stamp
    # its command arrives: exactly that command is held over the next physics steps
    u_new = [node.runtime.u[0] + 0.01, 0.0, 0.0, 0.0]
    ctl.pub.publish(messages.actuator_command_msg(ctl.f, k_stuck * node.runtime.dt_ns, u_new))
    ctl.u, ctl.answer = u_new, True
    standin.spin_for(ex, 0.1)
    assert node.runtime.k > k_stuck + node.runtime.d_state
    assert applied[-1][1] == pytest.approx(u_new) and applied[-1][0] > k_stuck
    first = next(u for k, u in applied if k == k_stuck)
    assert first == pytest.approx(u_new)  # computed on the state at k, held from k


def test_lockstep_runs_on_without_a_stopped_controller(fresh):
    node = lockstep_vehicle(("lockstep_timeout_s", 0.3))
    ctl = Answerer(rclpy.create_node("controller"), node.runtime.u)
    ex = standin.spin_nodes([node, ctl.node], 0.2)
    ctl.answer = False
    standin.spin_for(ex, 1.0)
    assert node.runtime.lockstep_timeouts == 1 and not node.runtime.engaged
    k = node.runtime.k
    standin.spin_for(ex, 0.5)
    assert node.runtime.k - k >= 0.4 * 500  # free again, paced at real time
    assert node.runtime.handed_back  # baseline hold after command_timeout_s


def test_lockstep_waits_for_a_reference_on_sim_time(fresh):
    """Once velocity_reference comes on sim time, the physics never runs more than
    lockstep_reference_lag_s ahead of it (a starved excitation node slows the simulation
    instead of going stale at the controller)."""
    from geometry_msgs.msg import TwistStamped

    node = lockstep_vehicle(("lockstep_reference_lag_s", 0.03))
    exc = rclpy.create_node("excitation")
    f = messages.MsgFactory.rclpy()
    pub = exc.create_publisher(TwistStamped, "/lpv_sysid/velocity_reference", 10)
    sim_now = {"ns": 0}
    exc.create_subscription(
        ClockMsg, "/clock", lambda m: sim_now.update(ns=messages.stamp_ns_from_time(m.clock)), 10
    )
    sending = {"on": True}

    def tick():
        if sending["on"]:
            pub.publish(messages.twist_reference_msg(f, sim_now["ns"], [0.0, 0.0, 0.0], 0.0))

    exc.create_timer(0.01, tick)
    ex = standin.spin_nodes([node, exc], 0.3)
    assert node.runtime.ref_engaged
    sending["on"] = False
    last = node.runtime._ref_stamp_ns
    standin.spin_for(ex, 0.5)
    assert (
        node.runtime.physics_stamp_ns() - last
        <= 0.03e9 + node.runtime.d_state * node.runtime.dt_ns
    )
    assert node.runtime.awaiting is not None
