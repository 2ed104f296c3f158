"""The parameters of sim_vehicle_node (:class:`SimVehicleSettings`) and its sensors
(:class:`~lpv_sysid.sim.vehicle.SensorConfig`): the one declaration of every key of
config/sim_vehicle.yaml (:data:`SPECS`; the rclpy declarations are generated from it,
:mod:`lpv_sysid.configuration.parameters`). No rclpy here.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from lpv_sysid.configuration import parameters
from lpv_sysid.sim.vehicle import SensorConfig

MODES = ("baseline", "lpv")


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
        "once a controller answers the state samples, integrate past a state sample only "
        "once its answer arrived: the actuator_command stamped with it, or lockstep_ack "
        "while the controller sends no command (the graph on use_sim_time, controller "
        "tick_source state and lockstep; sim.launch.py)",
    )
    lockstep_timeout_s: float = parameters.double(
        1.0,
        "lockstep: wall time to wait for the answer to "
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
    publish_tf: bool = parameters.flag(
        False, "publish odom -> base_link on /tf from the state (REP-105; RViz, Foxglove)"
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

#: every parameter of the node: ``{name: (default, ParamSpec)}``
SPECS = {
    **parameters.specs(SimVehicleSettings),
    **parameters.config_specs(SensorConfig, SENSOR_DESCRIPTIONS),
}


def settings_from_params(values: dict) -> tuple[SimVehicleSettings, SensorConfig]:
    """The node's settings and sensor configuration from its ``{parameter: value}``."""
    own = parameters.specs(SimVehicleSettings)
    settings = SimVehicleSettings.from_dict({k: v for k, v in values.items() if k in own})
    return settings, SensorConfig.from_dict({f.name: values[f.name] for f in fields(SensorConfig)})
