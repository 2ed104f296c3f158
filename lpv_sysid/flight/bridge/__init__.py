"""What ``mavlink_bridge_node`` does, without rclpy: ROS messages <-> the bridge core
(:mod:`lpv_sysid.mavlink.bridge`) over MAVLink or MAVROS (:class:`BridgeRuntime`,
:mod:`~lpv_sysid.flight.bridge.runtime`), and the node's parameters, declared once
(:mod:`~lpv_sysid.flight.bridge.settings`, with the hand-back time bound the launch files
give the node before it is stopped).
"""

from __future__ import annotations

from lpv_sysid.flight.bridge.runtime import PARSERS, BridgeRuntime
from lpv_sysid.flight.bridge.settings import SPECS, handback_bound_s, settings_from_params

__all__ = [
    "BridgeRuntime",
    "PARSERS",
    "SPECS",
    "handback_bound_s",
    "settings_from_params",
]
