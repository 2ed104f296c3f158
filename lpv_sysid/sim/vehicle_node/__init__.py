"""What ``sim_vehicle_node`` does, without rclpy: the simulated quadrotor paced to the
clock (or lock-stepped to the controller's commands), its sensors and samples as messages,
its status (:class:`SimVehicleRuntime`, :mod:`~lpv_sysid.sim.vehicle_node.runtime`), and the
node's parameters, declared once (:class:`SimVehicleSettings`,
:mod:`~lpv_sysid.sim.vehicle_node.settings`).
"""

from __future__ import annotations

from lpv_sysid.sim.vehicle_node.runtime import (
    LOCKSTEP_RESEND_S,
    SLIP_LOG_PERIOD_S,
    SimVehicleRuntime,
)
from lpv_sysid.sim.vehicle_node.settings import SPECS, SimVehicleSettings, settings_from_params

__all__ = [
    "LOCKSTEP_RESEND_S",
    "SLIP_LOG_PERIOD_S",
    "SPECS",
    "SimVehicleRuntime",
    "SimVehicleSettings",
    "settings_from_params",
]
