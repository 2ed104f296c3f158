"""TODO face"""

from __future__ import annotations

from lpv_sysid.flight.phase2.analysis import excitation_gain, inversion_error
from lpv_sysid.flight.phase2.options import Phase2Options
from lpv_sysid.flight.phase2.sequence import fly_phase2, load_phase2_law, save_summary

__all__ = [
    "Phase2Options",
    "excitation_gain",
    "fly_phase2",
    "inversion_error",
    "load_phase2_law",
    "save_summary",
]
