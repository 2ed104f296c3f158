"""TODO face"""

from __future__ import annotations

from lpv_sysid.flight.campaign.config import (
    FlyConfig,
    bridge_config_for,
    load_signals,
)
from lpv_sysid.flight.campaign.outputs import (
    format_results,
    identification_template,
    write_outputs,
)
from lpv_sysid.flight.campaign.recorder import RATE_TOPIC, TOPICS, CampaignRecorder
from lpv_sysid.flight.campaign.runner import FlightRunner
from lpv_sysid.flight.campaign.runtime import (
    PARSERS,
    CampaignNodeSettings,
    CampaignRuntime,
    vehicle_status,
)

__all__ = [
    "CampaignNodeSettings",
    "CampaignRecorder",
    "CampaignRuntime",
    "FlightRunner",
    "FlyConfig",
    "PARSERS",
    "RATE_TOPIC",
    "TOPICS",
    "bridge_config_for",
    "format_results",
    "identification_template",
    "load_signals",
    "vehicle_status",
    "write_outputs",
]
