"""The phase-2 flight on a PX4 vehicle that is armed and in the air (``lpv-sysid fly phase2``,
step 5 of the chain): its options (:mod:`~lpv_sysid.flight.phase2.options`), the flight
(:func:`fly_phase2`, :mod:`~lpv_sysid.flight.phase2.sequence`) and what it measured: the
u_e -> z gain against gamma, tracking, the torque error of the rate-loop inversion
(:mod:`~lpv_sysid.flight.phase2.analysis`).
"""

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
