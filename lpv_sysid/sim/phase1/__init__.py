"""Phase-1 experiment simulation (seed 0 Sec. IV): vertex flights under baseline control.

For each vertex v_d of the scheduling box (seed 0 Eq. 20, default [-5, 5]^3 m/s, Table 1
order: u fastest, then v, then w) the simulated vehicle flies ``trim_s`` (10 s) at the
constant body-velocity reference, then ``excite_s`` (30 s) of a 4-axis multisine on the
u, v, w and yaw-rate references (0.2-2 Hz), all under the PX4-like baseline controller.
One extra run about hover serves as the independent validation manoeuvre.

With ``start: hover`` (default) each run starts in hover (model hover trim, controller
integrators warm started there) and the vertex reference is applied as a step at t = 0,
so the 10 s trim segment contains the transition and the settling, as in flight; with
``start: trim`` the run starts at the model trim of its vertex (quick tests). The
achieved equilibrium is the mean over the last ``trim_average_s`` of the trim segment of
the *measured* data, as seed 0 Table 1 is computed from flight data.

Outputs: an in-memory :class:`RunRecord` per run; ``write_run_bag`` writes it as a
rosbag2 directory with the topics of docs/DESIGN.md; ``write_trim_table`` writes
trims.yaml and trims.md.

Parts: :mod:`~lpv_sysid.sim.phase1.config` (``Phase1Config``,
``load_config``), :mod:`~lpv_sysid.sim.phase1.runs` (excitation, ``simulate_run``,
``run_phase1``, ``RunRecord``), :mod:`~lpv_sysid.sim.phase1.trims` (the Table 1 trim table)
and :mod:`~lpv_sysid.sim.phase1.bag` (``write_run_bag``).
"""

from __future__ import annotations

from lpv_sysid.sim.phase1.bag import BAG_TOPICS, DECLARED_EPOCH_NS, write_run_bag
from lpv_sysid.sim.phase1.config import Phase1Config, load_config
from lpv_sysid.sim.phase1.runs import (
    design_excitation,
    excitation_signal,
    run_phase1,
    simulate_run,
)
from lpv_sysid.sim.phase1.trims import format_trim_table, trim_table, write_trim_table

__all__ = [
    "DECLARED_EPOCH_NS",
    "BAG_TOPICS",
    "Phase1Config",
    "design_excitation",
    "excitation_signal",
    "format_trim_table",
    "load_config",
    "run_phase1",
    "simulate_run",
    "trim_table",
    "write_run_bag",
    "write_trim_table",
]
