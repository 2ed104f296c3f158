"""TODO face"""

from __future__ import annotations

from lpv_sysid.flight.campaign.config import FlyConfig
from lpv_sysid.flight.campaign.recorder import CampaignRecorder
from lpv_sysid.flight.campaign.runtime import (
    PARSERS,
    CampaignNodeSettings,
    CampaignRuntime,
    vehicle_status,
)
from lpv_sysid.flight.campaign.sequence import EXIT_FAILED, fly, plan_flight

__all__ = [
    "CampaignNodeSettings",
    "CampaignRecorder",
    "CampaignRuntime",
    "EXIT_FAILED",
    "FlyConfig",
    "PARSERS",
    "fly",
    "plan_flight",
    "vehicle_status",
]
