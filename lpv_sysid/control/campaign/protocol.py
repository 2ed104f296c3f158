"""What passes between the campaign sequencer and its runner (``lpv_sysid/cli/vehicle/fly.py``,
``lpv_sysid/nodes/campaign_node.py``): the phase names, :class:`VehicleStatus` in, and
:class:`CampaignOutput` out (the velocity command, the actions the runner carries out and
the events it presents)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from lpv_sysid.control.campaign.plan import PlannedRun
from lpv_sysid.control.campaign.results import RunResult

# the phases of the sequence (module docstring of lpv_sysid.control.campaign)
IDLE, STARTING, TAKEOFF, REPOSITION, SETTLE = "idle", "starting", "takeoff", "reposition", "settle"
TRIM, EXCITATION, RECOVER, FINISHING, LANDING = (
    "trim",
    "excitation",
    "recover",
    "finishing",
    "landing",
)
DONE, ABORTING, ABORTED, FAILED = "done", "aborting", "aborted", "failed"
TERMINAL = (DONE, ABORTED, FAILED)
FLYING = (TAKEOFF, REPOSITION, SETTLE, TRIM, EXCITATION, RECOVER)
RUN_PHASES = (SETTLE, TRIM, EXCITATION)


@dataclass(frozen=True)
class VehicleStatus:
    """What the runner knows about the bridge and the vehicle at ``step`` time."""

    bridge_state: str  # OffboardMachine state value (IDLE ... FAILED)
    bridge_reason: str = ""
    mode: str | None = None  # PX4 mode name from the HEARTBEAT
    armed: bool = False
    home_ned: Any = None  # the envelope's home (NED), when armed
    violation: str | None = None  # the envelope's latched violation, if any
    confirmed_mode: str | None = None  # hand-back mode the bridge confirmed (DONE, or FAILED
    # after a fault hand-back that PX4 confirmed)


@dataclass(frozen=True)
class StartBridge:
    pass


@dataclass(frozen=True)
class AbortBridge:
    reason: str


@dataclass(frozen=True)
class ActivateFloor:
    reason: str


@dataclass(frozen=True)
class FinishBridge:
    """End the offboard session in ``mode`` (HOLD or LAND) with the bridge's confirmation
    rules (``BridgeCore.finish``)."""

    mode: str


@dataclass(frozen=True)
class RunStarted:
    run: PlannedRun
    t: float


@dataclass(frozen=True)
class RunEnded:
    run: PlannedRun
    t: float
    complete: bool
    result: "RunResult"


@dataclass(frozen=True)
class CampaignEvent:
    t: float
    phase: str
    message: str
    level: str = "info"  # info | warn | error


@dataclass
class CampaignOutput:
    command: tuple | None = None  # (v (3,) in the command frame [m/s], yaw rate [rad/s])
    actions: list = field(default_factory=list)
    events: list = field(default_factory=list)
