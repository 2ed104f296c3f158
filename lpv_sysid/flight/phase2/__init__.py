"""The phase-2 flight on a PX4 vehicle that is armed and in the air (``lpv-sysid fly phase2``,
step 5 of the chain): its options (:mod:`~lpv_sysid.flight.phase2.options`), the flight
(:func:`fly_phase2`, :mod:`~lpv_sysid.flight.phase2.sequence`: the phase-2 nodes' runtimes in
process, :func:`phase2_graph`, so every check of ``lpv_controller_node`` applies) and what
it measured: the u_e -> z gain against gamma, tracking, the torque error of the rate-loop
inversion, the loop latency (:mod:`~lpv_sysid.flight.phase2.analysis`).
"""

from __future__ import annotations

from lpv_sysid.flight.phase2.analysis import (
    excitation_gain,
    inversion_error,
    latency_from_bag,
    loop_latency,
)
from lpv_sysid.flight.phase2.options import Phase2Options
from lpv_sysid.flight.phase2.sequence import (
    Phase2Graph,
    controller_loop_delay_s,
    fly_phase2,
    load_phase2_law,
    phase2_graph,
    save_summary,
)

__all__ = [
    "Phase2Graph",
    "Phase2Options",
    "controller_loop_delay_s",
    "excitation_gain",
    "fly_phase2",
    "inversion_error",
    "latency_from_bag",
    "load_phase2_law",
    "loop_latency",
    "phase2_graph",
    "save_summary",
]
