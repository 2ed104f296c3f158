"""The lock-stepped phase-2 graph of sim.launch.py at message level, without ROS: the
simulated vehicle's and the controller's runtimes (the code the nodes run) joined by a model
of the transport -- keep-last queues per subscription (``/clock`` depth 1 as rclpy's time
source, sensors 5, reliable streams 10), a controller that takes one message per
subscription per wake in the order its node creates them (LeanExecutor: the watchdog timer,
then /clock, state, rotor_speeds, velocity_reference, excitation), its node clock the newest
``/clock`` it took -- and a stand-in excitation node that publishes the reference and the
excitation on sim time at 100 Hz.

The case of CI (test_ros_phase2.py at load 10-20 on 2 cores): the controller starts and is
then descheduled before its first command. Before the fix the simulation engaged its
barrier only on that first command, so it ran on the wall clock meanwhile; the controller
woke to a /clock 150 ms past its start, ticked on a queued state sample before taking the
queued rotor_speeds and aborted ("stale: rotor_speeds: no message for 0.150 s since
arming"; CI: 0.064 s). The oracle of the fix is the lock-step contract itself: every state
sample the simulation publishes is answered exactly once (its command, or ``lockstep_ack``),
the physics never passes an unanswered sample, so the stall costs no sim time at all."""

import re
from collections import deque
from pathlib import Path

import numpy as np
import pytest
import yaml

from lpv_sysid.control.safety import STALE
from lpv_sysid.flight.controller import ControllerRuntime, ControllerSettings
from lpv_sysid.io import messages
from lpv_sysid.sim.vehicle import SensorConfig
from lpv_sysid.sim.vehicle_node import SimVehicleRuntime, SimVehicleSettings

ROOT = Path(__file__).resolve().parents[1]
GAINS = ROOT / "msg_samples" / "gains.yaml"
MS = 1_000_000  # ns
F = messages.MsgFactory.rosbags()
#: controller subscriptions in the node's creation order (the executor's order per wake)
CONTROLLER_INPUTS = ("state", "rotor_speeds", "velocity_reference", "excitation")
DEPTH = {"clock": 1, "state": 5, "rotor_speeds": 5, "velocity_reference": 10, "excitation": 10}


def controller_settings(lockstep: bool) -> ControllerSettings:
    """config/lpv_controller.yaml with the overrides sim.launch.py gives the controller."""
    (body,) = yaml.safe_load((ROOT / "config" / "lpv_controller.yaml").read_text()).values()
    params = dict(body["ros__parameters"])
    params.update(
        gains_file=str(GAINS),
        tick_source="state",
        reference_hold="foh",
        input_latency_s=0.01,
        lockstep=lockstep,
    )
    return ControllerSettings.from_dict(params)


class Graph:
    """sim_vehicle (lockstep, lpv) + lpv_controller + a 100 Hz excitation stand-in on one
    wall clock advanced in 1 ms steps; ``stall`` = wall interval in which the controller
    process gets no CPU."""

    def __init__(self, lockstep: bool):
        self.sim = SimVehicleRuntime(
            SimVehicleSettings(mode="lpv", lockstep=True), SensorConfig(), F, log=self._log
        )
        self.ctl = ControllerRuntime(controller_settings(lockstep), F)
        self.ctl.lockstep_linked = True  # the simulation subscribes to the answers (the shell)
        self.ctl_q = {k: deque(maxlen=d) for k, d in DEPTH.items()}
        self.sim_q: deque = deque()  # reliable: commands, acks, references, in arrival order
        self.exc_clock: deque = deque(maxlen=1)
        self.exc_due = 0
        self.ctl_now = 0.0  # the controller's node clock [s] (newest /clock taken)
        self.watch_due = 0.0
        self.wall = 0
        self.stall = (0, 0)
        self.sim_at_stall_end = 0
        self.published_states: list[int] = []
        self.answers: list[tuple[str, int]] = []
        self.logs: list = []

    def _log(self, level, text):
        self.logs.append((level, text))

    # -- transport ----------------------------------------------------------------
    def _from_sim(self, out):
        for topic, msg in out:
            if topic == "clock":
                self.ctl_q["clock"].append(msg)
                self.exc_clock.append(msg)
            elif topic in ("state", "rotor_speeds"):
                if topic == "state":
                    self.published_states.append(messages.stamp_ns_of(msg))
                self.ctl_q[topic].append(msg)

    def _from_controller(self, out):
        for topic, msg in out:
            if topic == "actuator_command":
                self.answers.append((topic, messages.stamp_ns_of(msg)))
                self.sim_q.append((topic, msg))
            elif topic == "lockstep_ack":
                self.answers.append((topic, messages.clock_ns_of(msg)))
                self.sim_q.append((topic, msg))

    # -- processes ----------------------------------------------------------------
    def _sim_wake(self):
        if self.wall % (4 * MS) == 0:  # its 250 Hz steady timer
            self._from_sim(self.sim.on_tick(self.wall))
        while self.sim_q:
            topic, msg = self.sim_q.popleft()
            if topic == "actuator_command":
                t, u = messages.actuator_command_from_joint_state(msg)
                self._from_sim(self.sim.on_command(t, u, self.wall))
            elif topic == "lockstep_ack":
                self._from_sim(self.sim.on_answer(messages.clock_ns_of(msg) * 1e-9, self.wall))
            else:
                t, v, r = messages.reference_from_twist(msg)
                self._from_sim(self.sim.on_reference(t, v, r, self.wall))

    def _excitation_wake(self):
        """The excitation node on sim time: a 100 Hz timer stamped with its clock."""
        if not self.exc_clock:
            return
        now = messages.clock_ns_of(self.exc_clock.pop())
        if now < self.exc_due:
            return
        self.exc_due = (now // (10 * MS) + 1) * 10 * MS
        ref = messages.twist_reference_msg(F, now, np.zeros(3), 0.0)
        self.ctl_q["velocity_reference"].append(ref)
        self.ctl_q["excitation"].append(messages.excitation_msg(F, now, np.zeros(4)))
        self.sim_q.append(("velocity_reference", ref))

    def _controller_wake(self):
        if self.stall[0] <= self.wall < self.stall[1]:
            return
        ctl = self.ctl
        if self.ctl_now >= self.watch_due > 0.0:  # the watchdog timer (sim time)
            self._from_controller(ctl.on_timer(self.ctl_now))
        if self.watch_due == 0.0 or self.ctl_now >= self.watch_due:
            self.watch_due = self.ctl_now + ctl.settings.timer_period_s
        if self.ctl_q["clock"]:
            self.ctl_now = messages.clock_ns_of(self.ctl_q["clock"].popleft()) * 1e-9
        for topic in CONTROLLER_INPUTS:
            if self.ctl_q[topic]:
                msg = self.ctl_q[topic].popleft()
                self._from_controller(ctl.on_input(topic, msg, self.ctl_now))

    def run_until(self, wall_ns: int):
        while self.wall < wall_ns:
            self.wall += MS
            self._sim_wake()
            self._excitation_wake()
            self._controller_wake()


def start_then_stall(lockstep: bool, stall_ms: int = 150) -> tuple[Graph, float]:
    """Run 0.3 s, start the controller (the start service, end of a wake), deschedule it for
    ``stall_ms`` of wall time at once, run on to 1 s; returns the graph and the start time."""
    g = Graph(lockstep)
    g.run_until(300 * MS)
    ok, why = g.ctl.start(g.ctl_now, wait_for_inputs=True)
    assert ok, why
    t_start = g.ctl_now
    g.stall = (g.wall + MS, g.wall + MS + stall_ms * MS)
    g.run_until(g.stall[1])
    g.sim_at_stall_end = g.sim.physics_stamp_ns()
    g.run_until(1000 * MS)
    return g, t_start


def test_without_the_controllers_answer_a_stall_after_start_aborts_stale():
    """The failure of CI reproduced in the model (the controller answering with commands
    only, as before): the simulation runs on the wall clock until the first command."""
    g, t_start = start_then_stall(lockstep=False)
    ev = g.ctl.supervisor.event
    assert ev is not None and ev.reason == STALE, ev
    m = re.fullmatch(
        r"rotor_speeds: no message for ([0-9.]+) s since arming \(timeout 0.06 s\)", ev.detail
    )
    assert m, ev.detail
    # the sim time ran on during the stall: the abort ~150 ms of sim time after the start
    assert float(m.group(1)) == pytest.approx(ev.t - t_start, abs=1e-6)
    assert ev.t - t_start == pytest.approx(0.150, abs=0.005)


def test_lockstep_answers_hold_the_simulation_through_a_stall_after_start():
    g, t_start = start_then_stall(lockstep=True)
    assert g.ctl.supervisor.event is None, g.ctl.supervisor.event
    assert g.ctl.supervisor.armed and g.ctl.commands > 100
    assert g.sim.lockstep_timeouts == 0 and g.sim.lockstep_resends >= 2  # 150 ms / 50 ms
    # every state sample published was answered exactly once (but the newest, awaited),
    # by lockstep_ack before the start and its command from the first sample after it
    states = sorted(set(g.published_states))  # the resends repeat a sample
    assert len(g.published_states) - len(states) == g.sim.lockstep_resends
    answered = [s for _, s in g.answers]
    assert len(answered) == len(set(answered))
    assert answered == states[: len(answered)] and len(states) - len(answered) <= 1
    t_start_ns = round(t_start * 1e9)
    assert {s for k, s in g.answers if k == "lockstep_ack"} == {
        s for s in answered if s <= t_start_ns
    }
    assert {s for k, s in g.answers if k == "actuator_command"} == {
        s for s in answered if s > t_start_ns
    }
    # the stall cost no sim time: the physics waited at the first sample after the start
    # (one state period on), and that sample got the first command
    first_cmd = min(s for k, s in g.answers if k == "actuator_command")
    assert first_cmd - t_start_ns == 4 * MS
    assert g.sim_at_stall_end - t_start_ns == 4 * MS


def test_lockstep_start_waits_until_the_simulation_receives_the_answers():
    """The controller's start is refused (naming why) until the simulation's subscription to
    its answers matched and two answers went out since: only then does the simulation wait
    for it (real Jazzy: a start in the controller's first wake, before DDS matched the
    answers, let the simulation run on the wall clock past it)."""
    g = Graph(lockstep=True)
    g.ctl.lockstep_linked = False
    g.run_until(300 * MS)
    assert g.ctl.missing_inputs() == []
    ok, why = g.ctl.start(g.ctl_now, wait_for_inputs=True)
    assert not ok and why.startswith("lockstep: no answer received yet by the simulation")
    assert "received yet" in why  # the drivers' retry word (test_ros_phase2.py DRIVER)
    assert (
        g.ctl.status(g.ctl_now)
        .status[0]
        .message.endswith("no answer received yet by the lock-stepped simulation")
    )
    g.ctl.lockstep_linked = True
    g.run_until(304 * MS)  # one answer since
    assert not g.ctl.start(g.ctl_now, wait_for_inputs=True)[0]
    g.run_until(308 * MS)
    assert g.ctl.start(g.ctl_now, wait_for_inputs=True) == (True, "LPV control started")
