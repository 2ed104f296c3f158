"""A simulated quadrotor that speaks MAVLink 2 like PX4 SITL (v1.16 behaviour subset), so the
bridge, the campaign and ``lpv-sysid fly`` run against a real protocol peer on loopback.

Parts: the vehicle and its routing (:mod:`~lpv_sysid.sim.px4_vehicle.vehicle`), its options
and PX4 tables (:mod:`~lpv_sysid.sim.px4_vehicle.config`), PX4's commander (arming, modes,
failsafes; :mod:`~lpv_sysid.sim.px4_vehicle.commander`), the parameter protocol
(:mod:`~lpv_sysid.sim.px4_vehicle.params`), the physics (the seed 0 quadrotor under the
PX4-like cascade; :mod:`~lpv_sysid.sim.px4_vehicle.physics`), offboard setpoints
(:mod:`~lpv_sysid.sim.px4_vehicle.setpoints`), its state
(:mod:`~lpv_sysid.sim.px4_vehicle.state`) and telemetry at PX4's onboard-link rates
(:mod:`~lpv_sysid.sim.px4_vehicle.telemetry`).
"""

from __future__ import annotations

from lpv_sysid.sim.px4_vehicle.config import DEFAULT_RATES, PARAMS, SimVehicleConfig
from lpv_sysid.sim.px4_vehicle.vehicle import SimVehicle

__all__ = [
    "DEFAULT_RATES",
    "PARAMS",
    "SimVehicle",
    "SimVehicleConfig",
]
