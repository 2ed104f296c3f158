"""Message-level behaviour of sim_vehicle_node: physics pacing, lock-step, samples, status.

No rclpy here: the node shell (:mod:`lpv_sysid.nodes.sim_vehicle_node`) reads its clocks and
forwards parsed inputs and timer ticks to :class:`SimVehicleRuntime`, which returns the
``(topic, message)`` pairs to publish, in order (messages built by a
:class:`~lpv_sysid.io.messages.MsgFactory`). Its parameters are declared once, in
:mod:`lpv_sysid.sim.vehicle_node.settings`.

The simulated quadrotor is :class:`lpv_sysid.sim.vehicle.SimVehicle` (seed 0 Eqs. 3, 6-8,
RK4) with the PX4-like :class:`lpv_sysid.control.baseline.BaselineController`. Each tick
(the node's ``state_hz`` timer) advances the physics to the pace clock in fixed
``physics_hz`` RK4 steps (several per tick when the tick was late, so the simulation keeps
real time however the timer jitters); ``state`` (Odometry), ``imu`` and ``rotor_speeds`` are
published at their sensor rates, stamped with the *physics* time of the sample (evenly
spaced, never the jittery callback time). If the simulation falls more than
``max_catch_up_s`` behind (an overloaded machine), it slips: it runs slower than real time,
counts the slip (``realtime_slips_s`` on ``status``) and warns (at most once per
:data:`SLIP_LOG_PERIOD_S`), rather than integrating a huge step. Mode ``baseline`` (phase 1):
the baseline flies ``velocity_reference``. Mode ``lpv`` (phase 2): ``actuator_command`` is
applied directly; when it is older than ``command_timeout_s`` (the controller stopped
commanding after a safety abort) the vehicle falls back to the baseline holding zero
velocity, which is what PX4 does when offboard control is handed back.

``lockstep`` (sim.launch.py): the simulation is the clock of the graph. Physics time starts
at 0 and every stamp, and ``/clock`` (published at each state sample, before the samples of
that instant), is physics time; the other nodes run on ``use_sim_time``. A steady wall clock
paces it (at most ``real_time_factor`` x real time). Once a controller answers the state
samples (an ``actuator_command`` stamped with a state instant: lpv_controller with
``tick_source: state``; with its ``lockstep`` also a ``lockstep_ack`` stamped with the sample
while it sends no command, i.e. from its first sample on, started or not) every state sample
waits for the answer stamped with it before the physics integrates on (and, once a
``velocity_reference`` arrives on sim time, for the reference to be at most
``lockstep_reference_lag_s`` old: a CPU-starved excitation node slows the simulation instead
of going stale; measured at load 9 on 2 cores without this barrier: a 104 ms sim-time gap in
the reference and a stale abort), so the loop has exactly the sampling of the offline
``simulate phase2`` (command computed on the state at t_k, held over [t_k, t_k+1)) however
loaded the machine is: the wall-clock graph on 2 loaded cores had a p99 state-to-command
delay of 23 ms (bench_node_rclpy, load 8-11), beyond the demo gains' certified loop delay
(certificate.loop_delay.bound_s, 17.7 ms). A controller that answers with commands only
engages the barrier at its first command: until then the physics runs on the wall clock, and
a controller descheduled between its start and that command sees its clock jump past its
start (measured at load 12-25 on 2 cores, test_ros_phase2.py: "stale: rotor_speeds: no
message for 0.064 s since arming", or a state stamp ahead of its clock); lpv_controller's
``lockstep`` answers from its first sample and closes that window
(test/test_lockstep_graph.py). An unanswered sample is sent again every
:data:`LOCKSTEP_RESEND_S` (best-effort stream); after ``lockstep_timeout_s`` of wall time
without an answer the simulation runs on alone (``command_timeout_s`` later: baseline hold).
Status reports ``real_time_factor`` (sim time per wall time), resends and timeouts.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any, Callable, Optional

import numpy as np

from lpv_sysid.control.baseline import BaselineController, BaselineGains
from lpv_sysid.errors import LpvSysidError
from lpv_sysid.io import messages
from lpv_sysid.io.files import read_yaml_mapping
from lpv_sysid.models.quadrotor import Quadrotor, QuadrotorParams
from lpv_sysid.sim.vehicle import SensorConfig, SimVehicle
from lpv_sysid.sim.vehicle_node.settings import SimVehicleSettings

_LOG = logging.getLogger(__name__)

#: lockstep: a state sample still unanswered after this much wall time is sent again (same
#: stamp and values: the state stream is best effort, one lost sample must not stall the loop)
LOCKSTEP_RESEND_S = 0.05
#: lockstep: what a state sample waits for from the controller (its command or its ack)
ANSWER = "actuator_command or lockstep_ack"
#: at most one "slipping real time" warning in this period of the pace clock [s]
SLIP_LOG_PERIOD_S = 5.0

#: ``(topic, message)`` pairs to publish, in order (topics: clock, state, imu, rotor_speeds,
#: status)
Outputs = list[tuple[str, Any]]


def _yaml_mapping(path: str, what: str) -> dict:
    if not path:
        return {}
    return read_yaml_mapping(path, f"{what} {path}")


def _python_log(level: str, text: str) -> None:
    _LOG.log({"error": logging.ERROR, "warn": logging.WARNING}.get(level, logging.INFO), text)


class SimVehicleRuntime:
    """See module docstring. Every time argument ``pace_ns`` is the pace clock: the steady
    (wall) clock in lockstep, else the node clock; ``t0_ns`` is its reading at start.
    ``log(level, text)`` (level ``info``, ``warn`` or ``error``) receives the log lines."""

    def __init__(
        self,
        settings: SimVehicleSettings,
        sensors: SensorConfig,
        factory: messages.MsgFactory,
        name: str = "/lpv_sysid/sim_vehicle",
        t0_ns: int = 0,
        log: Optional[Callable[[str, str], None]] = None,
    ):
        self.settings = p = settings
        self.name = name
        self.log = log or _python_log
        vehicle = _yaml_mapping(p.vehicle_file, "vehicle_file")
        model = Quadrotor(QuadrotorParams.from_dict(vehicle) if vehicle else None)
        gains = BaselineGains.from_dict(_yaml_mapping(p.baseline_file, "baseline_file"))
        gains = replace(gains, arm_length=model.params.arm_length)
        v0 = np.asarray(p.initial_velocity_frd, dtype=float)
        trim = model.trim(v0)
        self.vehicle = SimVehicle(model, sensors, trim.full_state)
        self.vehicle.u = trim.u0.tolist()
        self.baseline = BaselineController(gains)
        self.baseline.warm_start(trim.x0, trim.u0, v0)
        self.u = trim.u0.tolist()
        self.d_state = sensors.decimation(sensors.state_hz)
        self.d_imu = sensors.decimation(sensors.imu_hz)
        self.d_rot = sensors.decimation(sensors.rotor_hz)
        self.d_ctrl = sensors.decimation(gains.rate_hz)
        self.k = 0
        self.dt_ns = round(1e9 / sensors.physics_hz)
        self.slip_ns = 0
        self._slip_logged_ns: Optional[int] = None
        self._max_behind = max(1, round(p.max_catch_up_s * sensors.physics_hz))
        self.xm = self.vehicle.measure_state()
        self.ref = (v0.copy(), 0.0, -np.inf)  # (v_d FRD, r_d, receive time)
        self.cmd: tuple[Any, float] = (None, -np.inf)  # (u, receive time)
        self.handed_back = False
        self.lockstep = p.lockstep
        self.t0_ns = t0_ns
        self.engaged = False  # lockstep: a controller answers the state samples
        self.awaiting: Optional[list] = None  # lockstep: [k, pace ns, resends] of the sample
        self.lockstep_timeouts = 0
        self.lockstep_resends = 0
        self.ref_engaged = False  # lockstep: a reference publisher runs on this sim time
        self._cmd_k = -1  # lockstep: the state instant the last command answered
        self._ref_stamp_ns = -1  # lockstep: stamp of the newest velocity_reference
        self._ref_lag_ns = round(p.lockstep_reference_lag_s * 1e9)
        self._published_k = -1
        self._rtf_mark = (t0_ns, 0)
        self.f = factory

    # -- inputs ---------------------------------------------------------------------------
    def on_reference(self, stamp_s: float, v, r: float, pace_ns: int) -> Outputs:
        """A parsed ``velocity_reference`` (stamp, v_d FRD, r_d)."""
        out: Outputs = []
        self.ref = (v, r, self.physics_stamp_ns() * 1e-9)
        if not self.lockstep:
            return out
        self._ref_stamp_ns = round(stamp_s * 1e9)
        lag = self.physics_stamp_ns() - self._ref_stamp_ns
        if not self.ref_engaged and abs(lag) <= self._ref_lag_ns:
            # a reference publisher on this sim time (excitation node, use_sim_time): from
            # now on the physics never runs more than lockstep_reference_lag_s ahead of it
            self.ref_engaged = True
            self.log("info", "lockstep: velocity_reference on sim time; the physics waits for it")
        self._release(pace_ns, out)
        return out

    def on_command(self, stamp_s: float, u, pace_ns: int) -> Outputs:
        """A parsed ``actuator_command`` (stamp, u): applied, and in lockstep the answer to
        the state sample it is stamped with."""
        self.cmd = (u, self.physics_stamp_ns() * 1e-9)
        return self.on_answer(stamp_s, pace_ns)

    def on_answer(self, stamp_s: float, pace_ns: int) -> Outputs:
        """Lockstep: the controller answered the state sample stamped ``stamp_s`` -- with its
        ``actuator_command`` (:meth:`on_command`) or, while it sends none (not started,
        aborted), on ``lockstep_ack``. An answer stamped with a state instant comes from a
        controller answering the state samples (``tick_source: state``): from then on every
        sample waits for its answer. The controller's ``lockstep`` answers from its first
        sample, so the physics never runs ahead of it, neither before its start nor between
        its start and its first command (measured before: the simulation ran on the wall
        clock until that first command, and a controller descheduled there for 60+ ms of a
        loaded machine saw /clock jump past its start and aborted stale)."""
        out: Outputs = []
        if not self.lockstep:
            return out
        t_cmd = round(stamp_s * 1e9)
        period = self.d_state * self.dt_ns
        on_grid = abs(t_cmd - round(t_cmd / period) * period) * 2 <= self.dt_ns
        if on_grid and not self.engaged:
            self.engaged = True
            self.log(
                "info", "lockstep engaged: each state sample waits for the controller's answer"
            )
        if (
            self.awaiting is not None
            and abs(t_cmd - self.awaiting[0] * self.dt_ns) * 2 <= self.dt_ns
        ):
            self._cmd_k = self.awaiting[0]
        self._release(pace_ns, out)
        return out

    # -- lock-step barrier ----------------------------------------------------------------
    def _missing(self) -> list:
        """What the awaited state instant still waits for (lockstep barrier)."""
        assert self.awaiting is not None
        k = self.awaiting[0]
        out = []
        if self.engaged and self._cmd_k != k:
            out.append(ANSWER)
        if self.ref_engaged and self._ref_stamp_ns < k * self.dt_ns - self._ref_lag_ns:
            out.append("velocity_reference")
        return out

    def _release(self, pace_ns: int, out: Outputs) -> None:
        if self.awaiting is not None and not self._missing():
            self.awaiting = None
            self._advance(pace_ns, out)

    def _wait_over(self, pace_ns: int, out: Outputs) -> bool:
        """Whether the awaited instant may be integrated past: everything arrived, or the
        wait timed out (the missing party is then no longer waited for)."""
        assert self.awaiting is not None
        missing = self._missing()
        if not missing:
            self.awaiting = None
            return True
        waited = pace_ns - self.awaiting[1]
        if waited <= self.settings.lockstep_timeout_s * 1e9:
            if ANSWER in missing and waited >= (self.awaiting[2] + 1) * LOCKSTEP_RESEND_S * 1e9:
                self.awaiting[2] += 1
                self.lockstep_resends += 1
                out.append(("state", self._state_msg(self.physics_stamp_ns())))
            return False
        self.awaiting = None
        self.engaged = self.engaged and ANSWER not in missing
        self.ref_engaged = self.ref_engaged and "velocity_reference" not in missing
        self.lockstep_timeouts += 1
        self.log(
            "warn",
            f"lockstep: no {' / '.join(missing)} for the state at "
            f"t={self.k * self.dt_ns * 1e-9:.3f} s within {self.settings.lockstep_timeout_s:g} s "
            "of wall time: running on without it",
        )
        return True

    # -- physics --------------------------------------------------------------------------
    def on_tick(self, pace_ns: int) -> Outputs:
        """Advance the physics to the pace clock (see the module docstring)."""
        out: Outputs = []
        self._advance(pace_ns, out)
        return out

    def _advance(self, pace_ns: int, out: Outputs) -> None:
        elapsed = pace_ns - self.t0_ns
        if self.lockstep:
            elapsed = round(elapsed * self.settings.real_time_factor)
        due = (elapsed - self.slip_ns) // self.dt_ns
        behind = due - self.k
        if behind > self._max_behind:
            self.slip_ns += (behind - self._max_behind) * self.dt_ns
            if not self.lockstep:  # lockstep: waiting for the graph is the design
                self._warn_slip(behind, pace_ns)
            behind = self._max_behind
        until = self.k + int(behind)
        while self.k < until:
            if self.awaiting is not None and not self._wait_over(pace_ns, out):
                return
            self._physics(pace_ns, out)

    def _warn_slip(self, behind: int, pace_ns: int) -> None:
        last = self._slip_logged_ns
        if last is not None and pace_ns - last < SLIP_LOG_PERIOD_S * 1e9:
            return
        self._slip_logged_ns = pace_ns
        self.log(
            "warn",
            f"simulation {behind * self.dt_ns * 1e-9:.3f} s behind the "
            f"clock: slipping real time (total {self.slip_ns * 1e-9:.3f} s)",
        )

    def physics_stamp_ns(self) -> int:
        """The physics time of step ``k``: sim time from 0 (lockstep) or the node clock at
        start plus the slip (real time)."""
        if self.lockstep:
            return self.k * self.dt_ns
        return self.t0_ns + self.slip_ns + self.k * self.dt_ns

    def _physics(self, pace_ns: int, out: Outputs) -> None:
        """Step ``k``: publish the samples due at it (once), in lockstep wait there for the
        command of a state sample, then hold the command over one RK4 step."""
        veh, k = self.vehicle, self.k
        stamp = self.physics_stamp_ns()
        now = stamp * 1e-9
        if self._published_k != k:
            self._published_k = k
            self._samples(k, stamp, out)
            if (self.engaged or self.ref_engaged) and k % self.d_state == 0:
                self.awaiting = [k, pace_ns, 0]
                if self._missing():
                    return
                self.awaiting = None
        if k % self.d_ctrl == 0:
            self.u = self._command(now)
        try:
            veh.step(self.u)
        except FloatingPointError as exc:
            raise LpvSysidError(f"sim_vehicle: {exc}") from None
        self.k += 1

    def _samples(self, k: int, stamp: int, out: Outputs) -> None:
        veh, f = self.vehicle, self.f
        if self.lockstep and k % self.d_state == 0:
            # the clock first: a sample then never arrives ahead of its instant's /clock
            out.append(("clock", messages.clock_msg(f, stamp)))
        if k % self.d_state == 0:
            self.xm = veh.measure_state()
            out.append(("state", self._state_msg(stamp)))
        if k % self.d_imu == 0:
            a, w = veh.measure_imu()
            out.append(("imu", messages.imu_msg(f, stamp, a, w)))
        if k % self.d_rot == 0:
            out.append(("rotor_speeds", messages.rotor_speeds_msg(f, stamp, veh.measure_rotors())))

    def _state_msg(self, stamp: int):
        x = self.xm
        return messages.odometry_from_state(self.f, stamp, x[0:3], x[3:6], x[6:9], x[9:12])

    def _command(self, now: float):
        xm = self.xm
        # phi, theta, u, v, w, p, q, r of the measured FULL_STATE_NAMES sample
        rigid_body_state = (xm[3], xm[4], xm[6], xm[7], xm[8], xm[9], xm[10], xm[11])
        if self.settings.mode == "lpv":
            u, t_rx = self.cmd
            if u is not None and now - t_rx <= self.settings.command_timeout_s:
                self.handed_back = False
                return list(u)
            if u is not None and not self.handed_back:
                self.handed_back = True
                self.log("warn", "actuator_command stale: baseline holds (hand-back)")
            return self.baseline.step(now, rigid_body_state, (0.0, 0.0, 0.0), 0.0).tolist()
        v, r, t_rx = self.ref
        if now - t_rx > self.settings.reference_timeout_s and np.isfinite(t_rx):
            v, r = np.zeros(3), 0.0
        return self.baseline.step(now, rigid_body_state, tuple(v), r).tolist()

    # -- status ---------------------------------------------------------------------------
    def status(self, pace_ns: int):
        """The ``status`` DiagnosticArray (stamped with physics time in lockstep, else the
        node clock ``pace_ns``); lockstep: the real-time factor since the previous status."""
        x = self.vehicle.x
        values = {
            "mode": self.settings.mode,
            "t_sim": round(self.vehicle.t, 6),
            "u": float(x[6]),
            "v": float(x[7]),
            "w": float(x[8]),
            "handed_back": self.handed_back,
            "realtime_slips_s": round(self.slip_ns * 1e-9, 6),
        }
        if self.lockstep:
            wall, k = pace_ns, self.k
            w0, k0 = self._rtf_mark
            self._rtf_mark = (wall, k)
            values.update(
                lockstep_engaged=self.engaged,
                lockstep_timeouts=self.lockstep_timeouts,
                lockstep_resends=self.lockstep_resends,
                lockstep_reference=self.ref_engaged,
                real_time_factor=round((k - k0) * self.dt_ns / max(wall - w0, 1), 4),
            )
        message = "baseline hold" if self.handed_back else self.settings.mode
        st = messages.diagnostic_status(
            self.f, "WARN" if self.handed_back else "OK", self.name, message, values
        )
        stamp = self.physics_stamp_ns() if self.lockstep else pace_ns
        return messages.diagnostic_array(self.f, stamp, [st])
