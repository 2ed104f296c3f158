"""TODO face"""

from __future__ import annotations

from lpv_sysid.control.law.config import LpvControllerConfig
from lpv_sysid.control.law.controller import LpvController
from lpv_sysid.control.law.reference_limiter import ReferenceLimiter

__all__ = [
    "LpvController",
    "LpvControllerConfig",
    "ReferenceLimiter",
]
