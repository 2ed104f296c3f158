"""TODO face"""

from __future__ import annotations

from lpv_sysid.flight.phase2.analysis import analyse_phase2, excitation_gain, inversion_error
from lpv_sysid.flight.phase2.fly import (
    Phase2Options,
    fly_phase2,
    load_phase2_law,
    phase2_bridge_config,
    save_summary,
)

__all__ = [
    "Phase2Options",
    "analyse_phase2",
    "excitation_gain",
    "fly_phase2",
    "inversion_error",
    "load_phase2_law",
    "phase2_bridge_config",
    "save_summary",
]
