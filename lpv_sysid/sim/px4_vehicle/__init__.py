"""TODO face"""

from __future__ import annotations

from lpv_sysid.sim.px4_vehicle.config import DEFAULT_RATES, PARAMS, SimVehicleConfig
from lpv_sysid.sim.px4_vehicle.vehicle import SimVehicle

__all__ = [
    "DEFAULT_RATES",
    "PARAMS",
    "SimVehicle",
    "SimVehicleConfig",
]
