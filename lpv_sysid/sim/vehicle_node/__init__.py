"""TODO face"""

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
