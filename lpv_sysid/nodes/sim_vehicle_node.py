"""sim_vehicle_node: the simulated quadrotor as a node, so the graph runs without hardware.

Shell around :class:`lpv_sysid.sim.vehicle.SimVehicle` (seed 0 Eqs. 3, 6-8, RK4) and the
PX4-like :class:`lpv_sysid.control.baseline.BaselineController`. A timer at
``state_hz`` advances the physics to the node clock in fixed ``physics_hz`` RK4 steps
(several per tick when the tick was late, so the simulation keeps real time however the
timer jitters); ``state`` (Odometry), ``imu`` and ``rotor_speeds`` are published at their
sensor rates (best effort), stamped with the *physics* time of the sample (evenly spaced,
never the jittery callback time). If the node falls more than ``max_catch_up_s`` behind
(an overloaded machine), the simulation slips: it runs slower than real time, counts the
slip (``realtime_slips_s`` on ``status``) and warns, rather than integrating a huge step. Mode ``baseline`` (phase 1): the baseline
flies ``velocity_reference``. Mode ``lpv`` (phase 2): ``actuator_command`` is applied
directly; when it is older than ``command_timeout_s`` (the controller stopped commanding
after a safety abort) the vehicle falls back to the baseline holding zero velocity, which
is what PX4 does when offboard control is handed back.

    ros2 run lpv_sysid sim_vehicle_node --ros-args --params-file config/sim_vehicle.yaml
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, JointState

from lpv_sysid.control.baseline import BaselineController, BaselineGains
from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.io import messages as M
from lpv_sysid.io.yaml_file import read_yaml
from lpv_sysid.models.quadrotor import Quadrotor, QuadrotorParams
from lpv_sysid.nodes import _common as C
from lpv_sysid.sim.vehicle import SensorConfig, SimVehicle

NODE_NAME = "sim_vehicle"
MODES = ("baseline", "lpv")

PARAMETERS = [
    ("mode", "baseline", C.typed(Parameter.Type.STRING,
                                 "baseline: fly velocity_reference (phase 1); "
                                 "lpv: apply actuator_command (phase 2)")),
    ("physics_hz", 500.0, C.double("RK4 physics rate [Hz]", 50.0, 5000.0)),
    ("state_hz", 250.0, C.double("state publication rate [Hz], divides physics_hz",
                                 1.0, 5000.0)),
    ("imu_hz", 250.0, C.double("imu publication rate [Hz], divides physics_hz", 1.0, 5000.0)),
    ("rotor_hz", 100.0, C.double("rotor_speeds rate [Hz], divides physics_hz", 1.0, 5000.0)),
    ("seed", 0, C.integer("noise seed", 0, 2**31 - 1)),
    ("initial_velocity_frd", [0.0, 0.0, 0.0], C.typed(
        Parameter.Type.DOUBLE_ARRAY, "start in trim at this body velocity FRD [m/s]")),
    ("vehicle_file", "", C.typed(Parameter.Type.STRING,
                                 "YAML of QuadrotorParams (empty: FlameWheel-450 defaults)")),
    ("baseline_file", "", C.typed(Parameter.Type.STRING,
                                  "YAML of BaselineGains (empty: defaults)")),
    ("command_timeout_s", 0.1, C.double("lpv mode: actuator_command older than this -> "
                                        "baseline hold (PX4 hand-back) [s]", 0.001, 10.0)),
    ("reference_timeout_s", 0.5, C.double("velocity_reference older than this -> hold zero "
                                          "velocity [s]", 0.001, 60.0)),
    ("status_rate_hz", 1.0, C.double("status publication rate [Hz]", 0.1, 100.0)),
    ("max_catch_up_s", 0.1, C.double("largest lag behind the clock made up in one tick; "
                                     "more slips real time [s]", 0.001, 10.0)),
]


def _yaml_mapping(path: str, what: str) -> dict:
    if not path:
        return {}
    d = read_yaml(path, f"{what} {path}")
    if not isinstance(d, dict):
        raise ConfigError(f"{what} {path}: expected a mapping")
    return d


class SimVehicleNode(C.ShellNode):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        p = self.params
        if p["mode"] not in MODES:
            raise LpvSysidError(f"parameter 'mode' must be one of {MODES}, got {p['mode']!r}")
        vehicle = _yaml_mapping(p["vehicle_file"], "vehicle_file")
        model = Quadrotor(QuadrotorParams.from_dict(vehicle) if vehicle else None)
        sensors = SensorConfig(physics_hz=p["physics_hz"], state_hz=p["state_hz"],
                               imu_hz=p["imu_hz"], rotor_hz=p["rotor_hz"], seed=p["seed"])
        gains = BaselineGains.from_dict(_yaml_mapping(p["baseline_file"], "baseline_file"))
        gains = replace(gains, arm_length=model.params.arm_length)
        v0 = np.asarray(p["initial_velocity_frd"], dtype=float)
        if v0.shape != (3,):
            raise LpvSysidError(f"parameter 'initial_velocity_frd' needs 3 values, got {list(v0)}")
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
        self._max_behind = max(1, round(p["max_catch_up_s"] * sensors.physics_hz))
        self.xm = self.vehicle.measure_state()
        self.ref = (v0.copy(), 0.0, -np.inf)          # (v_d FRD, r_d, receive time)
        self.cmd = (None, -np.inf)                    # (u, receive time)
        self.handed_back = False
        self.t0_ns = self.now_ns()
        self.f = M.MsgFactory.rclpy()
        self.pub_state = self.create_publisher(Odometry, "state", C.qos_for("state"))
        self.pub_imu = self.create_publisher(Imu, "imu", C.qos_for("imu"))
        self.pub_rot = self.create_publisher(JointState, "rotor_speeds", C.qos_for("rotor_speeds"))
        self.pub_status = self.create_publisher(DiagnosticArray, "status", C.qos_for("status"))
        self.create_subscription(TwistStamped, "velocity_reference", self.on_reference,
                                 C.qos_for("velocity_reference"))
        self.create_subscription(JointState, "actuator_command", self.on_command,
                                 C.qos_for("actuator_command"))
        self.create_timer(1.0 / sensors.state_hz, self.on_tick)
        self.create_timer(1.0 / p["status_rate_hz"], self.publish_status)

    def on_reference(self, msg):
        parsed = self.parse_input("velocity_reference", M.reference_from_twist, msg)
        if parsed is not None:
            self.ref = (parsed[1], parsed[2], self.physics_stamp_ns() * 1e-9)

    def on_command(self, msg):
        parsed = self.parse_input("actuator_command", M.actuator_command_from_joint_state, msg)
        if parsed is not None:
            self.cmd = (parsed[1], self.physics_stamp_ns() * 1e-9)

    def on_tick(self):
        """Advance the physics to the node clock (see the module docstring)."""
        due = (self.now_ns() - self.t0_ns - self.slip_ns) // self.dt_ns
        behind = due - self.k
        if behind > self._max_behind:
            self.slip_ns += (behind - self._max_behind) * self.dt_ns
            self.get_logger().warning(
                f"simulation {behind * self.dt_ns * 1e-9:.3f} s behind the "
                f"clock: slipping real time (total {self.slip_ns * 1e-9:.3f} s)",
                throttle_duration_sec=5.0)
            behind = self._max_behind
        for _ in range(int(behind)):
            self.on_physics()

    def physics_stamp_ns(self) -> int:
        return self.t0_ns + self.slip_ns + self.k * self.dt_ns

    def on_physics(self):
        veh, k = self.vehicle, self.k
        stamp = self.physics_stamp_ns()
        now = stamp * 1e-9
        if k % self.d_state == 0:
            self.xm = veh.measure_state()
            x = self.xm
            self.pub_state.publish(M.odometry_from_state(self.f, stamp, x[0:3], x[3:6], x[6:9],
                                                         x[9:12]))
        if k % self.d_imu == 0:
            a, w = veh.measure_imu()
            self.pub_imu.publish(M.imu_msg(self.f, stamp, a, w))
        if k % self.d_rot == 0:
            self.pub_rot.publish(M.rotor_speeds_msg(self.f, stamp, veh.measure_rotors()))
        if k % self.d_ctrl == 0:
            self.u = self._command(now)
        try:
            veh.step(self.u)
        except FloatingPointError as exc:
            raise LpvSysidError(f"sim_vehicle: {exc}") from None
        self.k += 1

    def _command(self, now: float):
        xm = self.xm
        x8 = (xm[3], xm[4], xm[6], xm[7], xm[8], xm[9], xm[10], xm[11])
        if self.params["mode"] == "lpv":
            u, t_rx = self.cmd
            if u is not None and now - t_rx <= self.params["command_timeout_s"]:
                self.handed_back = False
                return list(u)
            if u is not None and not self.handed_back:
                self.handed_back = True
                self.get_logger().warning("actuator_command stale: baseline holds (hand-back)")
            return self.baseline.step(now, x8, (0.0, 0.0, 0.0), 0.0).tolist()
        v, r, t_rx = self.ref
        if now - t_rx > self.params["reference_timeout_s"] and np.isfinite(t_rx):
            v, r = np.zeros(3), 0.0
        return self.baseline.step(now, x8, tuple(v), r).tolist()

    def publish_status(self):
        x = self.vehicle.x
        values = {"mode": self.params["mode"], "t_sim": round(self.vehicle.t, 6),
                  "u": float(x[6]), "v": float(x[7]), "w": float(x[8]),
                  "handed_back": self.handed_back,
                  "realtime_slips_s": round(self.slip_ns * 1e-9, 6)}
        message = "baseline hold" if self.handed_back else self.params["mode"]
        st = M.diagnostic_status(self.f, "WARN" if self.handed_back else "OK",
                                 self.get_fully_qualified_name(), message, values)
        self.pub_status.publish(M.diagnostic_array(
            self.f, self.now_ns(), [st]))


def main(args=None):
    return C.run(SimVehicleNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
