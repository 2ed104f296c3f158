"""The phase-1 campaign flown on a PX4 vehicle, ROS-free: ``lpv-sysid fly phase1`` and the
ROS ``campaign_node`` run the same sequencer (:mod:`lpv_sysid.control.campaign`).

Parts: the flight's inputs (:mod:`~lpv_sysid.flight.campaign.config`), the sequence of the
command line (:func:`fly`, :mod:`~lpv_sysid.flight.campaign.sequence`), its loop
(:mod:`~lpv_sysid.flight.campaign.runner`), its recording
(:mod:`~lpv_sysid.flight.campaign.recorder`) and outputs
(:mod:`~lpv_sysid.flight.campaign.outputs`), and the campaign node's message-level runtime
(:mod:`~lpv_sysid.flight.campaign.runtime`).
"""

from __future__ import annotations

from lpv_sysid.flight.campaign.config import FlyConfig, resume_config
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
    "resume_config",
    "vehicle_status",
]
