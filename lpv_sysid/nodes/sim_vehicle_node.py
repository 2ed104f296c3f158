"""sim_vehicle_node: the simulated quadrotor as a node, so the graph runs without hardware.

Shell around :class:`lpv_sysid.sim.vehicle.SimVehicle` (seed 0 Eqs. 3, 6-8, RK4) and the
PX4-like :class:`lpv_sysid.control.baseline.BaselineController`. A timer at
``state_hz`` advances the physics to the node clock in fixed ``physics_hz`` RK4 steps
(several per tick when the tick was late, so the simulation keeps real time however the
timer jitters); ``state`` (Odometry), ``imu`` and ``rotor_speeds`` are published at their
sensor rates (best effort), stamped with the *physics* time of the sample (evenly spaced,
never the jittery callback time). If the node falls more than ``max_catch_up_s`` behind
(an overloaded machine), the simulation slips: it runs slower than real time, counts the
slip (``realtime_slips_s`` on ``status``) and warns, rather than integrating a huge step. Mode
``baseline`` (phase 1): the baseline
flies ``velocity_reference``. Mode ``lpv`` (phase 2): ``actuator_command`` is applied
directly; when it is older than ``command_timeout_s`` (the controller stopped commanding
after a safety abort) the vehicle falls back to the baseline holding zero velocity, which
is what PX4 does when offboard control is handed back.

``lockstep`` (sim.launch.py): the simulation is the clock of the graph. Physics time starts
at 0 and every stamp, and ``/clock`` (published at each state sample, before the samples of
that instant), is physics time; the other nodes run on ``use_sim_time``. A steady wall clock
paces it (at most ``real_time_factor`` x real time). Once a controller answers the state
samples (an ``actuator_command`` stamped with a state instant: lpv_controller with
``tick_source: state``) every state sample waits for the command stamped with it before the
physics integrates on (and, once a ``velocity_reference`` arrives on sim time, for the
reference to be at most ``lockstep_reference_lag_s`` old: a CPU-starved excitation node slows
the simulation instead of going stale; measured at load 9 on 2 cores without this barrier: a
104 ms sim-time gap in the reference and a stale abort), so the loop has exactly the
sampling of the offline ``simulate phase2`` (command computed on the state at t_k, held over
[t_k, t_k+1)) however loaded the machine is: the wall-clock graph on 2 loaded cores had ~14 ms of
loop delay, beyond the
8-12 ms at which the demo gains go unstable. An unanswered sample is sent again every
``LOCKSTEP_RESEND_S`` (best-effort stream); after ``lockstep_timeout_s`` of wall time without
an answer the simulation runs on alone (``command_timeout_s`` later: baseline hold). Status
reports ``real_time_factor`` (sim time per wall time), resends and timeouts.

    ros2 run lpv_sysid sim_vehicle_node --ros-args --params-file config/sim_vehicle.yaml
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import Imu, JointState

from lpv_sysid.control.baseline import BaselineController, BaselineGains
from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.io import messages
from lpv_sysid.io.yaml_file import read_yaml
from lpv_sysid.models.quadrotor import Quadrotor, QuadrotorParams
from lpv_sysid.nodes import shell
from lpv_sysid.nodes import parameters
from lpv_sysid.sim.vehicle import SensorConfig, SimVehicle

NODE_NAME = "sim_vehicle"
MODES = ("baseline", "lpv")
#: lockstep: a state sample still unanswered after this much wall time is sent again (same
#: stamp and values: the state stream is best effort, one lost sample must not stall the loop)
LOCKSTEP_RESEND_S = 0.05


@dataclass(frozen=True)
class SimVehicleSettings(parameters.Settings):
    """The shell's parameters; the sensor parameters are SensorConfig's (:data:`SPECS`)."""

    WHERE = "sim_vehicle"

    mode: str = parameters.text(
        "baseline",
        "baseline: fly velocity_reference (phase 1); lpv: apply actuator_command (phase 2)",
        choices=MODES,
    )
    initial_velocity_frd: tuple = parameters.doubles(
        (0.0, 0.0, 0.0),
        "start in trim at this body velocity FRD [m/s]",
        lo=-20.0,
        hi=20.0,
        lengths=(3,),
    )
    vehicle_file: str = parameters.text(
        "", "YAML of QuadrotorParams (empty: FlameWheel-450 defaults)"
    )
    baseline_file: str = parameters.text("", "YAML of BaselineGains (empty: defaults)")
    command_timeout_s: float = parameters.double(
        0.1,
        "lpv mode: actuator_command older than this -> baseline hold (PX4 hand-back) [s]",
        0.001,
        10.0,
    )
    reference_timeout_s: float = parameters.double(
        0.5, "velocity_reference older than this -> hold zero velocity [s]", 0.001, 60.0
    )
    status_rate_hz: float = parameters.double(1.0, "status publication rate [Hz]", 0.1, 100.0)
    lockstep: bool = parameters.flag(
        False,
        "sim time: publish /clock (the physics time, from 0) and, "
        "while a controller commands, integrate past a state sample only "
        "once the actuator_command stamped with that sample arrived (the "
        "graph on use_sim_time, controller tick_source state; sim.launch.py)",
    )
    lockstep_timeout_s: float = parameters.double(
        1.0,
        "lockstep: wall time to wait for the command of "
        "a state sample before running on without it (the "
        "controller stopped; baseline hold after "
        "command_timeout_s of sim time) [s]",
        0.01,
        60.0,
    )
    lockstep_reference_lag_s: float = parameters.double(
        0.03,
        "lockstep: the physics waits at a state sample while the newest "
        "velocity_reference (once one arrives on sim time) is older than this [s]; at least one "
        "reference period plus one state period, or it waits for a sample not yet due",
        0.001,
        1.0,
    )
    real_time_factor: float = parameters.double(
        1.0,
        "lockstep: sim time runs at most this fast "
        "against wall time (slower when the controller is "
        "slower)",
        0.01,
        100.0,
    )
    max_catch_up_s: float = parameters.double(
        0.1,
        "largest lag behind the clock made up in one tick; more slips real time [s]",
        0.001,
        10.0,
    )

    def validate(self) -> None:
        if self.real_time_factor != 1.0 and not self.lockstep:
            self.fail(
                f"real_time_factor {self.real_time_factor:g} needs lockstep: without it "
                "the physics follows the node clock (real time)"
            )


#: descriptions of the parameters generated from SensorConfig (its fields: types, defaults,
#: checks)
SENSOR_DESCRIPTIONS = {
    "physics_hz": "RK4 physics rate [Hz]",
    "state_hz": "state publication rate [Hz], divides physics_hz",
    "imu_hz": "imu publication rate [Hz], divides physics_hz",
    "rotor_hz": "rotor_speeds rate [Hz], divides physics_hz",
    "pos_std": "position noise [m]",
    "att_std_deg": "attitude noise [deg]",
    "vel_std": "velocity noise [m/s]",
    "rate_std": "body-rate noise in state [rad/s]",
    "accel_std": "accelerometer noise [m/s^2]",
    "gyro_std": "gyro noise [rad/s]",
    "rotor_std": "rotor-speed noise [rad/s]",
    "vib_accel": "once-per-rev accelerometer vibration at omega_ref [m/s^2]",
    "vib_accel_blade": "blade-pass (2/rev) accelerometer vibration at omega_ref [m/s^2]",
    "vib_gyro": "gyro vibration at omega_ref [rad/s]",
    "vib_state_fraction": "share of the gyro vibration in the estimated rates",
    "omega_ref": "rotor speed of the vibration amplitudes [rad/s]",
    "seed": "noise seed",
}

SPECS = {
    **parameters.specs(SimVehicleSettings),
    **parameters.config_specs(SensorConfig, SENSOR_DESCRIPTIONS),
}
PARAMETERS = shell.spec_table(SPECS)


def _yaml_mapping(path: str, what: str) -> dict:
    if not path:
        return {}
    d = read_yaml(path, f"{what} {path}")
    if not isinstance(d, dict):
        raise ConfigError(f"{what} {path}: expected a mapping")
    return d


class SimVehicleNode(shell.ShellNode):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        own = parameters.specs(SimVehicleSettings)
        self.settings = p = SimVehicleSettings.from_dict(
            {k: v for k, v in self.params.items() if k in own}
        )
        sensors = SensorConfig.from_dict(
            {f.name: self.params[f.name] for f in fields(SensorConfig)}
        )
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
        self._max_behind = max(1, round(p.max_catch_up_s * sensors.physics_hz))
        self.xm = self.vehicle.measure_state()
        self.ref = (v0.copy(), 0.0, -np.inf)  # (v_d FRD, r_d, receive time)
        self.cmd = (None, -np.inf)  # (u, receive time)
        self.handed_back = False
        # lockstep: the physics is paced by a steady (wall) clock and is itself the time of
        # the graph; otherwise it follows the node clock (system time)
        self.lockstep = p.lockstep
        self.pace_clock = Clock(clock_type=ClockType.STEADY_TIME) if p.lockstep else None
        self.t0_ns = self._pace_ns()
        self.engaged = False  # lockstep: a controller answers the state samples
        self.awaiting = None  # lockstep: [k, wall ns, resends] of the sample waiting
        self.lockstep_timeouts = 0
        self.lockstep_resends = 0
        self.ref_engaged = False  # lockstep: a reference publisher runs on this sim time
        self._cmd_k = -1  # lockstep: the state instant the last command answered
        self._ref_stamp_ns = -1  # lockstep: stamp of the newest velocity_reference
        self._ref_lag_ns = round(p.lockstep_reference_lag_s * 1e9)
        self._published_k = -1
        self._rtf_mark = (self.t0_ns, 0)
        self.f = messages.MsgFactory.rclpy()
        self.pub_state = self.create_publisher(Odometry, "state", shell.qos_for("state"))
        self.pub_imu = self.create_publisher(Imu, "imu", shell.qos_for("imu"))
        self.pub_rot = self.create_publisher(
            JointState, "rotor_speeds", shell.qos_for("rotor_speeds")
        )
        self.pub_status = shell.StatusPublisher(self)  # status and /diagnostics
        self.create_subscription(
            TwistStamped,
            "velocity_reference",
            self.on_reference,
            shell.qos_for("velocity_reference"),
        )
        self.create_subscription(
            JointState, "actuator_command", self.on_command, shell.qos_for("actuator_command")
        )
        if p.lockstep:
            self.pub_clock = self.create_publisher(ClockMsg, "/clock", shell.QOS_RELIABLE)
        self.create_timer(1.0 / sensors.state_hz, self.on_tick, clock=self.pace_clock)
        self.create_timer(1.0 / p.status_rate_hz, self.publish_status)

    def on_reference(self, msg):
        parsed = self.parse_input("velocity_reference", messages.reference_from_twist, msg)
        if parsed is None:
            return
        self.ref = (parsed[1], parsed[2], self.physics_stamp_ns() * 1e-9)
        if not self.lockstep:
            return
        self._ref_stamp_ns = round(parsed[0] * 1e9)
        lag = self.physics_stamp_ns() - self._ref_stamp_ns
        if not self.ref_engaged and abs(lag) <= self._ref_lag_ns:
            # a reference publisher on this sim time (excitation node, use_sim_time): from
            # now on the physics never runs more than lockstep_reference_lag_s ahead of it
            self.ref_engaged = True
            self.get_logger().info(
                "lockstep: velocity_reference on sim time; the physics waits for it"
            )
        self._release()

    def on_command(self, msg):
        parsed = self.parse_input(
            "actuator_command", messages.actuator_command_from_joint_state, msg
        )
        if parsed is None:
            return
        self.cmd = (parsed[1], self.physics_stamp_ns() * 1e-9)
        if not self.lockstep:
            return
        # a command stamped with a state instant comes from a controller answering the
        # state samples (tick_source state): from now on every sample waits for its command
        t_cmd = round(parsed[0] * 1e9)
        period = self.d_state * self.dt_ns
        on_grid = abs(t_cmd - round(t_cmd / period) * period) * 2 <= self.dt_ns
        if on_grid and not self.engaged:
            self.engaged = True
            self.get_logger().info(
                "lockstep engaged: each state sample waits for its actuator_command"
            )
        if (
            self.awaiting is not None
            and abs(t_cmd - self.awaiting[0] * self.dt_ns) * 2 <= self.dt_ns
        ):
            self._cmd_k = self.awaiting[0]
        self._release()

    def _missing(self) -> list:
        """What the awaited state instant still waits for (lockstep barrier)."""
        k = self.awaiting[0]
        out = []
        if self.engaged and self._cmd_k != k:
            out.append("actuator_command")
        if self.ref_engaged and self._ref_stamp_ns < k * self.dt_ns - self._ref_lag_ns:
            out.append("velocity_reference")
        return out

    def _release(self) -> None:
        if self.awaiting is not None and not self._missing():
            self.awaiting = None
            self.on_tick()

    def _pace_ns(self) -> int:
        return self.pace_clock.now().nanoseconds if self.pace_clock is not None else self.now_ns()

    def on_tick(self):
        """Advance the physics to the pace clock (see the module docstring)."""
        elapsed = self._pace_ns() - self.t0_ns
        if self.lockstep:
            elapsed = round(elapsed * self.settings.real_time_factor)
        due = (elapsed - self.slip_ns) // self.dt_ns
        behind = due - self.k
        if behind > self._max_behind:
            self.slip_ns += (behind - self._max_behind) * self.dt_ns
            if not self.lockstep:  # lockstep: waiting for the graph is the design
                self.get_logger().warning(
                    f"simulation {behind * self.dt_ns * 1e-9:.3f} s behind the "
                    f"clock: slipping real time (total {self.slip_ns * 1e-9:.3f} s)",
                    throttle_duration_sec=5.0,
                )
            behind = self._max_behind
        until = self.k + int(behind)
        while self.k < until:
            if self.awaiting is not None and not self._wait_over():
                return
            self.on_physics()

    def _wait_over(self) -> bool:
        """Whether the awaited instant may be integrated past: everything arrived, or the
        wait timed out (the missing party is then no longer waited for)."""
        missing = self._missing()
        if not missing:
            self.awaiting = None
            return True
        waited = self._pace_ns() - self.awaiting[1]
        if waited <= self.settings.lockstep_timeout_s * 1e9:
            if (
                "actuator_command" in missing
                and waited >= (self.awaiting[2] + 1) * LOCKSTEP_RESEND_S * 1e9
            ):
                self.awaiting[2] += 1
                self.lockstep_resends += 1
                self._publish_state(self.physics_stamp_ns())
            return False
        self.awaiting = None
        self.engaged = self.engaged and "actuator_command" not in missing
        self.ref_engaged = self.ref_engaged and "velocity_reference" not in missing
        self.lockstep_timeouts += 1
        self.get_logger().warning(
            f"lockstep: no {' / '.join(missing)} for the state at "
            f"t={self.k * self.dt_ns * 1e-9:.3f} s within {self.settings.lockstep_timeout_s:g} s "
            "of wall time: running on without it"
        )
        return True

    def physics_stamp_ns(self) -> int:
        """The physics time of step ``k``: sim time from 0 (lockstep) or the node clock at
        start plus the slip (real time)."""
        if self.lockstep:
            return self.k * self.dt_ns
        return self.t0_ns + self.slip_ns + self.k * self.dt_ns

    def on_physics(self):
        """Step ``k``: publish the samples due at it (once), in lockstep wait there for the
        command of a state sample, then hold the command over one RK4 step."""
        veh, k = self.vehicle, self.k
        stamp = self.physics_stamp_ns()
        now = stamp * 1e-9
        if self._published_k != k:
            self._published_k = k
            self._publish_samples(k, stamp)
            if (self.engaged or self.ref_engaged) and k % self.d_state == 0:
                self.awaiting = [k, self._pace_ns(), 0]
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

    def _publish_samples(self, k: int, stamp: int) -> None:
        veh = self.vehicle
        if self.lockstep and k % self.d_state == 0:
            # the clock first: a sample then never arrives ahead of its instant's /clock
            self.pub_clock.publish(
                self.f("rosgraph_msgs/msg/Clock", clock=messages.time_msg(self.f, stamp))
            )
        if k % self.d_state == 0:
            self.xm = veh.measure_state()
            self._publish_state(stamp)
        if k % self.d_imu == 0:
            a, w = veh.measure_imu()
            self.pub_imu.publish(messages.imu_msg(self.f, stamp, a, w))
        if k % self.d_rot == 0:
            self.pub_rot.publish(messages.rotor_speeds_msg(self.f, stamp, veh.measure_rotors()))

    def _publish_state(self, stamp: int) -> None:
        x = self.xm
        self.pub_state.publish(
            messages.odometry_from_state(self.f, stamp, x[0:3], x[3:6], x[6:9], x[9:12])
        )

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
                self.get_logger().warning("actuator_command stale: baseline holds (hand-back)")
            return self.baseline.step(now, rigid_body_state, (0.0, 0.0, 0.0), 0.0).tolist()
        v, r, t_rx = self.ref
        if now - t_rx > self.settings.reference_timeout_s and np.isfinite(t_rx):
            v, r = np.zeros(3), 0.0
        return self.baseline.step(now, rigid_body_state, tuple(v), r).tolist()

    def publish_status(self):
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
            wall, k = self._pace_ns(), self.k
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
            self.f,
            "WARN" if self.handed_back else "OK",
            self.get_fully_qualified_name(),
            message,
            values,
        )
        self.pub_status.publish(
            messages.diagnostic_array(
                self.f, self.physics_stamp_ns() if self.lockstep else self.now_ns(), [st]
            )
        )


def main(args=None):
    return shell.run(SimVehicleNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
