"""TODO face"""

from __future__ import annotations

from lpv_sysid.flight.bridge.runtime import PARSERS, BridgeRuntime
from lpv_sysid.flight.bridge.settings import SPECS, handback_bound_s

__all__ = [
    "BridgeRuntime",
    "PARSERS",
    "SPECS",
    "handback_bound_s",
]
