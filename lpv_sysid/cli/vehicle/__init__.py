"""Commands that talk to a vehicle over MAVLink: ``fly``, ``chain``, ``preflight``, and
``sim-vehicle`` (the package's simulated PX4 on loopback).
"""

from __future__ import annotations

from lpv_sysid.cli.vehicle.fly import parse_params

__all__ = [
    "parse_params",
]
